"""Visual-servo laws as pure functions: PBVS look-and-move, IBVS, 2.5D, adaptive gain, twists.

No ROS and no robot here: poses in, next pose or velocity out.

Conventions (see docs/ARCHITECTURE.md):

- ``T_a_b`` is the pose of frame ``b`` in frame ``a`` (4x4, metres).
- A *twist* is a 6-vector ``(v, w)``: ``v`` the linear velocity (m/s) of a frame's origin, ``w`` the
  angular velocity (rad/s); "twist in frame f" means both are expressed in ``f``'s axes. The same
  ordering as the Jacobians of ``kinematics.ArmKinematics`` ([linear; angular]).
- Image features are *normalised* coordinates ``x = X/Z``, ``y = Y/Z`` of points in the camera
  optical frame (x right, y down, z forward), as returned by ``CameraModel.undistort_points``.
- Gripper frame = Baxter's ``left_gripper``: origin at the fingertip plane, z along the fingers,
  fingers close along y.

Laws (Chaumette & Hutchinson, "Visual Servo Control Part I/II", IEEE RAM 2006/2007):

- ``look_and_move_step``: the thesis's "dynamic look and move" PBVS: move a fraction of the remaining
  displacement (SE(3) interpolation, as Corke's ``SE3.interp1``), then look again.
- ``ibvs_twist``: image-based, ``v = -lambda L^+ e`` on point features (eq. 2.6 of the thesis).
- ``hybrid_twist``: Malis's 2.5D law on ``(x, y, log Z/Z*, theta u)``.
- ``AdaptiveGain``: ViSP's ``vpAdaptiveGain``.
"""
import numpy as np
from scipy.linalg import expm, logm
from scipy.spatial.transform import Rotation

from baxter_pnp import transforms


# --------------------------------------------------------------------------------------------------
# PBVS: dynamic look-and-move (the thesis)

def interpolate_pose(T_a_from, T_a_to, s):
    """Pose a fraction ``s`` (0..1) of the way from ``T_a_from`` to ``T_a_to``.

    Translation is interpolated linearly (a straight line of the frame origin in ``a``), rotation by
    slerp (a constant rotation axis), as spatialmath's ``SE3.interp1``.
    """
    R_from = Rotation.from_matrix(T_a_from[:3, :3])
    R_rel = R_from.inv() * Rotation.from_matrix(T_a_to[:3, :3])
    R_s = R_from * Rotation.from_rotvec(s * R_rel.as_rotvec())
    p_s = (1.0 - s) * T_a_from[:3, 3] + s * T_a_to[:3, 3]
    return transforms.make_transform(R_s, p_s)


def _bounded_fraction(T_a_from, T_a_to, fraction, max_translation, max_rotation):
    """``fraction`` reduced so that the step moves at most ``max_translation`` (m) and rotates at
    most ``max_rotation`` (rad). One scale for both keeps the path a straight SE(3) interpolation."""
    s = float(fraction)
    distance = np.linalg.norm(T_a_to[:3, 3] - T_a_from[:3, 3])
    angle = transforms.rotation_angle_between(T_a_from, T_a_to)
    if max_translation is not None and distance * s > max_translation:
        s = max_translation / distance
    if max_rotation is not None and angle * s > max_rotation:
        s = max_rotation / angle
    return s


def look_and_move_step(T_base_gripper, T_base_goal, fraction, max_translation=None, max_rotation=None):
    """Next gripper pose of the thesis's dynamic look-and-move: ``fraction`` of the remaining motion.

    ``fraction`` is the thesis's 0.35 or 0.12 (Corke's PBVS ``lmbda``). The remaining error shrinks
    by ``(1 - fraction)`` per step, so reaching ``e`` from ``e0`` takes ``ln(e/e0) / ln(1 - fraction)``
    steps. ``max_translation`` (m) and ``max_rotation`` (rad) optionally bound the step; the whole
    step is scaled, so the path stays straight.

    Returns ``T_base_gripper_next`` (4x4). Works for any frame (gripper, camera) of the same body.
    """
    s = _bounded_fraction(T_base_gripper, T_base_goal, fraction, max_translation, max_rotation)
    return interpolate_pose(T_base_gripper, T_base_goal, s)


# --------------------------------------------------------------------------------------------------
# Gains

class AdaptiveGain:
    """ViSP's ``vpAdaptiveGain``: ``lambda(|e|) = (l0 - linf) exp(-l0' |e| / (l0 - linf)) + linf``.

    ``gain_at_zero`` = l0 (1/s), ``gain_at_infinity`` = linf (1/s), ``slope_at_zero`` = l0' (the slope
    of lambda at |e| = 0). High gain near convergence, low gain far away (where a high gain would
    saturate velocities or lose the target). ViSP's tuning: (4, 0.4, 30) in simulation.
    Call it on ``|e|`` (the laws below pass the infinity norm of the error, as ViSP's ``vpServo``).
    """

    def __init__(self, gain_at_zero, gain_at_infinity, slope_at_zero):
        self.gain_at_zero = float(gain_at_zero)
        self.gain_at_infinity = float(gain_at_infinity)
        self.slope_at_zero = float(slope_at_zero)

    def __call__(self, error_norm):
        span = self.gain_at_zero - self.gain_at_infinity
        if abs(span) <= np.finfo(float).eps:
            return self.gain_at_infinity
        return span * np.exp(-self.slope_at_zero * error_norm / span) + self.gain_at_infinity

    def __repr__(self):
        return 'AdaptiveGain(%g, %g, %g)' % (self.gain_at_zero, self.gain_at_infinity, self.slope_at_zero)


def _apply_gain(gain, unit_gain_twist):
    """``-lambda * unit_gain_twist`` with a constant gain, or a callable one (``AdaptiveGain``) evaluated,
    as in ViSP's ``vpServo::computeControlLaw``, on the infinity norm of the unit-gain twist ``L^+ e``."""
    value = gain(np.max(np.abs(unit_gain_twist))) if callable(gain) else gain
    return -float(value) * unit_gain_twist


# --------------------------------------------------------------------------------------------------
# IBVS

def interaction_matrix(points_xy, Z):
    """Stacked interaction matrices (2n, 6) of n image points (thesis eq. 2.6).

    ``points_xy`` (n, 2) normalised coordinates, ``Z`` (n,) or scalar depths (m) in the camera frame.
    Rows 2i, 2i+1 give ``(xdot_i, ydot_i) = L_i (v, w)`` for the camera twist in the camera frame,
    the points being static.
    """
    points_xy = np.atleast_2d(np.asarray(points_xy, dtype=float))
    x, y = points_xy[:, 0], points_xy[:, 1]
    inverse_Z = 1.0 / np.broadcast_to(np.asarray(Z, dtype=float), x.shape)
    zero = np.zeros_like(x)
    row_x = np.stack([-inverse_Z, zero, x * inverse_Z, x * y, -(1.0 + x * x), y], axis=1)
    row_y = np.stack([zero, -inverse_Z, y * inverse_Z, 1.0 + y * y, -x * y, -x], axis=1)
    return np.stack([row_x, row_y], axis=1).reshape(-1, 6)


def interaction_matrix_point(x, y, Z):
    """Interaction matrix (2, 6) of one image point (x, y) (normalised) at depth ``Z`` (m), eq. 2.6."""
    return interaction_matrix([[x, y]], [Z])


IBVS_VARIANTS = ('current', 'desired', 'mean')


def ibvs_twist(s, s_star, Z, Z_star, gain, variant='mean'):
    """IBVS camera twist ``v = -lambda L^+ (s - s*)`` (6,) in the camera frame (m/s, rad/s).

    ``s``, ``s_star`` (n, 2) current and desired normalised point coordinates; ``Z``, ``Z_star`` (n,)
    or scalar current and desired depths (m). ``gain`` (1/s) is a number or an ``AdaptiveGain``.
    ``variant`` picks the interaction-matrix estimate (ViSP's ``vpServoIteractionMatrixType``):
    'current' L(s, Z) (straight image paths, but the camera retreats under large rotations about the
    optical axis), 'desired' L(s*, Z*) (constant), 'mean' (L + L*)/2 (no retreat; the best of the three).
    """
    s = np.asarray(s, dtype=float)
    s_star = np.asarray(s_star, dtype=float)
    error = (s - s_star).ravel()
    if variant == 'current':
        L = interaction_matrix(s, Z)
    elif variant == 'desired':
        L = interaction_matrix(s_star, Z_star)
    elif variant == 'mean':
        L = 0.5 * (interaction_matrix(s, Z) + interaction_matrix(s_star, Z_star))
    else:
        raise ValueError('variant must be one of %s, not %r' % (IBVS_VARIANTS, variant))
    return _apply_gain(gain, np.linalg.pinv(L) @ error)


# --------------------------------------------------------------------------------------------------
# 2.5D visual servoing (Malis, Chaumette, Boudet 1999)

def _skew(w):
    """3x3 cross-product matrix: ``_skew(w) @ p == np.cross(w, p)``."""
    return np.array([[0.0, -w[2], w[1]], [w[2], 0.0, -w[0]], [-w[1], w[0], 0.0]])


def _sinc(a):
    """sin(a) / a (numpy's sinc is the normalised sin(pi a) / (pi a))."""
    return np.sinc(a / np.pi)


def theta_u_interaction_matrix(theta_u):
    """``L_w`` (3, 3) with ``d(theta u)/dt = L_w w`` for theta u of ``R_cstar_c`` and ``w`` the camera's
    angular velocity in its own frame: ``I - theta/2 [u]x + (1 - sinc(theta) / sinc^2(theta/2)) [u]x^2``.
    Singular only at theta = 2 pi; ``L_w theta u = theta u``."""
    theta = np.linalg.norm(theta_u)
    if theta < 1e-12:
        return np.eye(3)
    u_cross = _skew(np.asarray(theta_u) / theta)
    return np.eye(3) - 0.5 * theta * u_cross + (1.0 - _sinc(theta) / _sinc(0.5 * theta) ** 2) * u_cross @ u_cross


def hybrid_twist(x, y, Z, x_star, y_star, Z_star, R_cstar_c, gain):
    """2.5D camera twist (6,) in the camera frame (m/s, rad/s), on ``(x, y, log Z/Z*, theta u)``.

    ``(x, y)`` normalised coordinates and ``Z`` (m) depth of a reference point (e.g. the block's
    centre), ``(x_star, y_star, Z_star)`` their desired values; ``R_cstar_c`` (3, 3) the current camera
    orientation in the desired camera frame (from a pose estimate or a homography). ``gain`` (1/s) is
    a number or an ``AdaptiveGain``. The interaction matrix is block upper-triangular, so rotation is
    decoupled (``w = -lambda theta u``, a straight rotation path, no singularity up to and including
    pi), ``(x, y)`` decreases exponentially (a straight image trajectory of the reference point), and
    the camera does not retreat.
    """
    theta_u = Rotation.from_matrix(R_cstar_c).as_rotvec()
    error = np.concatenate([[x - x_star, y - y_star, np.log(Z / Z_star)], theta_u])
    L = np.zeros((6, 6))
    L[:3, :3] = np.array([[-1.0, 0.0, x], [0.0, -1.0, y], [0.0, 0.0, -1.0]]) / Z
    L[:3, 3:] = np.array([[x * y, -(1.0 + x * x), y], [1.0 + y * y, -x * y, -x], [-y, x, 0.0]])
    L[3:, 3:] = theta_u_interaction_matrix(theta_u)
    return _apply_gain(gain, np.linalg.solve(L, error))


# --------------------------------------------------------------------------------------------------
# Frames and joints

def velocity_twist_matrix(T_a_b):
    """6x6 ``aVb`` (ViSP's ``vpVelocityTwistMatrix``) for two frames fixed on one rigid body.

    Maps the body's twist given at ``b``'s origin in ``b``'s axes to the same motion given at ``a``'s
    origin in ``a``'s axes: ``w_a = R w_b``, ``v_a = R v_b + t x (R w_b)`` with ``(R, t) = T_a_b``.
    E.g. ``velocity_twist_matrix(T_gripper_camera) @ twist_camera`` is the gripper twist (gripper
    origin, gripper axes) that moves the camera with ``twist_camera``.
    """
    R, t = T_a_b[:3, :3], T_a_b[:3, 3]
    V = np.zeros((6, 6))
    V[:3, :3] = R
    V[:3, 3:] = _skew(t) @ R
    V[3:, 3:] = R
    return V


def camera_twist_to_base(twist_cam, T_base_camera):
    """Twist of the camera frame's origin, from camera axes to base axes (a pure rotation of v and w).

    To command a Jacobian of another point (e.g. ``left_gripper``), first move the reference point
    with ``velocity_twist_matrix``; ``ArmKinematics.jacobian(q, frame='left_hand_camera')`` takes it directly.
    """
    R = T_base_camera[:3, :3]
    twist_cam = np.asarray(twist_cam, dtype=float)
    return np.concatenate([R @ twist_cam[:3], R @ twist_cam[3:]])


def joint_velocities(J_base, twist_base, damping=1e-3, qdot_limits=None, q=None, lower=None, upper=None,
                     limit_margin=0.05, horizon=0.2):
    """Joint velocities (rad/s) giving ``twist_base`` by damped least squares.

    ``qdot = J^T (J J^T + damping^2 I)^-1 twist`` with ``J_base`` (6, n) [linear; angular] in base.
    ``damping`` (same units as J's singular values) bounds the velocities near singularities. With the
    current angles ``q`` and the joint limits ``lower``, ``upper`` (rad), a joint that the solution would
    take within ``limit_margin`` of a limit in ``horizon`` seconds (how long the robot applies a velocity
    command) is frozen (its Jacobian column removed) and the rest re-solved: a 7-joint arm keeps the twist
    with its other joints. If ``qdot_limits`` (n,) rad/s is given and exceeded, all joint velocities are
    divided by the same factor, so the end effector keeps the twist's direction at a lower speed.
    """
    J = np.asarray(J_base, dtype=float)
    twist = np.asarray(twist_base, dtype=float)
    free = np.ones(J.shape[1], dtype=bool)
    while True:
        J_free = J * free
        qdot = J_free.T @ np.linalg.solve(J_free @ J_free.T + damping ** 2 * np.eye(J.shape[0]), twist)
        if q is None:
            break
        ahead = np.asarray(q) + qdot * horizon
        blocked = free & (((ahead <= np.asarray(lower) + limit_margin) & (qdot < 0)) |
                          ((ahead >= np.asarray(upper) - limit_margin) & (qdot > 0)))
        if not blocked.any():
            break
        free &= ~blocked
    if qdot_limits is not None:
        overshoot = np.max(np.abs(qdot) / np.asarray(qdot_limits, dtype=float))
        if overshoot > 1.0:
            qdot = qdot / overshoot
    return qdot


def integrate_twist(T_a_b, twist_b, dt):
    """Pose of frame ``b`` after moving with a constant twist (in ``b``'s frame) for ``dt`` seconds:
    ``T_a_b expm(dt [twist]^)`` (the SE(3) exponential; ViSP's ``vpExponentialMap::direct``)."""
    twist_b = np.asarray(twist_b, dtype=float)
    twist_hat = np.zeros((4, 4))
    twist_hat[:3, :3] = _skew(twist_b[3:])
    twist_hat[:3, 3] = twist_b[:3]
    return T_a_b @ expm(dt * twist_hat)


def twist_between(T_a_from, T_a_to, dt):
    """The constant twist (in the moving frame, (v m/s, w rad/s)) that takes a frame from ``T_a_from`` to
    ``T_a_to`` in ``dt`` seconds: the inverse of :func:`integrate_twist` (``logm`` of the relative pose)."""
    twist_hat = np.real(logm(transforms.invert(T_a_from) @ T_a_to)) / dt
    return np.concatenate([twist_hat[:3, 3], [twist_hat[2, 1], twist_hat[0, 2], twist_hat[1, 0]]])
