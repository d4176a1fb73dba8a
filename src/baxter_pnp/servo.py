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
import cv2
import numpy as np
from scipy.linalg import expm, logm
from scipy.spatial.transform import Rotation

from baxter_pnp import transforms

# Jaw gap of the electric gripper with the simulator's fingers (extended_narrow, slot 2, paddle tips),
# fully open (m). See shared/reference/baxter_kinematics.md section 3.
ELECTRIC_GRIPPER_MAX_OPENING = 0.0577


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


def ray_hits(origin, directions, solid):
    """(N,) bool: which rays ``origin + t * directions[i]``, t >= 0, meet ``solid`` (a
    ``kinematics.Solid``, a box or a cylinder along its z; all in the same frame, metres)."""
    R, t = solid.T[:3, :3], solid.T[:3, 3]
    o = R.T @ (np.asarray(origin, dtype=float) - t)         # in the solid's frame
    d = np.asarray(directions, dtype=float) @ R
    h = solid.half_extents
    with np.errstate(divide='ignore', invalid='ignore'):
        axes = slice(0, 3) if solid.kind == 'box' else slice(2, 3)      # slabs: all 3 axes, or z only
        near = (-h[axes] - o[axes]) / d[:, axes]
        far = (h[axes] - o[axes]) / d[:, axes]
        entry = np.max(np.minimum(near, far), axis=1)
        exit_ = np.min(np.maximum(near, far), axis=1)
        if solid.kind == 'cylinder':    # and inside the radius: |o_xy + t d_xy| <= r, a quadratic in t
            a = np.sum(d[:, :2] ** 2, axis=1)
            b = 2.0 * d[:, :2] @ o[:2]
            c = o[:2] @ o[:2] - h[0] ** 2
            root = np.sqrt(np.maximum(b * b - 4.0 * a * c, 0.0))
            crossing = b * b - 4.0 * a * c >= 0.0
            entry = np.where(crossing, np.maximum(entry, (-b - root) / (2.0 * a)), np.inf)
            exit_ = np.where(crossing, np.minimum(exit_, (-b + root) / (2.0 * a)), -np.inf)
    return exit_ >= np.maximum(entry, 0.0)


def hand_clearance_px(camera, hand_solids_camera):
    """(H, W) float32 map: each pixel's distance (pixels) to the nearest pixel where the hand hides the scene.

    ``camera`` is a ``CameraModel``; ``hand_solids_camera`` the hand's ``kinematics.Solid`` s in the camera
    optical frame (``ArmKinematics.hand_solids`` moved there). Every pixel's ray (distortion removed) is
    tested against every solid; hidden pixels are 0.
    """
    u, v = np.meshgrid(np.arange(camera.width, dtype=float), np.arange(camera.height, dtype=float))
    xy = camera.undistort_points(np.stack([u.ravel(), v.ravel()], axis=1))
    rays = np.column_stack([xy, np.ones(len(xy))])
    hidden = np.zeros(len(rays), dtype=bool)
    for solid in hand_solids_camera:
        hidden |= ray_hits(np.zeros(3), rays, solid)
    free = (~hidden).reshape(camera.height, camera.width).astype(np.uint8)
    return cv2.distanceTransform(free, cv2.DIST_L2, 5)


def polygon_clear(pixels, clearance_px, margin_px):
    """True if the convex polygon of ``pixels`` (N, 2) lies more than ``margin_px`` from every hidden pixel
    of ``clearance_px`` (see :func:`hand_clearance_px`)."""
    face = np.zeros(clearance_px.shape, np.uint8)
    cv2.fillConvexPoly(face, cv2.convexHull(np.round(pixels).astype(np.int32)), 1)
    inside = clearance_px[face > 0]
    return bool(inside.size == 0 or inside.min() > margin_px)


def points_in_view(T_base_camera, points_base, camera, margin_px=0.0, clearance_px=None):
    """True if every point (N,3) or (3,) in ``base`` is in front of the camera and projects at least
    ``margin_px`` pixels inside the image of ``camera`` (a ``CameraModel``; distorted pixels) and, given
    the hand's ``clearance_px`` map (:func:`hand_clearance_px`), their polygon is more than ``margin_px``
    from the pixels the hand hides."""
    points_camera = transforms.transform_points(transforms.invert(T_base_camera), np.atleast_2d(points_base))
    if np.any(points_camera[:, 2] <= 0.0):
        return False
    pixels = camera.project(points_camera)
    upper = np.array([camera.width - 1.0, camera.height - 1.0]) - margin_px
    if not (np.all(pixels >= margin_px) and np.all(pixels <= upper)):
        return False
    return clearance_px is None or polygon_clear(pixels, clearance_px, margin_px)


def path_in_view(T_base_gripper_from, T_base_gripper_to, points_base, camera, T_gripper_camera, margin_px=0.0,
                 clearance_px=None, samples=12):
    """True if ``points_in_view`` holds at ``samples`` poses evenly spread along the straight (SE(3)
    interpolated) gripper path between the two poses, both ends included."""
    return all(points_in_view(interpolate_pose(T_base_gripper_from, T_base_gripper_to, s) @ T_gripper_camera,
                              points_base, camera, margin_px, clearance_px)
               for s in np.linspace(0.0, 1.0, samples))


def keep_in_view_step(T_base_gripper, T_base_goal, fraction, points_base, camera, T_gripper_camera,
                      margin_px=20.0, max_translation=None, max_rotation=None, bisections=12, clearance_px=None):
    """``look_and_move_step`` that keeps ``points_base`` (the block's centre, or its vertices) in view.

    The step is split, in the camera's axes at the current pose, into a *lateral* translation
    (across the optical axis) and the rest: the *axial* translation (along the optical axis) plus
    the rotation. Approaching and rotating are what push an off-centre target out of the image
    (x = X/Z grows as Z shrinks), while the lateral motion toward the goal re-centres it. So:

    1. the full step, if the points stay ``margin_px`` inside the image after it;
    2. otherwise the full lateral step with the axial and rotation parts scaled by the largest factor
       in [0, 1] that keeps the points in view (bisection);
    3. otherwise (even the lateral step alone loses them) the lateral step alone, scaled likewise;
       if they are already out of view (with the margin) at the current pose, the whole lateral step:
       it moves the camera toward where it sees the block as it will from the goal, while approaching or
       rotating would push the block further out. ``camera`` is a ``CameraModel``,
    ``T_gripper_camera`` the camera's pose in the gripper frame; with the hand's ``clearance_px`` map
    (:func:`hand_clearance_px`) "in view" also means not behind (nor within ``margin_px`` of) a finger.
    Returns ``T_base_gripper_next``.
    """
    def in_view(T_base_gripper_candidate):
        return points_in_view(T_base_gripper_candidate @ T_gripper_camera, points_base, camera, margin_px,
                              clearance_px)

    full_step = look_and_move_step(T_base_gripper, T_base_goal, fraction, max_translation, max_rotation)
    if in_view(full_step):
        return full_step

    R_base_camera = T_base_gripper[:3, :3] @ T_gripper_camera[:3, :3]
    translation_camera = R_base_camera.T @ (full_step[:3, 3] - T_base_gripper[:3, 3])
    lateral_base = R_base_camera @ np.array([translation_camera[0], translation_camera[1], 0.0])
    axial_base = R_base_camera @ np.array([0.0, 0.0, translation_camera[2]])
    rotvec_gripper = Rotation.from_matrix(T_base_gripper[:3, :3].T @ full_step[:3, :3]).as_rotvec()

    def step(lateral_scale, rest_scale):
        rotation = Rotation.from_matrix(T_base_gripper[:3, :3]) * Rotation.from_rotvec(rest_scale * rotvec_gripper)
        translation = T_base_gripper[:3, 3] + lateral_scale * lateral_base + rest_scale * axial_base
        return transforms.make_transform(rotation, translation)

    def largest_feasible(candidate):
        """Largest a in [0, 1] with candidate(a) in view, given candidate(0) in view (bisection)."""
        feasible, infeasible = 0.0, 1.0
        for _ in range(bisections):
            middle = 0.5 * (feasible + infeasible)
            if in_view(candidate(middle)):
                feasible = middle
            else:
                infeasible = middle
        return candidate(feasible)

    if in_view(step(1.0, 0.0)):
        return largest_feasible(lambda a: step(1.0, a))
    if in_view(T_base_gripper):
        return largest_feasible(lambda b: step(b, 0.0))
    return step(1.0, 0.0)


def grasp_width(side_length, symmetry_angle):
    """Jaw gap (m) needed to grasp a regular polygonal prism across the block's x axis.

    Even n: across two parallel faces, ``2 * apothem``; odd n: from a face to the opposite vertex,
    ``apothem + circumradius``. ``n = 2 pi / symmetry_angle``.
    """
    n = int(round(2.0 * np.pi / symmetry_angle))
    apothem = side_length / (2.0 * np.tan(np.pi / n))
    circumradius = side_length / (2.0 * np.sin(np.pi / n))
    return 2.0 * apothem if n % 2 == 0 else apothem + circumradius


def grasp_goal(T_base_block, side_length, grasp_depth, approach_height, symmetry_angle, T_base_gripper_current,
               max_opening=ELECTRIC_GRIPPER_MAX_OPENING):
    """Gripper pose (``left_gripper`` in base) to grasp the block, or to hover above it.

    - Gripper z = -block z (fingers pointing down, toward the table).
    - Fingers close along the block's x axis (the normal of the face perpendicular to +x, see the
      block frame in docs/ARCHITECTURE.md) or one of its symmetric copies: the block is invariant under
      rotations by ``symmetry_angle`` (2 pi / n, rad) about its z and a parallel-jaw gripper under
      pi about its own z, so the candidate yaws are ``k * symmetry_angle`` and ``k * symmetry_angle + pi``.
      The candidate with the smallest rotation from ``T_base_gripper_current`` is chosen (the thesis
      kept the start orientation instead, which caused occlusion and collisions).
    - Origin (fingertip plane) ``grasp_depth`` (m) below the top face's centre, then raised by
      ``approach_height`` (m) along the block's z (0 for the grasp itself, > 0 for a pre-grasp pose).

    ``side_length`` (m) gives the jaw gap needed (``grasp_width``); a ``ValueError`` is raised if it
    exceeds ``max_opening`` (m; None disables the check).
    """
    width = grasp_width(side_length, symmetry_angle)
    if max_opening is not None and width > max_opening:
        raise ValueError('block of side %.3f m needs a %.3f m jaw gap, more than the gripper opening %.3f m'
                         % (side_length, width, max_opening))
    best = grasp_orientations(T_base_block, symmetry_angle, T_base_gripper_current)[0]
    position = T_base_block[:3, 3] + T_base_block[:3, 2] * (approach_height - grasp_depth)
    return transforms.make_transform(best, position)


def grasp_orientations(T_base_block, symmetry_angle, T_base_gripper_current):
    """The distinct gripper orientations (``Rotation`` s, base) that grasp the block across a pair of faces
    (see :func:`grasp_goal`), the smallest rotation from ``T_base_gripper_current`` first."""
    R_base_block = Rotation.from_matrix(T_base_block[:3, :3])
    # gripper x = block y, gripper y = block x (closing axis), gripper z = -block z
    R_block_gripper = Rotation.from_euler('z', np.pi / 2) * Rotation.from_euler('x', np.pi)
    n = int(round(2.0 * np.pi / symmetry_angle))
    yaws = np.concatenate([np.arange(n) * symmetry_angle, np.arange(n) * symmetry_angle + np.pi])
    R_current = Rotation.from_matrix(T_base_gripper_current[:3, :3])
    candidates = []
    for R in sorted((R_base_block * Rotation.from_euler('z', yaw) * R_block_gripper for yaw in yaws),
                    key=lambda R: (R_current.inv() * R).magnitude()):
        if all((R.inv() * other).magnitude() > 1e-6 for other in candidates):
            candidates.append(R)
    return candidates


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
