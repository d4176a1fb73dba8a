"""The pure pick-task layer (pick.py): configuration, geometry, servo targets, features."""
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from baxter_pnp import models, pick, servo, view
from baxter_pnp.camera import load_default_camera
from baxter_pnp.transforms import invert, make_transform, pose_error, transform_points

# The hand camera in the gripper frame (left_gripper -> left_hand_camera, baxter_kinematics.md §2).
T_GRIPPER_CAMERA = make_transform(Rotation.from_euler('z', -np.pi / 2), (0.03825, 0.012, -0.142345))
CAMERA = load_default_camera().scaled(640, 400)


def block_at(x, y, yaw, table_top_z=-0.15, height=0.02):
    return make_transform(Rotation.from_euler('z', yaw), (x, y, table_top_z + height))


def gripper_down_at(x, y, z, yaw=0.0):
    return make_transform(Rotation.from_euler('z', yaw) * Rotation.from_euler('x', np.pi), (x, y, z))


def test_config_validation_names_the_key():
    assert pick.PickConfig.from_dict({'mode': 'ibvs'}).mode == 'ibvs'
    for values, key in (({'mode': 'teleport'}, 'mode'), ({'step_fraction': 0.0}, 'step_fraction'),
                        ({'side_length': -1}, 'side_length'), ({'grasp_depth': 0.05}, 'grasp_depth'),
                        ({'place_xy': [0.5]}, 'place_xy'), ({'gain': [0.1, 1.0, 3]}, 'gain'),
                        ({'edge_radius': -0.001}, 'edge_radius'), ({'edge_radius': 0.012}, 'edge_radius'),
                        ({'far_height_error': 0.01}, 'far_height_error'),
                        ({'colur': 'green'}, 'colur')):
        with pytest.raises(ValueError, match=key):
            pick.PickConfig.from_dict(values)


def test_a_block_the_gripper_cannot_grip_is_refused_before_the_robot_is_asked():
    """The jaw gap closed and open (``gripper_gap``, slot 2's 16 / 57.7 mm by default): a block across the fingers
    narrower than closed + 3 mm (the pads' squeeze) or wider than open is a ParameterError naming ``side_length``;
    a 16 mm die is gripped with the fingers in slot 1."""
    assert pick.PickConfig.from_dict({'side_length': 0.019}).gripper_gap == [0.016, 0.0577]
    for values, why in (({'side_length': 0.0185}, 'less than the gripper closed'),
                        ({'side_length': 0.021, 'shape': 'triangle'}, 'less than the gripper closed'),   # 18.2 mm
                        ({'side_length': 0.04, 'shape': 'hexagon'}, 'more than the gripper opens'),      # 69 mm
                        ({'side_length': 0.06}, 'more than the gripper opens')):
        with pytest.raises(ValueError, match='side_length: .*' + why):
            pick.PickConfig.from_dict(values)
    die = pick.PickConfig.from_dict({'side_length': 0.016, 'edge_radius': 0.0015, 'gripper_gap': [0.0, 0.0387]})
    assert die.side_length == 0.016
    for gap in ([0.02, 0.01], [0.016], [-0.001, 0.05], [0.0, float('nan')]):
        with pytest.raises(ValueError, match='gripper_gap'):
            pick.PickConfig.from_dict({'gripper_gap': gap})


def test_table_plane_in_camera_contains_table_points():
    T_base_camera = gripper_down_at(0.6, 0.2, 0.3) @ T_GRIPPER_CAMERA
    plane = models.table_plane_in_camera(T_base_camera, models.Plane.level(-0.15))
    table_points_base = np.array([[0.5, 0.1, -0.15], [0.8, 0.4, -0.15], [0.65, 0.2, -0.15]])
    table_points_camera = transform_points(invert(T_base_camera), table_points_base)
    np.testing.assert_allclose(table_points_camera @ plane.normal, plane.offset, atol=1e-12)
    assert plane.normal[2] < -0.99      # camera looks down: the table's up normal points back at the camera


def test_hover_and_grasp_poses_centre_and_align_the_gripper():
    config = pick.PickConfig()
    T_base_block = block_at(0.7, 0.25, 0.4)
    T_hover = pick.hover_pose(T_base_block, config, gripper_down_at(0.65, 0.25, 0.14))
    T_grasp = pick.grasp_pose(T_base_block, config, T_hover)
    np.testing.assert_allclose(T_hover[:2, 3], [0.7, 0.25], atol=1e-12)
    assert T_hover[2, 3] == pytest.approx(-0.13 - config.grasp_depth + config.hover_height)
    assert T_grasp[2, 3] == pytest.approx(-0.13 - config.grasp_depth)
    assert T_hover[2, 2] == pytest.approx(-1.0)                       # fingers point down
    closing_axis = T_hover[:3, 1]                                        # fingers close along gripper y
    block_faces = [T_base_block[:3, 0], T_base_block[:3, 1]]
    assert max(abs(closing_axis @ f) for f in block_faces) == pytest.approx(1.0)
    # a floor above the grasp (the block estimated lower than it stands) raises it there, orientation kept
    raised = pick.grasp_pose(T_base_block, config, T_hover, floor_z=T_grasp[2, 3] + 0.003)
    assert raised[2, 3] == T_grasp[2, 3] + 0.003
    np.testing.assert_array_equal(raised[:3, :3], T_grasp[:3, :3])
    np.testing.assert_array_equal(pick.grasp_pose(T_base_block, config, T_hover, floor_z=T_grasp[2, 3] - 0.003),
                                  T_grasp)
    top_z = T_base_block[2, 3]      # a floor less than MIN_GRIP_DEPTH under the top face: left for the safety check
    np.testing.assert_array_equal(pick.grasp_pose(T_base_block, config, T_hover, floor_z=top_z - 0.002), T_grasp)


def test_pbvs_target_moves_a_fraction_and_snaps_near_the_goal():
    config = pick.PickConfig()
    T_base_block = block_at(0.7, 0.25, 0.0)
    T_goal = pick.hover_pose(T_base_block, config, gripper_down_at(0.7, 0.25, 0.14))
    far = gripper_down_at(0.7, 0.25, 0.14)
    step, toward = pick.pbvs_target(far, T_goal, T_base_block, config, CAMERA, T_GRIPPER_CAMERA)
    assert toward is T_goal
    before, _ = pose_error(far, T_goal)
    after, _ = pose_error(step, T_goal)
    assert after == pytest.approx((1 - config.step_fraction) * before, rel=1e-6)
    near = T_goal.copy()
    near[0, 3] += 0.005
    assert pose_error(pick.pbvs_target(near, T_goal, T_base_block, config, CAMERA, T_GRIPPER_CAMERA)[0],
                           T_goal)[0] < 1e-9
    assert pick.converged(T_goal, T_goal, config) and not pick.converged(near, T_goal, config)
    # no full step on an uncertain estimate: the block known to 5 mm only, the last step stays a fraction
    uncertain, _ = pick.pbvs_target(near, T_goal, T_base_block, config, CAMERA, T_GRIPPER_CAMERA, position_std=0.005)
    assert pose_error(uncertain, T_goal)[0] == pytest.approx((1 - config.step_fraction) * 0.005, rel=1e-6)
    certain, _ = pick.pbvs_target(near, T_goal, T_base_block, config, CAMERA, T_GRIPPER_CAMERA, position_std=0.001)
    assert pose_error(certain, T_goal)[0] < 1e-9


@pytest.fixture(scope='module')
def hand_clearance():
    from baxter_pnp.kinematics import ArmKinematics
    kinematics = ArmKinematics('left')
    try:
        solids = [solid.moved(invert(T_GRIPPER_CAMERA)) for solid in kinematics.hand_solids()]
    finally:
        kinematics.close()
    return view.hand_clearance_px(CAMERA, solids)


def test_pbvs_goes_via_the_view_pose_instead_of_passing_the_block_behind_a_finger(hand_clearance):
    """A far block off to the side (a scene the thesis's straight path lost): the straight PBVS path takes
    it to the top of the image, behind a finger; with the hand's clearance map every step keeps it clear
    and the servo still reaches the hover pose."""
    config = pick.PickConfig(side_length=0.046)
    T_base_block = block_at(0.712, -0.015, -2.06)
    start = gripper_down_at(0.65, 0.25, 0.14)
    T_hover = pick.hover_pose(T_base_block, config, start)
    vertices_base = transform_points(T_base_block, config.model.vertices)

    def clear_of_fingers(T_base_gripper):
        return view.points_in_view(T_base_gripper @ T_GRIPPER_CAMERA, vertices_base, CAMERA, 0.0, hand_clearance)

    assert clear_of_fingers(start)
    T, hidden_steps = start, 0
    for _ in range(10):
        T, toward = pick.pbvs_target(T, T_hover, T_base_block, config, CAMERA, T_GRIPPER_CAMERA)
        hidden_steps += not clear_of_fingers(T)
    assert hidden_steps > 0             # without the map: behind a finger on the way

    T, via_view = start, 0
    for _ in range(config.max_steps):
        if pick.converged(T, T_hover, config):
            break
        T, toward = pick.pbvs_target(T, T_hover, T_base_block, config, CAMERA, T_GRIPPER_CAMERA, hand_clearance)
        via_view += toward is not T_hover
        assert view.points_in_view(T @ T_GRIPPER_CAMERA, vertices_base, CAMERA, config.view_margin_px - 1e-6,
                                    hand_clearance)
    assert pick.converged(T, T_hover, config)
    assert via_view > 0


def test_pbvs_goes_straight_to_the_view_pose_when_no_step_toward_it_keeps_the_block_in_view(hand_clearance):
    """The PBVS batch's one failure (seed 21, `down` scene 69): a 31 mm square far to the left, grasped with the
    gripper turned 89 deg. After the first step the block sits in the image's upper left corner, and any step toward
    the view pose swings it out or behind a finger: the kept steps were 1.3 mm, 40 times (``not_converged``). Now
    the step goes straight to the view pose, which sees the block, and the servo reaches the hover pose from
    there with every pose keeping the block in view."""
    from baxter_pnp.kinematics import ArmKinematics
    kinematics = ArmKinematics('left')
    try:
        start = kinematics.fk([-0.6305, -1.1974, -0.2306, 1.7062, 0.0951, 1.0729, -0.1059])    # the `down` pose
        config = pick.PickConfig(side_length=0.03141)
        T_base_block = block_at(0.75576, 0.52908, -0.02657)
        approach = pick.plan_approach(T_base_block, start, config, CAMERA, T_GRIPPER_CAMERA,
                                      lambda T: kinematics.ik(T, seed=None) is not None)
    finally:
        kinematics.close()
    assert approach.rank == 1                           # the second grasp orientation: the gripper turned 89 deg
    T_hover = pick.hover_pose(T_base_block, config, approach.T_reference)
    T_view = pick.view_pose(T_base_block, T_hover, T_GRIPPER_CAMERA, CAMERA, config, approach.view_depth)
    vertices_base = transform_points(T_base_block, config.model.vertices)
    T, straight = start, 0
    for _ in range(config.max_steps):
        if pick.converged(T, T_hover, config):
            break
        kept = view.keep_in_view_step(T, T_view, config.step_fraction, vertices_base, CAMERA, T_GRIPPER_CAMERA,
                                      config.view_margin_px, config.max_step_translation, config.max_step_rotation,
                                      clearance_px=hand_clearance)
        T_next, toward = pick.pbvs_target(T, T_hover, T_base_block, config, CAMERA, T_GRIPPER_CAMERA, hand_clearance,
                                          approach.view_depth)
        if T_next is T_view or np.allclose(T_next, T_view):
            straight, T_blocked = straight + 1, T
            free = servo.look_and_move_step(T, T_view, config.step_fraction, config.max_step_translation,
                                            config.max_step_rotation)
            assert pose_error(T, kept)[0] < pick.BLOCKED_STEP_FRACTION * pose_error(T, free)[0]   # blocked
        T = T_next
        assert view.points_in_view(T @ T_GRIPPER_CAMERA, vertices_base, CAMERA, 0.0, hand_clearance)
    assert straight == 1
    assert pick.converged(T, T_hover, config)
    # a view pose the arm cannot reach (the random-look batch's seed 11 `angled` 0: ik_failure) is no step: from the
    # blocked pose the kept step is taken instead, as before the rule
    T_kept, _ = pick.pbvs_target(T_blocked, T_hover, T_base_block, config, CAMERA, T_GRIPPER_CAMERA, hand_clearance,
                                 approach.view_depth, reachable=lambda T: not np.allclose(T, T_view))
    assert not np.allclose(T_kept, T_view)
    assert view.points_in_view(T_kept @ T_GRIPPER_CAMERA, vertices_base, CAMERA, 0.0, hand_clearance)


def test_place_pose_puts_the_block_bottom_at_the_requested_height():
    config = pick.PickConfig()
    T_holding = gripper_down_at(0.7, 0.25, -0.04)
    T_gripper_block = make_transform(Rotation.from_euler('x', np.pi), (0.001, -0.002, config.grasp_depth))
    T_place = pick.place_pose(T_holding, T_gripper_block, (0.6, 0.1), config, -0.12, 0.004)
    T_base_block = T_place @ T_gripper_block
    np.testing.assert_allclose(T_base_block[:2, 3], [0.6, 0.1], atol=1e-12)
    assert T_base_block[2, 3] == pytest.approx(-0.12 + config.block_height + 0.004)
    np.testing.assert_allclose(T_place[:3, :3], T_holding[:3, :3])


def test_measured_features_follow_the_model_order():
    model = models.model_for('square', 0.04)
    T_camera_block = make_transform(Rotation.from_euler('xyz', [np.pi + 0.1, 0.05, 0.3]), (0.02, -0.01, 0.25))
    exact, depths = pick.normalised(transform_points(T_camera_block, model.vertices))
    shuffled = exact[[2, 0, 3, 1]]
    features, Z = pick.measured_features(shuffled, T_camera_block, model)
    np.testing.assert_allclose(features, exact)
    np.testing.assert_allclose(Z, depths)


@pytest.mark.parametrize('mode', ['ibvs', 'hybrid'])
def test_servo_twist_drives_a_free_camera_to_the_goal(mode):
    """Integrate the camera twist of each law (40 ms steps, true pose as the 'estimate'): the features converge."""
    config = pick.PickConfig()
    model = config.model
    T_camera_goal_block = make_transform(Rotation.from_euler('x', np.pi), (0.0, 0.03, 0.19))
    T_camera_block = make_transform(Rotation.from_euler('xyz', [np.pi - 0.2, 0.15, 0.6]), (0.08, -0.05, 0.4))
    gain = pick.make_gain(config)
    errors = []
    for _ in range(400):
        vertices_xy, _ = pick.normalised(transform_points(T_camera_block, model.vertices))
        twist, error = pick.servo_twist(mode, T_camera_block, T_camera_goal_block, vertices_xy, model, gain)
        errors.append(error)
        twist = pick.bounded_twist(twist, config.max_linear_speed, config.max_angular_speed)
        T_world_camera = servo.integrate_twist(np.eye(4), twist, 0.04)
        T_camera_block = invert(T_world_camera) @ T_camera_block
    assert errors[-1] * CAMERA.fx < 0.5 and errors[-1] < 1e-3 * errors[0]
    np.testing.assert_allclose(T_camera_block, T_camera_goal_block, atol=1e-3)


def test_bounded_twist_keeps_direction():
    twist = np.array([0.3, 0.0, 0.4, 0.0, 0.0, 2.0])
    bounded = pick.bounded_twist(twist, 0.1, 0.5)
    assert np.linalg.norm(bounded[:3]) <= 0.1 + 1e-12 and np.linalg.norm(bounded[3:]) <= 0.5 + 1e-12
    np.testing.assert_allclose(bounded / np.linalg.norm(bounded), twist / np.linalg.norm(twist))


def test_a_block_already_near_a_finger_is_moved_away_from_it(hand_clearance):
    """Within the margin of a finger nothing can be 'kept' in view: the step must still take the block away
    from the finger (the old rule then took the plain step, whatever it did)."""
    import cv2
    config = pick.PickConfig(side_length=0.046)
    T_base_block = block_at(0.712, -0.015, -2.06)
    vertices_base = transform_points(T_base_block, config.model.vertices)
    T_hover = pick.hover_pose(T_base_block, config, gripper_down_at(0.65, 0.25, 0.14))
    T_view = pick.view_pose(T_base_block, T_hover, T_GRIPPER_CAMERA, CAMERA, config)

    def finger_distance_px(T_base_gripper):
        pixels = CAMERA.project(transform_points(invert(T_base_gripper @ T_GRIPPER_CAMERA), vertices_base))
        face = np.zeros(hand_clearance.shape, np.uint8)
        cv2.fillConvexPoly(face, cv2.convexHull(np.round(pixels).astype(np.int32)), 1)
        return hand_clearance[face > 0].min()

    # the straight path without the map goes behind a finger: find a pose on it just short of the finger
    clear = gripper_down_at(0.65, 0.25, 0.14)
    hidden, _ = pick.pbvs_target(clear, T_hover, T_base_block, config, CAMERA, T_GRIPPER_CAMERA)
    while finger_distance_px(hidden) > 0.0:
        clear, (hidden, _) = hidden, pick.pbvs_target(hidden, T_hover, T_base_block, config, CAMERA, T_GRIPPER_CAMERA)
    low, high = 0.0, 1.0
    T = clear
    while not 0.0 < finger_distance_px(T) < 0.5 * config.view_margin_px:
        middle = 0.5 * (low + high)
        T = servo.interpolate_pose(clear, hidden, middle)
        low, high = (middle, high) if finger_distance_px(T) > 0.0 else (low, middle)
    kept = view.keep_in_view_step(T, T_view, config.step_fraction, vertices_base, CAMERA, T_GRIPPER_CAMERA,
                                   margin_px=config.view_margin_px, clearance_px=hand_clearance)
    assert finger_distance_px(T) < finger_distance_px(kept)
    assert view.points_in_view(kept @ T_GRIPPER_CAMERA, vertices_base, CAMERA)


def test_view_kept_twist_slows_a_twist_that_would_push_the_block_out_of_the_image():
    config = pick.PickConfig()
    T_base_camera = gripper_down_at(0.65, 0.25, 0.14) @ T_GRIPPER_CAMERA
    T_base_block = block_at(0.70, 0.25, 0.0)
    vertices_base = transform_points(T_base_block, config.model.vertices)
    assert view.points_in_view(T_base_camera, vertices_base, CAMERA, config.view_margin_px)
    gentle = np.array([0.0, 0.0, 0.01, 0.0, 0.0, 0.0])      # 1 cm/s toward the table: stays in view
    np.testing.assert_array_equal(pick.view_kept_twist(gentle, T_base_camera, T_base_block, config, CAMERA), gentle)
    pushing = np.array([0.0, 0.0, 0.0, 1.2, 0.0, 0.0])      # a fast tilt sweeps the block off the image
    assert not view.points_in_view(servo.integrate_twist(T_base_camera, pushing, 0.5), vertices_base, CAMERA,
                                    config.view_margin_px)
    kept = pick.view_kept_twist(pushing, T_base_camera, T_base_block, config, CAMERA)
    assert 0.0 < np.linalg.norm(kept[3:]) < np.linalg.norm(pushing[3:])
    assert view.points_in_view(servo.integrate_twist(T_base_camera, kept, 0.5), vertices_base, CAMERA,
                                config.view_margin_px - 1e-6)
    np.testing.assert_allclose(servo.twist_between(T_base_camera, servo.integrate_twist(T_base_camera, pushing, 0.5),
                                                   0.5), pushing, atol=1e-9)


def test_multi_cycle_result_json_and_summary_plot(tmp_path):
    from baxter_pnp.task import outputs
    from baxter_pnp.task.settings import SessionConfig
    done = pick.PickResult(success=True, mode='pbvs', time_s=6.0, steps=9, final_error_mm_est=0.4)
    lost = pick.PickResult(success=False, mode='pbvs', failure_reason='block_lost')
    assert outputs.results_json([done], 1, 'pbvs') == done.to_json()
    summary = outputs.results_json([done, lost], 3, 'pbvs')
    assert summary['successes'] == 1 and not summary['success'] and summary['cycles_planned'] == 3
    assert [c['failure_reason'] for c in summary['cycles']] == [None, 'block_lost']
    assert outputs.results_json([done, done, done], 3, 'pbvs')['success']
    assert not outputs.results_json([done, done], 3, 'pbvs')['success']   # one not run yet
    outputs.plot_cycles([done, lost, done], str(tmp_path / 'cycles.png'))
    assert (tmp_path / 'cycles.png').stat().st_size > 1000
    with pytest.raises(ValueError, match='cycles'):
        SessionConfig.from_dict({'cycles': 0})


def test_plan_approach_turns_the_gripper_and_shortens_the_view_for_what_is_out_of_reach():
    config = pick.PickConfig()
    T_base_block = block_at(0.70, 0.0, 0.0)
    start = gripper_down_at(0.65, 0.25, 0.14)
    everywhere = pick.plan_approach(T_base_block, start, config, CAMERA, T_GRIPPER_CAMERA, lambda T: True)
    assert (everywhere.rank, everywhere.view_depth) == (0, config.view_depth)

    orientations = pick.grasp_orientations(T_base_block, config.model.symmetry_angle, start)
    view_x = [pick.view_pose(T_base_block, pick.hover_pose(T_base_block, config, make_transform(R)),
                             T_GRIPPER_CAMERA, CAMERA, config)[0, 3] for R in orientations]
    x_floor = min(sorted(view_x)[1], 0.70) - 0.001     # keep the arm off x < x_floor: the nearest view fails
    assert view_x[0] < x_floor                           # (here: the least rotation's)
    approach = pick.plan_approach(T_base_block, start, config, CAMERA, T_GRIPPER_CAMERA, lambda T: T[0, 3] >= x_floor)
    assert approach.rank == next(k for k, x in enumerate(view_x) if x >= x_floor) > 0
    assert approach.view_depth == config.view_depth

    def within(radius):                         # an arm that reaches only this far (m) from the block
        return lambda T: np.linalg.norm(T[:2, 3] - T_base_block[:2, 3]) <= radius
    offset = np.linalg.norm(pick.view_pose(T_base_block, pick.hover_pose(T_base_block, config, start),
                                           T_GRIPPER_CAMERA, CAMERA, config)[:2, 3] - T_base_block[:2, 3])
    shorter = pick.plan_approach(T_base_block, start, config, CAMERA, T_GRIPPER_CAMERA, within(0.8 * offset))
    assert shorter.rank == 0 and shorter.view_depth < config.view_depth     # a closer view is in reach
    nothing = pick.plan_approach(T_base_block, start, config, CAMERA, T_GRIPPER_CAMERA, lambda T: False)
    assert nothing.rank == -1 and nothing.view_depth == config.view_depth
