"""sensor_msgs/Image <-> numpy conversions (baxter_pnp.ros_image), including serialisation round trips."""
import io

import numpy as np
import pytest
from sensor_msgs.msg import Image
from std_msgs.msg import Header

from baxter_pnp.ros_image import bgr_to_msg, msg_to_array, msg_to_bgr


@pytest.fixture
def image_bgr():
    rng = np.random.default_rng(3)
    return rng.integers(0, 256, size=(5, 7, 3), dtype=np.uint8)


def _wire_round_trip(msg):
    """Serialise and deserialise like rospy does between two nodes."""
    buffer = io.BytesIO()
    msg.serialize(buffer)
    received = Image()
    received.deserialize(buffer.getvalue())
    return received


@pytest.mark.parametrize('encoding', ['bgra8', 'bgr8', 'rgb8'])
def test_colour_round_trip_is_exact(image_bgr, encoding):
    msg = _wire_round_trip(bgr_to_msg(image_bgr, encoding, Header(frame_id='left_hand_camera')))
    assert (msg.width, msg.height, msg.encoding) == (7, 5, encoding)
    assert msg.header.frame_id == 'left_hand_camera'
    np.testing.assert_array_equal(msg_to_bgr(msg), image_bgr)


def test_channel_orders(image_bgr):
    b, g, r = image_bgr[0, 0]
    assert tuple(msg_to_array(bgr_to_msg(image_bgr, 'rgb8'))[0, 0]) == (r, g, b)
    assert tuple(msg_to_array(bgr_to_msg(image_bgr, 'bgra8'))[0, 0]) == (b, g, r, 255)


def test_mono8(image_bgr):
    msg = bgr_to_msg(image_bgr, 'mono8')
    grey = msg_to_array(msg)
    assert grey.shape == (5, 7) and msg.step == 7
    expected = np.round(0.114 * image_bgr[..., 0] + 0.587 * image_bgr[..., 1] + 0.299 * image_bgr[..., 2])
    assert np.abs(grey.astype(float) - expected).max() <= 1
    bgr = msg_to_bgr(msg)
    assert bgr.shape == (5, 7, 3) and np.all(bgr[..., 0] == grey) and np.all(bgr[..., 2] == grey)


def test_row_padding_is_removed(image_bgr):
    padded_rows = np.zeros((5, 7 * 3 + 3), np.uint8)
    padded_rows[:, :21] = image_bgr.reshape(5, 21)
    msg = Image(height=5, width=7, encoding='bgr8', step=24, data=padded_rows.tobytes())
    np.testing.assert_array_equal(msg_to_bgr(msg), image_bgr)


@pytest.mark.parametrize('encoding', ['16UC1', 'yuv422', 'bayer_rggb8', ''])
def test_unsupported_encoding_is_a_clear_error(encoding):
    msg = Image(height=1, width=1, encoding=encoding, step=2, data=b'\0\0')
    with pytest.raises(ValueError, match='not supported'):
        msg_to_bgr(msg)
    with pytest.raises(ValueError, match='not supported'):
        bgr_to_msg(np.zeros((1, 1, 3), np.uint8), encoding)


def test_wrong_data_length_is_a_clear_error(image_bgr):
    msg = bgr_to_msg(image_bgr, 'bgr8')
    msg.data = msg.data[:-1]
    with pytest.raises(ValueError, match='expected step'):
        msg_to_bgr(msg)
    msg = bgr_to_msg(image_bgr, 'bgr8')
    msg.step = 20
    with pytest.raises(ValueError, match='shorter than a row'):
        msg_to_bgr(msg)


def test_bgr_to_msg_rejects_non_bgr_arrays():
    with pytest.raises(ValueError, match='uint8'):
        bgr_to_msg(np.zeros((4, 4), np.uint8))
    with pytest.raises(ValueError, match='uint8'):
        bgr_to_msg(np.zeros((4, 4, 3), np.float32))
