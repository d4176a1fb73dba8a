"""Rosbags of hand-camera runs for the replay tests, written with ``rosbag.Bag`` (no master needed).

The CameraInfo is the one a real Baxter's left hand camera publishes at 640x400
(``../shared/real/baxter_hand_a/camera_info_as_published.yaml``): the full 1280x800 sensor's K and D, the centred
window as ``roi`` (offset 320, 200), ``P`` of the delivered image, ``frame_id`` ``/left_hand_camera``. The sensor's
K and D are copied here (numbers, not the photographs) so that the synthetic tests run without the shared folder.
"""
import json
import os

import numpy as np
import rosbag
import rospy
import yaml
from sensor_msgs.msg import CameraInfo

from baxter_pnp import ros_image
from baxter_pnp.camera import CameraModel, SensorWindow

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
REAL = os.environ.get('BAXTER_PNP_REAL_DATA', os.path.join(REPO, '..', 'shared', 'real'))
REAL_CAMERA_INFO = os.path.join(REAL, 'baxter_hand_a', 'camera_info_as_published.yaml')

IMAGE_TOPIC = '/cameras/left_hand_camera/image'
INFO_TOPIC = '/cameras/left_hand_camera/camera_info'
FRAME_ID = '/left_hand_camera'
# The real robot's sensor calibration (its CameraInfo's K and D).
SENSOR_K = [403.1498765559809, 0.0, 651.3100088479307, 0.0, 403.9409358133219, 405.82095914289783, 0.0, 0.0, 1.0]
SENSOR_D = [0.02909140543965944, -0.08374659479659467, -0.0010871751762388689, 0.002550696113092468,
            0.03253240050176302]
SENSOR_SIZE = (1280, 800)
WINDOW_640x400 = SensorWindow.centred(*SENSOR_SIZE, 640, 400)            # roi (320, 200) 640x400
WINDOW_BINNED = SensorWindow(0, 0, *SENSOR_SIZE, binning=2)              # the whole sensor at 640x400


def robot_sensor():
    """The real hand camera's full-sensor model (1280x800)."""
    return CameraModel(*SENSOR_SIZE, SENSOR_K, SENSOR_D, frame_id=FRAME_ID)


def window_camera(window):
    """The model of the image ``window`` delivers, by hand (not through ``CameraModel.from_camera_info``, which
    the replay uses): principal point shifted by the ROI offset, then K divided by the binning."""
    K = np.reshape(SENSOR_K, (3, 3)).copy()
    K[:2, 2] -= (window.x_offset, window.y_offset)
    K[:2] /= window.binning
    return CameraModel(*window.image_size(), K, SENSOR_D)


def stamped(msg, stamp_ns, seq, frame_id=FRAME_ID):
    """``msg`` with its header set (``stamp_ns``: ROS time in nanoseconds)."""
    msg.header.stamp = rospy.Time(stamp_ns // 10**9, stamp_ns % 10**9)
    msg.header.seq = seq
    msg.header.frame_id = frame_id
    return msg


def camera_info(stamp_ns, seq, window=WINDOW_640x400):
    """The CameraInfo the robot publishes for ``window`` of its sensor, stamped."""
    return stamped(robot_sensor().to_camera_info(window=window), stamp_ns, seq)


def published_camera_info(stamp_ns, seq):
    """The real robot's CameraInfo as published (from the shared folder's ``rostopic echo``), stamped."""
    with open(REAL_CAMERA_INFO) as f:
        fields = yaml.safe_load(f)
    msg = CameraInfo(width=fields['width'], height=fields['height'], distortion_model=fields['distortion_model'],
                     D=fields['D'], K=fields['K'], R=fields['R'], P=fields['P'], binning_x=fields['binning_x'],
                     binning_y=fields['binning_y'])
    for key, value in fields['roi'].items():
        setattr(msg.roi, key, value)
    return stamped(msg, stamp_ns, seq, fields['header']['frame_id'])


def image(image_bgr, stamp_ns, seq, encoding='bgra8'):
    """A ``sensor_msgs/Image`` of a BGR image in ``encoding`` (the robot sends bgra8), stamped."""
    return stamped(ros_image.bgr_to_msg(image_bgr, encoding), stamp_ns, seq)


def write_bag(path, messages):
    """Write ``messages``, (topic, msg, record time in ns), into a new bag at ``path``; returns ``path``."""
    with rosbag.Bag(str(path), 'w') as bag:
        for topic, msg, recorded_ns in messages:
            bag.write(topic, msg, rospy.Time(recorded_ns // 10**9, recorded_ns % 10**9))
    return str(path)


def frame_messages(stamp_ns, seq, image_msg, info=None):
    """An image message and, if given, its CameraInfo with the same stamp recorded after it (as the robot's driver
    publishes them), as ``write_bag`` entries."""
    messages = [(IMAGE_TOPIC, image_msg, stamp_ns + 2_000_000)]
    if info is not None:
        messages.append((INFO_TOPIC, info, stamp_ns + 3_000_000))
    return messages


def json_lines(text):
    """The JSON objects among ``text``'s lines (stdout and stderr may be mixed)."""
    return [json.loads(line) for line in text.splitlines() if line.startswith('{')]
