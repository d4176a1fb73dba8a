"""The hand camera's mount on the arm: ``hand_eye_transform`` from tf (or the URDF if tf does not answer),
``hand_eye_from_calibration`` from a hand-eye calibration file (``baxter_pnp.hand_eye``).

Frames: ``T_hand_camera`` is the ``<side>_hand_camera`` pose in ``<side>_hand``, ``T_gripper_camera``
its pose in ``<side>_gripper`` (4x4, metres). Timeouts in wall-clock seconds.
"""
from typing import NamedTuple

import numpy as np
import rospy

from baxter_pnp.robot import sdk
from baxter_pnp.robot.topics import wait_until
from baxter_pnp.transforms import from_xyz_quat


class HandEye(NamedTuple):
    """The hand camera's mount: T_hand_camera, T_gripper_camera (4x4, m) and their source ('tf', 'urdf' or
    'calibration <file>')."""
    T_hand_camera: np.ndarray
    T_gripper_camera: np.ndarray
    source: str


def _tf_matrix(transform_stamped):
    t, q = transform_stamped.transform.translation, transform_stamped.transform.rotation
    return from_xyz_quat((t.x, t.y, t.z), (q.x, q.y, q.z, q.w))


def hand_eye_transform(side, timeout=2.0, urdf_path=None):
    """The ``<side>_hand_camera`` pose in ``<side>_hand`` and in ``<side>_gripper``, from tf.

    Falls back (with a warning) to the URDF (``ArmKinematics``, ``urdf_path`` or urdf/baxter.urdf)
    when tf does not provide both transforms within ``timeout`` wall seconds.
    """
    import tf2_ros
    frames = sdk.arm_frames(side)
    hand, gripper, camera = frames.hand, frames.gripper, frames.hand_camera
    buffer = tf2_ros.Buffer()
    listener = tf2_ros.TransformListener(buffer)
    try:
        latest = rospy.Time(0)
        if wait_until(lambda: buffer.can_transform(hand, camera, latest) and
                      buffer.can_transform(gripper, camera, latest), timeout, rate_hz=50.0):
            return HandEye(_tf_matrix(buffer.lookup_transform(hand, camera, latest)),
                           _tf_matrix(buffer.lookup_transform(gripper, camera, latest)), 'tf')
    finally:
        listener.unregister()
    rospy.logwarn(f'tf has no {hand} -> {camera} and {gripper} -> {camera} after {timeout} s: '
                  f'using the URDF instead')
    from baxter_pnp.kinematics import ArmKinematics
    kinematics = ArmKinematics(side, urdf_path)
    try:
        return HandEye(kinematics.relative(hand, camera), kinematics.relative(gripper, camera), 'urdf')
    finally:
        kinematics.close()


def hand_eye_from_calibration(side, T_hand_camera, source, urdf_path=None):
    """The mount ``T_hand_camera`` (4x4, m: a calibration's camera pose in ``<side>_hand``), with
    ``T_gripper_camera`` through the URDF's fixed hand -> gripper joint."""
    from baxter_pnp.kinematics import ArmKinematics
    frames = sdk.arm_frames(side)
    kinematics = ArmKinematics(side, urdf_path)
    try:
        T_gripper_hand = kinematics.relative(frames.gripper, frames.hand)
    finally:
        kinematics.close()
    T_hand_camera = np.asarray(T_hand_camera, dtype=float)
    return HandEye(T_hand_camera, T_gripper_hand @ T_hand_camera, source)
