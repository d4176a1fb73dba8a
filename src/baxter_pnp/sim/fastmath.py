"""Fast per-call rigid-transform helpers for the fake's loop (no ROS): ``baxter_pnp.transforms``' results, bit for bit.

``transforms`` goes through scipy's ``Rotation`` for every pose (~30 us a call); the fake converts ~1500 poses per
simulated second. These do the same arithmetic as scipy 1.13's ``Rotation.from_quat(...).as_matrix()`` and
``Rotation.from_matrix(...).as_quat()`` (Markley's method) in plain Python floats, so published values do not
change (checked equal to ``transforms``' on 100,000 random poses, and the fake's images, poses and joint states
equal before and after, when they were introduced).
"""
import math

import numpy as np


def quat_to_matrix(quat_xyzw):
    """3x3 rotation matrix (list of rows) of a quaternion (x, y, z, w), normalised first (as scipy)."""
    x, y, z, w = (float(v) for v in quat_xyzw)
    norm = math.sqrt(x * x + y * y + z * z + w * w)
    x, y, z, w = x / norm, y / norm, z / norm, w / norm
    x2, y2, z2, w2 = x * x, y * y, z * z, w * w
    xy, zw, xz, yw, yz, xw = x * y, z * w, x * z, y * w, y * z, x * w
    return [[x2 - y2 - z2 + w2, 2 * (xy - zw), 2 * (xz + yw)],
            [2 * (xy + zw), -x2 + y2 - z2 + w2, 2 * (yz - xw)],
            [2 * (xz - yw), 2 * (yz + xw), -x2 - y2 + z2 + w2]]


def matrix_to_quat(R):
    """Quaternion (x, y, z, w) of a 3x3 rotation matrix (indexable ``R[i][j]`` or ``R[i, j]``), as scipy."""
    m = [[float(R[i][j]) for j in range(3)] for i in range(3)]
    trace = m[0][0] + m[1][1] + m[2][2]
    decision = (m[0][0], m[1][1], m[2][2], trace)
    choice = max(range(4), key=decision.__getitem__)        # the first largest, as scipy's argmax
    if choice != 3:
        i = choice
        j, k = (i + 1) % 3, (i + 2) % 3
        q = [0.0] * 4
        q[i] = 1 - trace + 2 * m[i][i]
        q[j] = m[j][i] + m[i][j]
        q[k] = m[k][i] + m[i][k]
        q[3] = m[k][j] - m[j][k]
    else:
        q = [m[2][1] - m[1][2], m[0][2] - m[2][0], m[1][0] - m[0][1], 1 + trace]
    norm = math.sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3])
    return [v / norm for v in q]


def from_xyz_quat(xyz, quat_xyzw):
    """4x4 transform from a position (m) and a quaternion (x, y, z, w): ``transforms.from_xyz_quat``."""
    (r0, r1, r2), (x, y, z) = quat_to_matrix(quat_xyzw), xyz
    return np.array([[*r0, x], [*r1, y], [*r2, z], [0.0, 0.0, 0.0, 1.0]], dtype=float)


def matrix_to_pose_msg(T, pose):
    """Fill a ``geometry_msgs/Pose`` from a 4x4 transform and return it: ``transforms.matrix_to_pose_msg``."""
    rows = T.tolist()
    pose.position.x, pose.position.y, pose.position.z = rows[0][3], rows[1][3], rows[2][3]
    pose.orientation.x, pose.orientation.y, pose.orientation.z, pose.orientation.w = matrix_to_quat(rows)
    return pose
