"""Visual-servo laws (baxter_pnp.servo) on a free-flying simulated camera and on the Baxter hand geometry.

The 4-point scene is ViSP's IBVS tutorial scene scaled by 0.2 to a 40 mm square: start
cMo = (0.03, -0.02, 0.20 m, theta u = 10, -10, 50 deg), goal cdMo = (0, 0, 0.15 m); 40 ms steps, the
twist integrated with the SE(3) exponential, stop when sum((s - s*)^2) < 1e-4 (normalised coordinates).
Normalised image coordinates are scale-invariant, so iteration counts compare with ViSP's (191 with
lambda = 0.5, 91 with vpAdaptiveGain(4, 0.4, 30)). Run with -s to see the measured counts.
"""
import math

import numpy as np
import pytest
from scipy.linalg import logm
from scipy.spatial.transform import Rotation

from baxter_pnp import pick, servo, view
from baxter_pnp import transforms as tf
from baxter_pnp.camera import load_default_camera

SCALE = 0.2
SQUARE_OBJECT = np.array([[-1, -1, 0], [1, -1, 0], [1, 1, 0], [-1, 1, 0]], dtype=float) * 0.1 * SCALE
DT = 0.04
TOLERANCE = 1e-4


def camera_in_object(translation, theta_u_deg):
    """T_object_camera from ViSP's cMo = (translation (unscaled m), theta u (deg))."""
    T_camera_object = tf.make_transform(Rotation.from_rotvec(np.radians(theta_u_deg)),
                                        np.asarray(translation) * SCALE)
    return tf.invert(T_camera_object)


VISP_START = camera_in_object([0.15, -0.1, 1.0], [10, -10, 50])
VISP_GOAL = camera_in_object([0.0, 0.0, 0.75], [0, 0, 0])


def image_points(T_object_camera, points_object=SQUARE_OBJECT):
    """(normalised (n, 2), depths (n,)) of object points seen from the camera."""
    points_camera = tf.transform_points(tf.invert(T_object_camera), points_object)
    return points_camera[:, :2] / points_camera[:, 2:], points_camera[:, 2]


def servo_camera(law, T_object_camera, T_object_camera_goal, gain=0.5, max_iterations=1000):
    """Run one law; returns (iterations or None if it failed, trajectory of T_object_camera)."""
    s_star, Z_star = image_points(T_object_camera_goal)
    T_goal_object = tf.invert(T_object_camera_goal)
    trajectory = [T_object_camera]
    for iteration in range(max_iterations):
        s, Z = image_points(T_object_camera)
        if np.any(Z <= 0.0) or not np.all(np.isfinite(s)):
            return None, trajectory
        if np.sum((s - s_star) ** 2) < TOLERANCE:
            return iteration, trajectory
        if law == 'pbvs':
            T_object_camera = servo.look_and_move_step(T_object_camera, T_object_camera_goal, gain * DT)
        else:
            if law == 'hybrid':  # reference point: the square's centre (object origin)
                centre = tf.invert(T_object_camera)[:3, 3]
                centre_star = T_goal_object[:3, 3]
                R_cstar_c = T_goal_object[:3, :3] @ T_object_camera[:3, :3]
                twist = servo.hybrid_twist(centre[0] / centre[2], centre[1] / centre[2], centre[2],
                                           centre_star[0] / centre_star[2], centre_star[1] / centre_star[2],
                                           centre_star[2], R_cstar_c, gain)
            else:
                twist = servo.ibvs_twist(s, s_star, Z, Z_star, gain, variant=law)
            T_object_camera = servo.integrate_twist(T_object_camera, twist, DT)
        trajectory.append(T_object_camera)
    return None, trajectory


def assert_reached(T_object_camera, T_object_camera_goal):
    """The image criterion sum(e^2) < 1e-4 leaves about 1 % of the depth and 1-2 deg of pose error."""
    assert np.linalg.norm(T_object_camera[:3, 3] - T_object_camera_goal[:3, 3]) < 0.003
    assert np.degrees(tf.rotation_angle_between(T_object_camera, T_object_camera_goal)) < 2.0


def retreat(trajectory, T_object_camera_goal):
    """How far (m) the camera went beyond the farther of its start and goal distances to the object."""
    distances = [np.linalg.norm(T[:3, 3]) for T in trajectory]
    return max(distances) - max(distances[0], np.linalg.norm(T_object_camera_goal[:3, 3]))


# --------------------------------------------------------------------------------------------------
# IBVS

def test_interaction_matrix_matches_finite_differences():
    rng = np.random.default_rng(1)
    point_camera = np.array([0.03, -0.02, 0.18])
    x, y = point_camera[:2] / point_camera[2]
    L = servo.interaction_matrix_point(x, y, point_camera[2])
    assert L.shape == (2, 6)
    h = 1e-6
    for _ in range(5):
        twist = rng.normal(size=6)
        # the point is static; the camera moves with `twist` (camera frame) for +-h seconds
        after = tf.transform_points(tf.invert(servo.integrate_twist(np.eye(4), twist, h)), point_camera[None])[0]
        before = tf.transform_points(tf.invert(servo.integrate_twist(np.eye(4), twist, -h)), point_camera[None])[0]
        xy_rate = (after[:2] / after[2] - before[:2] / before[2]) / (2 * h)
        np.testing.assert_allclose(L @ twist, xy_rate, rtol=1e-6, atol=1e-8)

    points = rng.uniform(-0.3, 0.3, size=(4, 2))
    depths = rng.uniform(0.1, 1.0, size=4)
    stacked = servo.interaction_matrix(points, depths)
    for i in range(4):
        np.testing.assert_array_equal(stacked[2 * i:2 * i + 2], servo.interaction_matrix_point(*points[i], depths[i]))


@pytest.mark.parametrize('law', ['current', 'desired', 'mean', 'hybrid', 'pbvs'])
def test_every_law_converges_from_the_visp_start(law):
    iterations, trajectory = servo_camera(law, VISP_START, VISP_GOAL)
    print('\n%s: %s iterations from the ViSP start (lambda = 0.5, 40 ms)' % (law, iterations))
    assert iterations is not None and iterations < 300
    assert_reached(trajectory[-1], VISP_GOAL)
    if law == 'current':  # ViSP tutorial-ibvs-4pts-plotter: 191 iterations, same law and scene
        assert abs(iterations - 191) <= 2


def test_ibvs_mean_avoids_the_camera_retreat_of_current_at_160_degrees():
    start = camera_in_object([0.0, 0.0, 0.75], [0, 0, 160])
    iterations_current, trajectory_current = servo_camera('current', start, VISP_GOAL)
    iterations_mean, trajectory_mean = servo_camera('mean', start, VISP_GOAL)
    iterations_desired, _ = servo_camera('desired', start, VISP_GOAL)
    retreat_current, retreat_mean = retreat(trajectory_current, VISP_GOAL), retreat(trajectory_mean, VISP_GOAL)
    print('\n160 deg: current %s it, retreat %.3f m (scene at 0.15 m); mean %s it, retreat %.2g m; desired %s'
          % (iterations_current, retreat_current, iterations_mean, retreat_mean, iterations_desired))
    assert iterations_current is not None and iterations_mean is not None
    assert retreat_current > 0.3          # twice the goal distance
    assert retreat_mean < 1e-3
    assert iterations_desired is None     # L* drives the points behind the camera (Chaumette 1998)


def test_hybrid_converges_at_180_degrees_where_ibvs_fails():
    start = camera_in_object([0.0, 0.0, 0.75], [0, 0, 180])
    iterations, trajectory = servo_camera('hybrid', start, VISP_GOAL)
    print('\n180 deg: 2.5D %s iterations' % iterations)
    assert iterations is not None
    assert_reached(trajectory[-1], VISP_GOAL)
    assert retreat(trajectory, VISP_GOAL) < 1e-3
    for variant in ('current', 'mean'):
        assert servo_camera(variant, start, VISP_GOAL, max_iterations=400)[0] is None


def test_hybrid_keeps_the_reference_point_image_path_straight():
    def largest_deviation_from_a_straight_image_path(law):
        """Largest distance of the square centre's image from the start-goal segment, / its length."""
        _, trajectory = servo_camera(law, VISP_START, VISP_GOAL)
        centre = np.array([image_points(T, np.zeros((1, 3)))[0][0] for T in trajectory])
        chord = centre[-1] - centre[0]
        offsets = centre - centre[0]
        return np.max(np.abs(offsets[:, 0] * chord[1] - offsets[:, 1] * chord[0])) / np.dot(chord, chord)

    hybrid = largest_deviation_from_a_straight_image_path('hybrid')
    pbvs = largest_deviation_from_a_straight_image_path('pbvs')
    print('\ncentre image path off the straight line: 2.5D %.2g, PBVS %.2g (fraction of its length)' % (hybrid, pbvs))
    assert hybrid < 0.005      # straight up to the 40 ms discretisation
    assert pbvs > 20 * hybrid  # PBVS does not control the image path


# --------------------------------------------------------------------------------------------------
# Gains

def test_adaptive_gain_formula():
    gain = servo.AdaptiveGain(4.0, 0.4, 30.0)
    assert gain(0.0) == pytest.approx(4.0)
    assert gain(10.0) == pytest.approx(0.4)
    h = 1e-7
    assert (gain(h) - gain(0.0)) / h == pytest.approx(-30.0, rel=1e-4)
    assert servo.AdaptiveGain(0.5, 0.5, 30.0)(0.3) == 0.5


@pytest.mark.parametrize('law', ['current', 'hybrid'])
def test_adaptive_gain_reduces_the_iteration_count(law):
    constant, _ = servo_camera(law, VISP_START, VISP_GOAL, gain=0.5)
    adaptive, trajectory = servo_camera(law, VISP_START, VISP_GOAL, gain=servo.AdaptiveGain(4.0, 0.4, 30.0))
    print('\n%s: constant 0.5 -> %s iterations, AdaptiveGain(4, 0.4, 30) -> %s' % (law, constant, adaptive))
    assert constant is not None and adaptive is not None
    assert adaptive < 0.6 * constant
    assert_reached(trajectory[-1], VISP_GOAL)


# --------------------------------------------------------------------------------------------------
# PBVS look-and-move

@pytest.mark.parametrize('fraction', [0.35, 0.12])
def test_look_and_move_reaches_2mm_in_the_predicted_number_of_steps(fraction):
    start = tf.make_transform(Rotation.from_euler('xyz', [3.0, 0.2, 0.5]), (0.6, 0.3, 0.1))
    goal = tf.make_transform(Rotation.from_euler('xyz', [3.1, 0.0, -0.2]), start[:3, 3] + (0.12, -0.16, 0.0))
    T, steps = start, 0
    while np.linalg.norm(T[:3, 3] - goal[:3, 3]) > 0.002:
        T_next = servo.look_and_move_step(T, goal, fraction)
        # straight line: each step moves the position along the start-goal segment by `fraction`
        np.testing.assert_allclose(T_next[:3, 3] - goal[:3, 3], (1 - fraction) * (T[:3, 3] - goal[:3, 3]), atol=1e-12)
        assert tf.rotation_angle_between(T_next, goal) == pytest.approx(
            (1 - fraction) * tf.rotation_angle_between(T, goal), abs=1e-9)
        T, steps = T_next, steps + 1
    predicted = math.ceil(math.log(0.002 / 0.2) / math.log(1 - fraction))
    print('\nfraction %.2f: 200 mm -> 2 mm in %d steps (ln(e/e0)/ln(1-lambda) = %.2f)'
          % (fraction, steps, math.log(0.002 / 0.2) / math.log(1 - fraction)))
    assert steps == predicted
    assert steps == {0.35: 11, 0.12: 37}[fraction]


def test_look_and_move_bounds_the_step():
    start = tf.make_transform(None, (0.0, 0.0, 0.0))
    goal = tf.make_transform(Rotation.from_euler('z', 1.0), (0.3, 0.0, 0.0))
    T = servo.look_and_move_step(start, goal, 0.35, max_translation=0.02)
    assert np.linalg.norm(T[:3, 3]) == pytest.approx(0.02)
    assert tf.rotation_angle_between(start, T) == pytest.approx(1.0 * 0.02 / 0.3)
    T = servo.look_and_move_step(start, goal, 0.35, max_translation=0.5, max_rotation=0.1)
    assert tf.rotation_angle_between(start, T) == pytest.approx(0.1)
    assert np.linalg.norm(T[:3, 3]) == pytest.approx(0.3 * 0.1)


# --------------------------------------------------------------------------------------------------
# Grasp goal and keep-in-view, on the Baxter left hand geometry (shared/reference/baxter_kinematics.md)

T_HAND_CAMERA = tf.make_transform(np.array([[0.0, 1, 0], [-1, 0, 0], [0, 0, 1]]), (0.03825, 0.012, 0.015355))
T_HAND_GRIPPER = tf.make_transform(None, (0.0, 0.0, 0.1577))
T_GRIPPER_CAMERA = tf.invert(T_HAND_GRIPPER) @ T_HAND_CAMERA
POINTING_DOWN = Rotation.from_euler('x', np.pi)


def yaw_of_closing_axis(T_base_gripper):
    """Angle (rad) of the gripper's y axis (closing direction) in the base xy plane."""
    return math.atan2(T_base_gripper[1, 1], T_base_gripper[0, 1])


def angle_difference(a, b):
    return abs((a - b + np.pi) % (2 * np.pi) - np.pi)


@pytest.mark.parametrize('n', [3, 4, 5, 6])
def test_grasp_goal_picks_the_symmetric_yaw_closest_to_the_current_one(n):
    block_yaw = 0.3
    T_base_block = tf.make_transform(Rotation.from_euler('z', block_yaw), (0.7, 0.2, -0.13))
    symmetry = 2 * np.pi / n
    side = 0.025
    for current_yaw in np.linspace(-np.pi, np.pi, 37):
        current = tf.make_transform(Rotation.from_euler('z', current_yaw) * POINTING_DOWN, (0.6, 0.1, 0.2))
        goal = pick.grasp_goal(T_base_block, side, grasp_depth=0.015, approach_height=0.05,
                                symmetry_angle=symmetry, T_base_gripper_current=current)
        np.testing.assert_allclose(goal[:3, 2], [0, 0, -1], atol=1e-12)           # fingers down
        np.testing.assert_allclose(goal[:3, 3], [0.7, 0.2, -0.13 + 0.05 - 0.015], atol=1e-12)
        chosen = yaw_of_closing_axis(goal)
        # the closing axis is an edge normal of the block, up to the gripper's own half-turn symmetry
        candidates = block_yaw + np.arange(2 * n) * symmetry / 2 if n % 2 else block_yaw + np.arange(n) * symmetry
        assert min(angle_difference(chosen, c) for c in candidates) < 1e-9
        # and the closest one to the current closing axis
        current_closing = yaw_of_closing_axis(current)
        best = min(angle_difference(current_closing, c) for c in candidates)
        assert angle_difference(chosen, current_closing) == pytest.approx(best, abs=1e-9)


def test_grasp_goal_follows_a_tilted_block_and_rejects_too_wide_blocks():
    T_base_block = tf.make_transform(Rotation.from_euler('xyz', [0.1, -0.05, 0.4]), (0.7, 0.2, -0.13))
    current = tf.make_transform(POINTING_DOWN, (0.6, 0.1, 0.2))
    goal = pick.grasp_goal(T_base_block, 0.04, 0.015, 0.0, np.pi / 2, current)
    np.testing.assert_allclose(goal[:3, 2], -T_base_block[:3, 2], atol=1e-12)
    np.testing.assert_allclose(goal[:3, 3], T_base_block[:3, 3] - 0.015 * T_base_block[:3, 2], atol=1e-12)
    assert pick.grasp_width(0.04, np.pi / 3) == pytest.approx(0.04 * math.sqrt(3))  # hexagon across flats
    with pytest.raises(ValueError):
        pick.grasp_goal(T_base_block, 0.04, 0.015, 0.0, np.pi / 3, current)


def test_keep_in_view_step_keeps_the_block_in_the_image_where_look_and_move_loses_it():
    camera = load_default_camera()
    T_base_block = tf.make_transform(None, (0.7, 0.2, -0.13))
    block_points = tf.transform_points(T_base_block, np.array(
        [[0, 0, 0], [0.02, 0.02, 0], [-0.02, 0.02, 0], [-0.02, -0.02, 0], [0.02, -0.02, 0]]))
    # gripper pointing down, 0.1 m above and beside the grasp pose, yawed 44 deg: the block is near
    # the image's top-left corner, and rotating to the goal yaw swings it out of the image
    goal = pick.grasp_goal(T_base_block, 0.04, 0.015, 0.0, np.pi / 2, tf.make_transform(POINTING_DOWN))
    start = goal @ tf.make_transform(Rotation.from_euler('z', np.radians(44)))
    start[:3, 3] += (0.1, 0.05, 0.1)
    assert np.array_equal(pick.grasp_goal(T_base_block, 0.04, 0.015, 0.0, np.pi / 2, start), goal)
    assert view.points_in_view(start @ T_GRIPPER_CAMERA, block_points, camera, margin_px=20)
    assert view.points_in_view(goal @ T_GRIPPER_CAMERA, block_points, camera, margin_px=20)

    def run(step):
        T, frames_out = start, 0
        for steps in range(1, 60):
            T = step(T)
            frames_out += not view.points_in_view(T @ T_GRIPPER_CAMERA, block_points, camera)
            if np.linalg.norm(T[:3, 3] - goal[:3, 3]) < 0.002 and tf.rotation_angle_between(T, goal) < np.radians(0.5):
                return steps, frames_out
        return None, frames_out

    plain_steps, plain_out = run(lambda T: servo.look_and_move_step(T, goal, 0.35))

    def guarded(T):
        T_next = view.keep_in_view_step(T, goal, 0.35, block_points, camera, T_GRIPPER_CAMERA, margin_px=20)
        assert view.points_in_view(T_next @ T_GRIPPER_CAMERA, block_points, camera, margin_px=20 - 1e-6)
        return T_next

    guarded_steps, guarded_out = run(guarded)
    print('\nlook_and_move: %s steps, block out of the image in %d; keep_in_view: %s steps, %d out'
          % (plain_steps, plain_out, guarded_steps, guarded_out))
    assert plain_out > 0
    assert guarded_out == 0 and guarded_steps is not None and guarded_steps <= plain_steps + 3


# --------------------------------------------------------------------------------------------------
# Frames and joints

def test_velocity_twist_matrix_maps_the_motion_of_one_rigid_body():
    rng = np.random.default_rng(2)
    T_a_b = tf.make_transform(Rotation.random(random_state=3), rng.normal(size=3) * 0.1)
    twist_b = rng.normal(size=6)
    dt = 0.3  # exact for any dt: T_a_b exp(dt twist_b^) T_b_a = exp(dt (aVb twist_b)^)
    motion_a = T_a_b @ servo.integrate_twist(np.eye(4), twist_b, dt) @ tf.invert(T_a_b)
    twist_hat = np.real(logm(motion_a)) / dt
    twist_a = np.concatenate([twist_hat[:3, 3], [twist_hat[2, 1], twist_hat[0, 2], twist_hat[1, 0]]])
    np.testing.assert_allclose(servo.velocity_twist_matrix(T_a_b) @ twist_b, twist_a, atol=1e-9)


def test_camera_twist_to_base_is_the_camera_origin_velocity_in_base():
    T_base_camera = tf.make_transform(Rotation.random(random_state=4), (0.6, 0.2, 0.1))
    twist_camera = np.array([0.05, -0.02, 0.1, 0.3, -0.1, 0.2])
    h = 1e-6
    after = servo.integrate_twist(T_base_camera, twist_camera, h)
    before = servo.integrate_twist(T_base_camera, twist_camera, -h)
    twist_base = servo.camera_twist_to_base(twist_camera, T_base_camera)
    np.testing.assert_allclose(twist_base[:3], (after[:3, 3] - before[:3, 3]) / (2 * h), atol=1e-8)
    rotation_rate = Rotation.from_matrix(after[:3, :3] @ before[:3, :3].T).as_rotvec() / (2 * h)
    np.testing.assert_allclose(twist_base[3:], rotation_rate, atol=1e-6)


def test_joint_velocities_reproduce_the_twist_and_respect_limits():
    rng = np.random.default_rng(5)
    U, _, Vt = np.linalg.svd(rng.normal(size=(6, 7)))
    J = U @ np.hstack([np.diag(np.linspace(0.3, 1.0, 6)), np.zeros((6, 1))]) @ Vt   # condition number 3.3
    twist = rng.normal(size=6) * 0.1
    qdot = servo.joint_velocities(J, twist)
    np.testing.assert_allclose(J @ qdot, twist, rtol=1e-4, atol=1e-6)
    # the minimum-norm solution: no component in the null space
    assert abs(Vt[6] @ qdot) < 1e-9

    limits = np.full(7, 0.5 * np.max(np.abs(qdot)))
    limited = servo.joint_velocities(J, twist, qdot_limits=limits)
    assert np.all(np.abs(limited) <= limits + 1e-12)
    assert np.max(np.abs(limited) / limits) == pytest.approx(1.0)
    np.testing.assert_allclose(limited, 0.5 * qdot, rtol=1e-9)      # same direction, half the speed
    achieved = J @ limited
    assert achieved @ twist / (np.linalg.norm(achieved) * np.linalg.norm(twist)) == pytest.approx(1.0, abs=1e-8)


def test_joint_velocities_freeze_a_joint_at_its_limit_and_keep_the_twist():
    rng = np.random.default_rng(5)
    J = rng.normal(size=(6, 7))
    twist = rng.normal(size=6)
    free = servo.joint_velocities(J, twist, damping=1e-6)
    joint = int(np.argmax(np.abs(free)))
    lower, upper = np.full(7, -2.0), np.full(7, 2.0)
    q = np.zeros(7)
    q[joint] = (lower if free[joint] < 0 else upper)[joint] - np.sign(free[joint]) * 0.01   # at the limit it heads to
    limited = servo.joint_velocities(J, twist, damping=1e-6, q=q, lower=lower, upper=upper)
    assert limited[joint] == 0.0
    np.testing.assert_allclose(J @ limited, twist, atol=1e-6)       # the other six joints still give the twist


def test_joint_velocities_freeze_a_joint_that_would_pass_its_limit_within_the_command_horizon():
    """A joint 0.16 rad from its limit, heading there at about 1 rad/s (the trials' elbow failure): one
    command lasts 0.2 s, so it must be frozen now, not when it is already within the margin."""
    rng = np.random.default_rng(5)
    J = rng.normal(size=(6, 7))
    twist = rng.normal(size=6)
    free = servo.joint_velocities(J, twist, damping=1e-6)
    joint = int(np.argmax(np.abs(free)))
    twist *= 1.0 / abs(free[joint])                  # that joint at 1 rad/s
    lower, upper = np.full(7, -2.0), np.full(7, 2.0)
    q = np.zeros(7)
    q[joint] = (lower if free[joint] < 0 else upper)[joint] - np.sign(free[joint]) * 0.16
    limited = servo.joint_velocities(J, twist, damping=1e-6, q=q, lower=lower, upper=upper, horizon=0.2)
    assert limited[joint] == 0.0
    ahead = q + 0.2 * limited
    assert np.all(ahead > lower) and np.all(ahead < upper)
    assert servo.joint_velocities(J, twist, damping=1e-6, q=q, lower=lower, upper=upper, horizon=0.05)[joint] != 0.0


def test_ray_hits_boxes_and_cylinders():
    from baxter_pnp.kinematics import Solid
    box = Solid("box", tf.make_transform(Rotation.identity(), (0.0, 0.0, 1.0)), np.array([0.1, 0.2, 0.05]))
    cylinder = Solid("cylinder", tf.make_transform(Rotation.from_euler('x', np.pi / 2), (0.0, 0.0, 1.0)),
                     np.array([0.1, 0.1, 0.3]))     # axis along camera y, radius 0.1, 0.6 long
    rays = np.array([[0.0, 0.0, 1.0], [0.09, 0.0, 1.0], [0.11, 0.0, 1.0], [0.0, 0.19, 1.0], [0.0, 0.22, 1.0],
                     [0.0, 0.0, -1.0], [0.08, 0.08, 1.0]])
    np.testing.assert_array_equal(view.ray_hits(np.zeros(3), rays, box),
                                  [True, True, False, True, False, False, True])
    # its square bounding box would take the corner ray (0.105, 0, 1): the cylinder does not
    rays = np.array([[0.0, 0.0, 1.0], [0.095, 0.28, 1.0], [0.0, 0.32, 1.0], [0.0, 0.36, 1.0], [0.105, 0.0, 1.0]])
    np.testing.assert_array_equal(view.ray_hits(np.zeros(3), rays, cylinder), [True, True, True, False, False])
    bounding_box = Solid('box', cylinder.T, cylinder.half_extents)
    assert view.ray_hits(np.zeros(3), rays[4:], bounding_box)[0]
