"""The task layer's pure parts: target choice, re-centre and search poses, session/task parameters."""
import dataclasses

import numpy as np
import pytest
import yaml
from scipy.spatial.transform import Rotation

from baxter_pnp import pick
from baxter_pnp.camera import SensorWindow, load_default_camera
from baxter_pnp.params import ParameterError
from baxter_pnp.models import Plane
from baxter_pnp.perception import BlockObservation
from baxter_pnp.pose import PoseEstimate
from baxter_pnp.task import target
from baxter_pnp.task.settings import SessionConfig, load_configs
from baxter_pnp.transforms import invert, make_transform
from baxter_pnp.vision import Detection

TABLE_Z = -0.15
RULES = target.TargetRules('square', 'green', 0.04, 0.02, Plane.level(TABLE_Z), max_residual_px=2.0, max_height_error=0.02,
                           place_xy=(0.62, 0.12))
DOWN = Rotation.from_euler('x', np.pi)             # camera looking straight down (optical z = -base z)
T_BASE_CAMERA = make_transform(DOWN, (0.65, 0.10, 0.25))


def observation(x, y, z=TABLE_Z + 0.02, residual=0.3, area=900.0, centroid=(320.0, 200.0), touches_border=False):
    """A green square's observation whose estimate puts it at (x, y, z) in base."""
    T_camera_block = invert(T_BASE_CAMERA) @ make_transform(None, (x, y, z))
    detection = Detection('square', 'green', np.zeros((4, 2)), np.asarray(centroid, float), area, 1.0,
                          touches_border, np.zeros((4, 1, 2), np.int32))
    return BlockObservation(detection, PoseEstimate(T_camera_block, residual, 'sqp', None))


def test_only_believable_estimates_are_targets():
    on_table = observation(0.70, 0.10)
    assert target.believable(on_table, T_BASE_CAMERA, RULES)
    assert not target.believable(observation(0.70, 0.10, residual=2.5), T_BASE_CAMERA, RULES)   # occluded, odd
    assert not target.believable(observation(0.70, 0.10, z=TABLE_Z + 0.045), T_BASE_CAMERA, RULES)  # 2.5 cm high
    assert target.believable(observation(0.70, 0.10, z=TABLE_Z + 0.045), T_BASE_CAMERA, RULES, on_table=False)
    placed = observation(0.62 + 0.07, 0.12)     # within two sides (8 cm) of the place position
    assert not target.believable(placed, T_BASE_CAMERA, RULES)
    assert target.believable(placed, T_BASE_CAMERA, RULES, placed_too=True)
    no_pose = BlockObservation(on_table.detection, None, 'estimation failed')
    assert not target.believable(no_pose, T_BASE_CAMERA, RULES)


def test_a_far_estimate_is_given_the_height_its_uncertainty_allows():
    """2.5 cm below the table: not believed when known to 2 mm, believed when the estimate itself says its height is
    uncertain by 10 mm (3 sigma: 30 mm); never beyond far_height_error (80 mm: a far 20 px die's estimate,
    uncertain by 50 mm, believed 75 mm low, not 85 mm)."""

    def uncertain(depth_below, std_z):      # the camera looks straight down: base z is -camera z
        low = observation(0.70, 0.10, z=TABLE_Z + 0.02 - depth_below)
        covariance = np.diag([1e-6, 1e-6, std_z ** 2, 1e-4, 1e-4, 1e-4])
        return BlockObservation(low.detection, PoseEstimate(low.pose.T_camera_object, 0.3, 'sqp', covariance))
    assert target.height_tolerance(uncertain(0.025, 0.010).pose, T_BASE_CAMERA, RULES) == pytest.approx(0.030)
    assert not target.believable(uncertain(0.025, 0.002), T_BASE_CAMERA, RULES)
    assert target.believable(uncertain(0.025, 0.010), T_BASE_CAMERA, RULES)
    assert not target.believable(observation(0.70, 0.10, z=TABLE_Z + 0.02 - 0.045), T_BASE_CAMERA, RULES)
    assert target.height_tolerance(uncertain(0.025, 0.020).pose, T_BASE_CAMERA, RULES) == pytest.approx(0.060)
    assert target.height_tolerance(uncertain(0.025, 0.050).pose, T_BASE_CAMERA, RULES) == pytest.approx(0.080)
    assert target.believable(uncertain(0.075, 0.050), T_BASE_CAMERA, RULES)
    assert not target.believable(uncertain(0.085, 0.050), T_BASE_CAMERA, RULES)
    closer = dataclasses.replace(RULES, far_height_error=0.04)
    assert not target.believable(uncertain(0.075, 0.050), T_BASE_CAMERA, closer)


def test_a_believed_target_is_moved_onto_the_table_as_far_as_the_uncertainties_say():
    """A far estimate 25 mm below its height, uncertain by 20 mm along its ray (base z here), the table known to
    5 mm: the chosen target comes to within 25 * 25 / (400 + 25) mm of its height, its std along z to 4.9 mm; x and y
    (uncorrelated with z) stay; an estimate certain to 1 mm hardly moves; without a table sigma nothing moves."""
    rules = dataclasses.replace(RULES, table_height_sigma=0.005)
    low = observation(0.70, 0.10, z=TABLE_Z + 0.02 - 0.025)

    def with_std_z(std_z):
        covariance = np.diag([1e-6, 1e-6, std_z ** 2, 1e-4, 1e-4, 1e-4])
        return BlockObservation(low.detection, PoseEstimate(low.pose.T_camera_object, 0.3, 'sqp', covariance))
    far = target.choose_target([with_std_z(0.020)], T_BASE_CAMERA, rules, (640, 400))
    position = (T_BASE_CAMERA @ far.pose.T_camera_object)[:3, 3]
    assert position[2] - (TABLE_Z + 0.02) == pytest.approx(-0.025 * 25 / 425)
    np.testing.assert_allclose(position[:2], (0.70, 0.10), atol=1e-12)
    assert target.height_std(far.pose, T_BASE_CAMERA) == pytest.approx(np.sqrt(1 / (1 / 0.020 ** 2 + 1 / 0.005 ** 2)))
    near = target.on_the_table(with_std_z(0.001), T_BASE_CAMERA, rules)
    assert (T_BASE_CAMERA @ near.pose.T_camera_object)[2, 3] - (TABLE_Z + 0.02) == pytest.approx(-0.025 * 25 / 26)
    uncertain = with_std_z(0.020)
    assert target.on_the_table(uncertain, T_BASE_CAMERA, RULES) is uncertain                   # sigma 0: off
    assert target.on_the_table(low, T_BASE_CAMERA, rules) is low                              # no covariance
    assert target.choose_target([with_std_z(0.020)], T_BASE_CAMERA, rules, (640, 400), on_table=False).pose \
        .T_camera_object[2, 3] == low.pose.T_camera_object[2, 3]


def test_an_estimate_off_its_height_tells_the_side_length_that_would_put_it_on_the_table():
    """A 38.6 mm block posed with the 40 mm model lies 3.6 % farther along the same ray (the IBVS batch's rerun
    of scene 63: 7 mm low at 0.19 m); the side length that puts it back on the table is the block's. Believed, yet
    off by more than 3 mm and its own stds, it is a suspect grasp; far off, of the target's kind, it is rejected for
    its height alone (the picker logs both with the implied side length)."""
    true_side = 0.0386
    on_table = np.array([0.70, 0.10, TABLE_Z + 0.02])
    camera = T_BASE_CAMERA[:3, 3]
    estimated = camera + (on_table - camera) * RULES.side_length / true_side
    low = observation(*estimated)
    assert target.height_error(low.pose, T_BASE_CAMERA, RULES) == pytest.approx(estimated[2] - on_table[2])
    assert target.height_error(low.pose, T_BASE_CAMERA, RULES) < -0.005
    assert target.implied_side_length(low.pose, T_BASE_CAMERA, RULES) == pytest.approx(true_side)
    assert target.implied_side_length(observation(*on_table).pose, T_BASE_CAMERA, RULES) == pytest.approx(0.04)
    above_camera = observation(0.70, 0.10, 0.30)        # a ray that never meets the table in front of the camera
    assert target.implied_side_length(above_camera.pose, T_BASE_CAMERA, RULES) is None
    assert target.grasp_height_suspect(low.pose, T_BASE_CAMERA, RULES)      # 14 mm low at 0.38 m: believed, suspect
    assert not target.grasp_height_suspect(observation(*on_table - [0, 0, 0.002]).pose, T_BASE_CAMERA, RULES)
    deep = observation(*(camera + (on_table - camera) * 1.3))      # a 31 mm block taken for 40 mm: 11 cm low
    red_deep = BlockObservation(dataclasses.replace(deep.detection, colour='red'), deep.pose)
    assert target.rejected_for_height([low, deep, red_deep], T_BASE_CAMERA, RULES) == [deep]


def test_a_still_blocks_position_is_the_mean_of_its_agreeing_looks():
    """The newest looks (3 at most) within 3 combined stds + 1 mm of the newest, weighted by their inverse variance:
    two solutions 5 mm apart, each +-1-3 mm, give their mean; a block moved 30 mm starts afresh; no std: the newest."""
    a, b = np.array([0.5, 0.0, -0.126]), np.array([0.5, 0.0, -0.131])
    np.testing.assert_allclose(target.steady_position([(a, 0.002), (b, 0.002), (a, 0.002)]), (2 * a + b) / 3)
    np.testing.assert_allclose(target.steady_position([(b, 0.001), (a, 0.002), (b, 0.002), (a, 0.002)]),
                               (2 * a + b) / 3)                                   # the oldest is out of the window
    np.testing.assert_allclose(target.steady_position([(a, 0.001), (b, 0.002)]), (4 * a + b) / 5)
    moved = a + [0.03, 0.0, 0.0]
    np.testing.assert_allclose(target.steady_position([(a, 0.002), (b, 0.002), (moved, 0.002)]), moved)
    np.testing.assert_allclose(target.steady_position([(a, 0.002), (moved, 0.002), (b, 0.002)]), b)
    np.testing.assert_allclose(target.steady_position([(a, 0.002), (b, None)]), b)
    np.testing.assert_allclose(target.steady_position([(a, None), (b, 0.002)]), b)


def test_choose_target_tracks_the_same_block_else_takes_the_largest():
    small, large = observation(0.70, 0.02, area=800.0), observation(0.75, 0.20, area=1200.0)
    image_size = (640, 400)
    assert target.choose_target([small, large], T_BASE_CAMERA, RULES, image_size) is large
    last = make_transform(None, (0.71, 0.03, TABLE_Z + 0.02))           # 1.4 cm from the small one
    assert target.choose_target([small, large], T_BASE_CAMERA, RULES, image_size, last) is small
    far_last = make_transform(None, (0.50, -0.20, TABLE_Z + 0.02))     # neither is the block seen before
    assert target.choose_target([small, large], T_BASE_CAMERA, RULES, image_size, far_last) is large
    unbelievable = observation(0.75, 0.20, area=5000.0, residual=9.0)
    assert target.choose_target([unbelievable, small], T_BASE_CAMERA, RULES, image_size) is small
    assert target.choose_target([unbelievable], T_BASE_CAMERA, RULES, image_size) is None


def test_recentred_puts_the_block_on_the_optical_axis():
    T_base_gripper = make_transform(DOWN, (0.60, 0.05, 0.20))
    T_gripper_camera = make_transform(Rotation.from_euler('z', 0.2), (0.03, 0.0, -0.1))
    T_base_camera = T_base_gripper @ T_gripper_camera
    T_base_block = make_transform(None, (0.72, 0.18, TABLE_Z + 0.02))
    T_next = target.recentred(T_base_gripper, T_base_camera, T_base_block, 0.025)
    T_next_camera = T_next @ T_gripper_camera
    axis = T_next_camera[:3, 2]
    hit = T_next_camera[:3, 3] + axis * (T_base_block[2, 3] - T_next_camera[2, 3]) / axis[2]
    np.testing.assert_allclose(hit[:2], T_base_block[:2, 3], atol=1e-9)
    assert T_next[2, 3] == pytest.approx(T_base_gripper[2, 3] + 0.025)
    np.testing.assert_allclose(T_next[:3, :3], T_base_gripper[:3, :3])


def test_a_block_not_believably_in_view_is_carried_over_to_the_new_camera_pose():
    """The velocity laws' bridge over a look without the block (a shadow over it): the last estimate, seen from the
    camera's new pose, projects where the block is; no residual, no covariance, never cut by the border."""
    camera = load_default_camera().scaled(640, 400)
    model = pick.PickConfig().model
    T_base_block = make_transform(Rotation.from_euler('z', 0.3), (0.76, 0.02, TABLE_Z + 0.02))
    last = observation(0.76, 0.02, touches_border=True)
    T_base_camera = make_transform(DOWN, (0.74, 0.00, 0.10))
    carried = target.predicted_target(last, T_base_block, T_base_camera, camera, model)
    np.testing.assert_allclose(T_base_camera @ carried.pose.T_camera_object, T_base_block, atol=1e-12)
    vertices_base = (T_base_block @ np.c_[model.vertices, np.ones(4)].T).T
    expected = camera.project((invert(T_base_camera) @ vertices_base.T).T[:, :3])
    np.testing.assert_allclose(carried.detection.vertices_px, expected)
    np.testing.assert_allclose(carried.detection.centroid_px, expected.mean(axis=0))
    assert (carried.detection.shape, carried.detection.colour) == ('square', 'green')
    assert carried.pose.method == 'predicted' and carried.pose.residual_px == 0.0
    assert carried.pose.position_std_m is None and not carried.detection.touches_border
    assert target.believable(carried, T_base_camera, RULES)
    assert last.detection.touches_border      # the last observation is left as it was
    with pytest.raises(ParameterError, match='max_predicted_looks'):
        pick.PickConfig(max_predicted_looks=-1).validate()


def test_search_pose_looks_from_above_the_last_seen_block_when_reachable():
    T_here = make_transform(DOWN, (0.60, 0.05, 0.20))
    T_view = make_transform(DOWN, (0.70, 0.15, 0.10))
    pose, over_block = target.search_pose(T_here, 2, 0.05, T_view, lambda T: True)
    assert over_block and pose[2, 3] == pytest.approx(0.20) and pose[0, 3] == pytest.approx(0.70)
    pose, over_block = target.search_pose(T_here, 2, 0.05, T_view, lambda T: False)   # out of reach: back off
    assert not over_block and pose[2, 3] == pytest.approx(0.25) and pose[0, 3] == pytest.approx(0.60)
    pose, over_block = target.search_pose(T_here, 0, 0.05)                          # never seen: back off
    assert not over_block and pose[2, 3] == pytest.approx(0.25)


def test_left_behind_only_when_the_block_still_lies_where_it_was():
    before = make_transform(None, (0.70, 0.10, TABLE_Z + 0.02))
    assert pick.left_behind(before, before, TABLE_Z, 0.02)
    assert not pick.left_behind(make_transform(None, (0.70, 0.10, TABLE_Z + 0.12)), before, TABLE_Z, 0.02)   # lifted
    assert not pick.left_behind(make_transform(None, (0.75, 0.10, TABLE_Z + 0.02)), before, TABLE_Z, 0.02)   # other


def test_one_yaml_splits_into_the_task_and_the_session_with_precedence(tmp_path):
    path = tmp_path / 'pick.yaml'
    path.write_text(yaml.safe_dump({'mode': 'ibvs', 'side': 'left', 'table_top_z': -0.12, 'cycles': 2,
                                    'step_fraction': 0.2, 'fps': 10}))
    task, session = load_configs(pick.PickConfig, str(path), {'step_fraction': 0.3, 'fps': 15},
                                 {'step_fraction': 0.12, 'mode': None})
    assert (task.mode, task.step_fraction) == ('ibvs', 0.12)                 # YAML, then the command line
    assert (session.table_top_z, session.cycles, session.fps) == (-0.12, 2, 15)   # YAML, then ~private
    assert isinstance(session, SessionConfig) and not hasattr(task, 'cycles')
    for values, key in (({'cycles': 0}, 'cycles'), ({'side': 'middle'}, 'side'), ({'fps': 'fast'}, 'fps'),
                        ({'speed_ratio': 1.5}, 'speed_ratio'), ({'save_views': 'yes'}, 'save_views'),
                        ({'stepfraction': 0.1}, 'stepfraction'), ({'camera_exposure': 101}, 'camera_exposure'),
                        ({'camera_gain': -2}, 'camera_gain'), ({'camera_gain': 'auto'}, 'camera_gain')):
        with pytest.raises(ParameterError, match=key):
            load_configs(pick.PickConfig, None, values)
    _, session = load_configs(pick.PickConfig, None, {'camera_exposure': 80, 'camera_gain': 0})
    assert (session.camera_exposure, session.camera_gain) == (80, 0)


def test_a_camera_calibration_is_the_image_model_or_its_centred_window(tmp_path):
    """``camera_calibration`` at the mode's size is used as it is; at a larger size its centred window (a hand
    camera's modes are windows of the sensor: 640x480 -> 640x400 drops 40 rows top and bottom); smaller, or not a
    camera, is a bad parameter before anything connects."""
    thesis = load_default_camera()                              # 640x480
    path = tmp_path / 'camera.yaml'
    thesis.to_yaml(str(path))
    at_640x400 = SessionConfig.from_dict({'camera_calibration': str(path), 'resolution': [640, 400]})
    camera = at_640x400.calibrated_camera()
    assert (camera.width, camera.height) == (640, 400)
    np.testing.assert_allclose(camera.K, thesis.K - [[0, 0, 0], [0, 0, 40], [0, 0, 0]])
    np.testing.assert_array_equal(camera.D, thesis.D)
    own = tmp_path / 'own.yaml'
    camera.to_yaml(str(own))
    np.testing.assert_array_equal(SessionConfig.from_dict({'camera_calibration': str(own)}).calibrated_camera().K,
                                  camera.K)
    small = tmp_path / 'small.yaml'
    thesis.windowed(SensorWindow.centred(640, 480, 320, 200)).to_yaml(str(small))
    with pytest.raises(ParameterError, match='camera_calibration.*smaller than the camera mode 640x400'):
        SessionConfig.from_dict({'camera_calibration': str(small), 'resolution': [640, 400]})
    with pytest.raises(ParameterError, match='camera_calibration.*not a readable'):
        SessionConfig.from_dict({'camera_calibration': str(tmp_path / 'missing.yaml')})


def test_stall_watch_flags_a_feature_error_that_does_not_fall_and_starts_afresh_per_goal():
    """The velocity laws' stall detection (pick.StallWatch): an error falling 10 % a second is never a stall;
    one crawling 1.5 % in 3 s is, as soon as 3 s of it are seen; a new goal phase or a reset starts afresh; a
    progress of 0 disables it."""
    StallWatch = pick.StallWatch
    watch = StallWatch(3.0, 0.1)
    assert not any(watch.stalled(0.05 * k, 100.0 * 0.9 ** (0.05 * k), 'view') for k in range(200))
    watch = StallWatch(3.0, 0.1)
    flags = [watch.stalled(0.05 * k, 50.0 - 0.0125 * k, 'view') for k in range(100)]
    assert flags.index(True) == 60 and watch.count > 0
    assert not watch.stalled(5.1, 30.0, 'hover')                    # a new phase: no history yet
    assert not any(watch.stalled(5.1 + 0.05 * k, 30.0, 'hover') for k in range(1, 60))
    assert watch.stalled(5.1 + 3.0, 30.0, 'hover')
    watch.reset()
    assert not watch.stalled(9.0, 30.0, 'hover')
    disabled = StallWatch(3.0, 0.0)
    assert not any(disabled.stalled(0.05 * k, 50.0, 'view') for k in range(200))
    gapped = StallWatch(3.0, 0.1)
    assert not any(gapped.stalled(t, 50.0, 'view') for t in (0.0, 0.05, 2.0, 3.1, 4.2))   # > 1 s gaps: afresh
