"""Tests of the thesis-experiment runner (baxter_pnp.bench.experiments): pose geometry, error bookkeeping,
and a reduced depth run against the real fake Baxter."""
import math

import numpy as np
import pytest
import yaml

from baxter_pnp.bench import experiments
from baxter_pnp.transforms import invert, make_transform

TARGET = np.array([0.62, 0.25, -0.13])


@pytest.mark.parametrize('name', experiments.DEPTH_POSES)
def test_pointing_pose_puts_the_gripper_161_mm_from_the_centroid_pointing_at_it(name):
    tilt = math.radians(25.0)
    T = experiments.pointing_pose(TARGET, experiments.pose_direction(name, tilt), experiments.RULER_DISTANCE_M)
    np.testing.assert_allclose(T[:3, :3].T @ T[:3, :3], np.eye(3), atol=1e-12)
    assert np.linalg.det(T[:3, :3]) == pytest.approx(1.0)
    to_target = TARGET - T[:3, 3]
    assert np.linalg.norm(to_target) == pytest.approx(0.161, abs=1e-12)
    np.testing.assert_allclose(T[:3, 2], to_target / np.linalg.norm(to_target), atol=1e-12)   # fingers at it
    expected_tilt = 0.0 if name == 'above' else tilt
    assert math.acos(-T[2, 2]) == pytest.approx(expected_tilt, abs=1e-9)       # angle from straight down
    # the pincer line (y) and the x axis stay in the vertical planes through base y and x: parallel to the
    # square's edges (yaw 0) seen from above, as the thesis's ruler measurement requires
    assert T[0, 1] == pytest.approx(0.0, abs=1e-12) and T[1, 0] == pytest.approx(0.0, abs=1e-12)
    side = {'above': (0, 0), 'left': (0, 1), 'right': (0, -1), 'front': (-1, 0), 'behind': (1, 0)}[name]
    offset = T[:2, 3] - TARGET[:2]
    np.testing.assert_allclose(np.sign(np.round(offset, 9)), side)             # where the gripper is


def test_above_pose_is_the_straight_down_orientation():
    T = experiments.pointing_pose(TARGET, (0, 0, 1), 0.161)
    np.testing.assert_allclose(T[:3, :3], np.diag([-1.0, 1.0, -1.0]), atol=1e-12)
    np.testing.assert_allclose(T[:3, 3], TARGET + [0, 0, 0.161], atol=1e-12)


def test_unknown_pose_is_rejected():
    with pytest.raises(ValueError, match='sideways'):
        experiments.pose_direction('sideways', 0.1)


def test_tilt_path_steps_at_most_five_degrees_and_ends_at_the_pose():
    tilt = math.radians(25.0)
    path = experiments.tilt_path(TARGET, 'behind', tilt, 0.161)
    assert len(path) == 5
    np.testing.assert_allclose(path[-1], experiments.pointing_pose(TARGET, experiments.pose_direction('behind', tilt),
                                                                   0.161), atol=1e-12)
    previous = experiments.pointing_pose(TARGET, (0, 0, 1), 0.161)
    for T in path:
        assert np.linalg.norm(T[:3, 3] - TARGET) == pytest.approx(0.161, abs=1e-12)
        step = math.acos(np.clip(T[:3, 2] @ previous[:3, 2], -1, 1))
        assert step == pytest.approx(math.radians(5.0), abs=1e-9)
        previous = T
    assert len(experiments.tilt_path(TARGET, 'left', math.radians(12.0), 0.161)) == 3


class _Estimate:
    def __init__(self, T_camera_object):
        self.T_camera_object = T_camera_object
        self.depth_m = T_camera_object[2, 3]
        self.residual_px = 0.1
        self.method = 'sqp'


def test_depth_sample_errors_are_estimate_minus_truth():
    """The application's poses (``used``: endpoint state and hand-eye) are off the true ones by a 3.7 mm
    shift that has a component along the optical axis, the estimate is 1 % too far along the true camera's
    ray: every field must come from its own input (m, base frame)."""
    T_base_gripper_true = experiments.pointing_pose(TARGET, (0, 0, 1), 0.161)
    T_gripper_camera = make_transform(None, (0.038, 0.012, -0.142))
    T_base_camera_true = T_base_gripper_true @ T_gripper_camera
    shift = make_transform(None, (0.002, -0.001, 0.003))          # the used poses' error, in base
    T_base_camera_used, T_base_gripper_used = shift @ T_base_camera_true, shift @ T_base_gripper_true
    T_base_block = make_transform(None, TARGET)
    T_camera_block = invert(T_base_camera_true) @ T_base_block    # what the true camera sees
    too_far = T_camera_block.copy()
    too_far[:3, 3] *= 1.01                               # 1 % further along the ray through the centroid
    sample = experiments.depth_sample('nominal', 'above', 0, 1.0, _Estimate(too_far), T_base_camera_used,
                                      T_base_gripper_used, T_base_camera_true, T_base_gripper_true, T_base_block)
    depth = T_camera_block[2, 3]
    camera_to_block = TARGET - T_base_camera_true[:3, 3]
    assert sample.depth_true == pytest.approx(depth)
    assert abs(depth - (invert(T_base_camera_used) @ T_base_block)[2, 3]) > 0.002   # premise: used != true depth
    assert sample.depth_error_mm == pytest.approx(10.0 * depth, rel=1e-9)
    assert sample.distance_true == pytest.approx(0.161, abs=1e-12)    # from the true gripper, not the used one
    # the estimate, placed with the used camera pose, sits 1 % further along the ray and shifted with it: its
    # distance from the used gripper is the true one's (the shift cancels), the position error includes it
    distance_est = np.linalg.norm(TARGET + 0.01 * camera_to_block - T_base_gripper_true[:3, 3])
    assert sample.distance_error_mm == pytest.approx(1000 * (distance_est - 0.161), abs=1e-9)
    assert sample.position_error == pytest.approx(np.linalg.norm(0.01 * camera_to_block + shift[:3, 3]), abs=1e-12)
    assert sample.ruler_error_mm == pytest.approx(sample.distance_error_mm, abs=1e-9)

    rows = experiments.summarise_depth([sample, sample])
    assert len(rows) == 1 and rows[0]['samples'] == 2
    assert rows[0]['depth_error_mean_mm'] == pytest.approx(sample.depth_error_mm)
    assert rows[0]['depth_error_std_mm'] == pytest.approx(0.0, abs=1e-9)


def test_reach_time_is_the_first_step_within_both_tolerances():
    history = [{'time_s': 1.0, 'error_mm': 50.0, 'error_deg': 10.0},
               {'time_s': 2.0, 'error_mm': 1.5, 'error_deg': 3.0},
               {'time_s': 3.0, 'error_mm': 1.9, 'error_deg': 1.0},
               {'time_s': 4.0, 'error_mm': 0.5, 'error_deg': 0.5}]
    assert experiments.reach_time(history, 2.0, 2.0) == 3.0
    assert experiments.reach_time(history[:2], 2.0, 2.0) is None


def test_command_line_rejects_unknown_poses_and_parses_lists():
    args = experiments.parse_args(['all', '--poses', 'above,front', '--fractions', '0.35', '--trials', '2'])
    assert args.poses == ('above', 'front') and args.fractions == (0.35,) and args.trials == 2
    assert args.focal_scales == (1.0, experiments.FOCAL_ERROR_SCALE)
    with pytest.raises(SystemExit):
        experiments.parse_args(['depth', '--poses', 'above,under'])


class FakeArmPoses:
    """The fake Baxter's own /tf (its simulated arm), kept from construction on (rospy initialised)."""

    def __init__(self):
        import rospy
        import tf2_ros
        self._buffer = tf2_ros.Buffer(rospy.Duration(600.0))
        self._listener = tf2_ros.TransformListener(self._buffer)

    def T_base(self, frame, stamp):
        """T_base_frame (4x4) at robot time ``stamp`` (s)."""
        import rospy
        from baxter_pnp.transforms import from_xyz_quat
        t = self._buffer.lookup_transform('base', frame, rospy.Time.from_sec(stamp), rospy.Duration(5.0)).transform
        return from_xyz_quat([t.translation.x, t.translation.y, t.translation.z],
                             [t.rotation.x, t.rotation.y, t.rotation.z, t.rotation.w])


def test_reduced_depth_run_on_the_fake_baxter(ros_node, fake_baxter, tmp_path):
    """One tilted pose (commanded through the app's IK service moves), 4 frames: the depth estimate is
    within the experiment's acceptance (mean |error| <= 1 mm over 56 frames; 1.2 mm here over 4: the frames'
    spread, 0.02-0.16 mm std in the README, weighs more in a mean of 4; -0.3 mm measured) of the truth the
    test takes itself from the fake: the block from its ground truth (/fake_baxter/object_poses), the camera
    and gripper from its /tf at each frame's stamp (robot time)."""
    import rospy
    from geometry_msgs.msg import PoseArray
    from baxter_pnp.transforms import pose_msg_to_matrix
    scene = tmp_path / 'scene.yaml'
    scene.write_text(yaml.safe_dump(experiments.depth_scene()))
    fake_baxter('--scene', str(scene), '--enable', '--real-time-factor', '0')
    arm = FakeArmPoses()
    samples = experiments.measure_depth('nominal', poses=('front',), samples=4)
    T_base_block = pose_msg_to_matrix(rospy.wait_for_message('/fake_baxter/object_poses', PoseArray, 5.0).poses[0])
    assert [s.sample for s in samples] == [0, 1, 2, 3] and {s.pose for s in samples} == {'front'}
    assert len({s.stamp for s in samples}) == 4                          # four different frames
    depth_errors_mm, distance_errors_mm = [], []
    for s in samples:
        T_camera_block = invert(arm.T_base('left_hand_camera', s.stamp)) @ T_base_block
        block_to_gripper = np.linalg.norm(T_base_block[:3, 3] - arm.T_base('left_gripper', s.stamp)[:3, 3])
        assert block_to_gripper == pytest.approx(0.161, abs=0.002)      # the arm got to the ruler pose
        assert T_camera_block[2, 3] == pytest.approx(0.303, abs=0.005)
        # the experiment's own truth (URDF forward kinematics of the joints read after the look) agrees with the
        # fake's: 0.2 um measured; 10 um allows for the still arm's settling between the frame and the read
        assert s.depth_true == pytest.approx(T_camera_block[2, 3], abs=1e-5)
        assert s.distance_true == pytest.approx(block_to_gripper, abs=1e-5)
        depth_errors_mm.append(1000 * (s.depth_est - T_camera_block[2, 3]))
        distance_errors_mm.append(1000 * (s.distance_est - block_to_gripper))
        assert s.position_error < 0.005
        assert s.method == 'sqp'
    assert np.mean(np.abs(depth_errors_mm)) < 1.2
    assert np.mean(np.abs(distance_errors_mm)) < 1.2
