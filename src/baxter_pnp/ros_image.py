"""``sensor_msgs/Image`` <-> numpy, for the encodings Baxter's cameras and our tools use.

Supported encodings: ``bgra8`` (what Baxter's hand cameras publish), ``bgr8``, ``rgb8`` and ``mono8``.
Inside the package images are ``uint8`` BGR ``(H, W, 3)`` arrays (OpenCV order); these helpers are the
only place where channel order and row padding (``step``) are dealt with, so that no cv_bridge is needed.
Anything else (another encoding, a ``data`` length that does not match ``step * height``, a ``step``
shorter than a row) raises ``ValueError`` with the reason.
"""
import cv2
import numpy as np

CHANNELS = {'bgra8': 4, 'bgr8': 3, 'rgb8': 3, 'mono8': 1}
# cv2.cvtColor codes from BGR to each encoding and back (None: no conversion).
_FROM_BGR = {'bgra8': cv2.COLOR_BGR2BGRA, 'bgr8': None, 'rgb8': cv2.COLOR_BGR2RGB, 'mono8': cv2.COLOR_BGR2GRAY}
_TO_BGR = {'bgra8': cv2.COLOR_BGRA2BGR, 'bgr8': None, 'rgb8': cv2.COLOR_RGB2BGR, 'mono8': cv2.COLOR_GRAY2BGR}


def _check_encoding(encoding):
    if encoding not in CHANNELS:
        raise ValueError(f'image encoding {encoding!r} is not supported (supported: {", ".join(CHANNELS)})')


def bgr_to_msg(image_bgr, encoding='bgr8', header=None):
    """``sensor_msgs/Image`` holding a uint8 BGR ``(H, W, 3)`` image converted to ``encoding``.

    ``header`` (``std_msgs/Header``) is copied into the message when given.
    """
    from sensor_msgs.msg import Image
    _check_encoding(encoding)
    image_bgr = np.asarray(image_bgr)
    if image_bgr.dtype != np.uint8 or image_bgr.ndim != 3 or image_bgr.shape[2] != 3:
        raise ValueError(f'bgr_to_msg expects a uint8 (H, W, 3) BGR array, got {image_bgr.dtype} {image_bgr.shape}')
    code = _FROM_BGR[encoding]
    pixels = image_bgr if code is None else cv2.cvtColor(image_bgr, code)
    pixels = np.ascontiguousarray(pixels)
    height, width = image_bgr.shape[:2]
    msg = Image(height=height, width=width, encoding=encoding, is_bigendian=0,
                step=width * CHANNELS[encoding], data=pixels.tobytes())
    if header is not None:
        msg.header = header
    return msg


def msg_to_array(msg):
    """The message's pixels as a uint8 array in its own channel order: ``(H, W, C)``, or ``(H, W)`` for mono8.

    Row padding (``step`` larger than ``width * channels``) is removed. The array is a read-only view
    of ``msg.data`` when no padding had to be removed.
    """
    _check_encoding(msg.encoding)
    channels = CHANNELS[msg.encoding]
    row_bytes = msg.width * channels
    if msg.step < row_bytes:
        raise ValueError(f'image step {msg.step} is shorter than a row of {msg.width} {msg.encoding} pixels '
                         f'({row_bytes} bytes)')
    if len(msg.data) != msg.step * msg.height:
        raise ValueError(f'image data has {len(msg.data)} bytes, expected step * height = '
                         f'{msg.step} * {msg.height} = {msg.step * msg.height}')
    rows = np.frombuffer(bytes(msg.data) if isinstance(msg.data, list) else msg.data, dtype=np.uint8)
    rows = rows.reshape(msg.height, msg.step)[:, :row_bytes]
    shape = (msg.height, msg.width) if channels == 1 else (msg.height, msg.width, channels)
    return rows.reshape(shape)


def msg_to_bgr(msg):
    """uint8 BGR ``(H, W, 3)`` image (a new array) from a ``sensor_msgs/Image`` in a supported encoding."""
    pixels = msg_to_array(msg)
    code = _TO_BGR[msg.encoding]
    return pixels.copy() if code is None else cv2.cvtColor(np.ascontiguousarray(pixels), code)
