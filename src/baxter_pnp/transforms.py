"""Rigid transforms as 4x4 homogeneous matrices, with scipy's ``Rotation`` underneath.

Naming convention used across the package: ``T_a_b`` is the pose of frame ``b`` expressed in frame
``a`` (it maps points from ``b`` coordinates to ``a`` coordinates: ``p_a = T_a_b @ p_b``).
Translations are in metres, angles in radians, quaternions in ROS order (x, y, z, w).
"""
import numpy as np
from scipy.spatial.transform import Rotation


def make_transform(rotation=None, translation=(0.0, 0.0, 0.0)):
    """4x4 transform from a ``Rotation`` (or 3x3 matrix, or None = identity) and a translation (m)."""
    T = np.eye(4)
    if rotation is not None:
        T[:3, :3] = rotation.as_matrix() if isinstance(rotation, Rotation) else np.asarray(rotation)
    T[:3, 3] = translation
    return T


def from_xyz_quat(xyz, quat_xyzw):
    """4x4 transform from a position (m) and a quaternion (x, y, z, w)."""
    return make_transform(Rotation.from_quat(quat_xyzw), xyz)


def from_xyz_rpy(xyz, rpy):
    """4x4 transform from a position (m) and URDF fixed-axis roll, pitch, yaw (rad): R = Rz(y) Ry(p) Rx(r)."""
    return make_transform(Rotation.from_euler('xyz', rpy), xyz)


def to_xyz_quat(T):
    """(position (3,), quaternion xyzw (4,)) of a 4x4 transform."""
    return np.array(T[:3, 3], dtype=float), Rotation.from_matrix(T[:3, :3]).as_quat()


def invert(T):
    """Inverse of a rigid 4x4 transform."""
    R = T[:3, :3]
    inverse = np.eye(4)
    inverse[:3, :3] = R.T
    inverse[:3, 3] = -R.T @ T[:3, 3]
    return inverse


def relative_transforms(T_ref_a, T_ref_b):
    """(N, 4, 4) T_a_b = inv(T_ref_a) @ T_ref_b of stacked rigid transforms (N, 4, 4) in one frame ``ref``."""
    R_a_ref = T_ref_a[:, :3, :3].transpose(0, 2, 1)
    T_a_b = np.zeros_like(T_ref_b)
    T_a_b[:, :3, :3] = R_a_ref @ T_ref_b[:, :3, :3]
    T_a_b[:, :3, 3] = np.einsum('nij,nj->ni', R_a_ref, T_ref_b[:, :3, 3] - T_ref_a[:, :3, 3])
    T_a_b[:, 3, 3] = 1.0
    return T_a_b


def transform_points(T, points):
    """Apply a 4x4 transform to an (N, 3) array of points."""
    points = np.asarray(points, dtype=float)
    return points @ T[:3, :3].T + T[:3, 3]


def pose_msg_to_matrix(pose):
    """4x4 transform from a ``geometry_msgs/Pose`` (duck-typed: ``.position``, ``.orientation``)."""
    p, q = pose.position, pose.orientation
    return from_xyz_quat((p.x, p.y, p.z), (q.x, q.y, q.z, q.w))


def matrix_to_pose_msg(T, pose):
    """Fill a ``geometry_msgs/Pose`` instance from a 4x4 transform and return it."""
    xyz, quat = to_xyz_quat(T)
    pose.position.x, pose.position.y, pose.position.z = (float(v) for v in xyz)
    (pose.orientation.x, pose.orientation.y,
     pose.orientation.z, pose.orientation.w) = (float(v) for v in quat)
    return pose


def rotation_angle_between(T_a, T_b):
    """Angle (rad) of the relative rotation between two transforms' orientations."""
    return float(Rotation.from_matrix(T_a[:3, :3].T @ T_b[:3, :3]).magnitude())


def pose_error(T_current, T_goal):
    """(translation error (m), rotation error (rad)) between two poses."""
    translation = float(np.linalg.norm(T_goal[:3, 3] - T_current[:3, 3]))
    return translation, rotation_angle_between(T_current, T_goal)


def raised(T_a_b, height):
    """The same pose ``height`` metres higher along ``a``'s z (in ``base``: up)."""
    T = np.array(T_a_b, dtype=float)
    T[2, 3] += height
    return T
