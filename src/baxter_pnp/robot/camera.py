"""``HandCamera``: one arm's hand camera, opened through the SDK's camera services (interfaces §8).

Frames (``Frame``) are uint8 BGR images (H, W, 3) with the ``CameraModel`` of the last camera_info
(pixels; the optical frame is ``<side>_hand_camera``) and their header stamp (ROS time, s).
Timeouts and stream ages are wall-clock seconds.
"""
import errno
import time
from typing import NamedTuple

import numpy as np
import rospy
from sensor_msgs.msg import CameraInfo, Image

from baxter_pnp.camera import CameraModel
from baxter_pnp.msgs import msg, srv
from baxter_pnp.robot import sdk
from baxter_pnp.robot.errors import RobotError
from baxter_pnp.robot.topics import DEFAULT_MAX_AGE, CachedTopic, wait_for_service
from baxter_pnp.ros_image import msg_to_bgr

CAMERA_INFO_GRACE = 1.0                # s (wall): frames may arrive before the first camera_info


class Frame(NamedTuple):
    """One camera frame: uint8 BGR (H, W, 3) image, its CameraModel, and its header stamp (ROS time, s)."""
    image_bgr: np.ndarray
    camera: CameraModel
    stamp: float


class HandCamera:
    """The hand camera of one arm: opened through ``/cameras/open`` when ``/cameras/list`` exists, at ``resolution``
    and ``fps``, with ``exposure`` and ``gain`` when given (``camera_controls``; -1: the camera's automatic ones).

    Without ``/cameras/list`` (e.g. the Gazebo simulator) the camera is assumed to stream already.
    Frames in bgra8, bgr8, rgb8 or mono8 are converted to BGR and paired with the last
    ``camera_info``; a frame with another encoding, without a camera_info, or whose size does not
    match is logged as an error and dropped (frames in the first ``CAMERA_INFO_GRACE`` s after subscribing,
    while the camera_info subscription connects, are dropped silently).
    """

    def __init__(self, side, resolution=(640, 400), fps=20, timeout=5.0, service_timeout=2.0,
                 exposure=sdk.CAMERA_CONTROL_AUTO, gain=sdk.CAMERA_CONTROL_AUTO):
        self.name = sdk.arm_frames(side).hand_camera
        self.resolution = tuple(resolution)
        if self.resolution not in sdk.CAMERA_MODES:
            raise ValueError(f'resolution {resolution} is not a camera mode (one of {sdk.CAMERA_MODES})')
        self.controls = camera_controls(exposure, gain)
        self.image_topic, self.info_topic = sdk.camera_topics(self.name)
        self.timeout = timeout
        self.fps = fps
        self.service_timeout = service_timeout
        self.opened = self._open(fps, service_timeout)
        self._subscribed_at = time.monotonic()
        self._info = CachedTopic(self.info_topic, CameraInfo, CameraModel.from_camera_info)
        self._frames = CachedTopic(self.image_topic, Image, self._frame, buff_size=1 << 24)

    def _open(self, fps, service_timeout):
        """Open the camera through /cameras/open if the robot has /cameras/list; True if opened."""
        try:
            rospy.wait_for_service(sdk.CAMERAS_LIST_SERVICE, timeout=service_timeout)
        except rospy.ROSException:
            rospy.loginfo(f'{self.name}: no {sdk.CAMERAS_LIST_SERVICE} service: assuming the camera streams already')
            return False
        available = rospy.ServiceProxy(sdk.CAMERAS_LIST_SERVICE, srv.ListCameras)().cameras
        if self.name not in available:
            raise RobotError(f'camera {self.name} is not available (powered cameras: {list(available)}); '
                             f'close another camera first')
        wait_for_service(sdk.CAMERAS_OPEN_SERVICE, service_timeout)
        width, height = self.resolution
        settings = msg.CameraSettings(width=width, height=height, fps=float(fps),
                                      controls=[msg.CameraControl(id=i, value=v) for i, v in self.controls])
        err = rospy.ServiceProxy(sdk.CAMERAS_OPEN_SERVICE, srv.OpenCamera)(self.name, settings).err
        if err != 0:
            raise RobotError(f'{sdk.CAMERAS_OPEN_SERVICE} {self.name} {width}x{height}@{fps} failed: '
                             f'{errno.errorcode.get(err, err)}')
        rospy.loginfo(f'{self.name}: opened at {width}x{height}, {fps} fps'
                      + ''.join(f', {sdk.CAMERA_CONTROL_RANGES[i][0]} {v}' for i, v in self.controls))
        return True

    def reopen(self):
        """Open the camera again with the same settings (after the robot restarted, say)."""
        self.opened = self._open(self.fps, self.service_timeout)

    def close(self):
        """Stop receiving frames and close the camera if this object opened it (err 0 or EINVAL accepted).

        A robot that no longer serves ``/cameras/close`` only earns a warning.
        """
        self._frames.unregister()
        self._info.unregister()
        if not self.opened:
            return
        self.opened = False
        try:
            err = rospy.ServiceProxy(sdk.CAMERAS_CLOSE_SERVICE, srv.CloseCamera)(self.name).err
        except rospy.ServiceException as error:     # the robot is gone: nothing left to close
            rospy.logwarn(f'{self.name}: not closed: {error}')
            return
        if err not in (0, errno.EINVAL):
            raise RobotError(f'{sdk.CAMERAS_CLOSE_SERVICE} {self.name} failed: {errno.errorcode.get(err, err)}')

    def _frame(self, message):
        camera = self._info.value
        if camera is None:
            if time.monotonic() - self._subscribed_at < CAMERA_INFO_GRACE:     # both topics are just connecting
                rospy.logdebug(f'{self.name}: frame before the first camera_info: dropped')
                return None
            raise ValueError(f'no valid camera_info on {self.info_topic} yet: frame dropped')
        if (message.width, message.height) != (camera.width, camera.height):
            raise ValueError(f'frame is {message.width}x{message.height} but camera_info is '
                             f'{camera.width}x{camera.height}: frame dropped')
        if self.opened and (message.width, message.height) != self.resolution:
            raise ValueError(f'frame is {message.width}x{message.height}, the camera was opened at '
                             f'{self.resolution[0]}x{self.resolution[1]}: frame dropped')
        return Frame(msg_to_bgr(message), camera, message.header.stamp.to_sec())

    def latest(self):
        """The last valid Frame (image_bgr, camera, stamp), or None if none arrived yet."""
        return self._frames.value

    def require_fresh(self, max_age=DEFAULT_MAX_AGE):
        """The last Frame if at most ``max_age`` s old (wall clock); StreamLost otherwise."""
        return self._frames.require_fresh(max_age)

    def wait_for_frame(self, after_stamp=None, timeout=None):
        """The first valid Frame stamped later than ``after_stamp`` (ROS time, s; None: any); RobotTimeout otherwise."""
        return self._frames.wait(self.timeout if timeout is None else timeout,
                                 accept=lambda frame: after_stamp is None or frame.stamp > after_stamp,
                                 what='no new valid frame' if after_stamp is not None else 'no valid frame')


def camera_controls(exposure=sdk.CAMERA_CONTROL_AUTO, gain=sdk.CAMERA_CONTROL_AUTO):
    """[(CameraControl id, value)] to open a camera with: ``exposure`` 0-100 and ``gain`` 0-79 (baxter_interface's
    ranges), each left out at ``CAMERA_CONTROL_AUTO`` (-1: the camera's own); ValueError for anything else (before
    the robot is asked). Opening a camera resets what was set before (``camera_control.py``): the app's settings
    are the ones that hold."""
    controls = [(sdk.CAMERA_CONTROL_EXPOSURE, exposure), (sdk.CAMERA_CONTROL_GAIN, gain)]
    for control, value in controls:
        problem = sdk.camera_control_problem(control, value)
        if problem:
            raise ValueError(problem)
    return [(control, value) for control, value in controls if value != sdk.CAMERA_CONTROL_AUTO]
