"""Table survey planner (baxter_pnp.survey) on the default table with the real kinematics, camera mount and
finger mask of the fake Baxter's 640x400 left hand camera."""
import os

import numpy as np
import pytest

from baxter_pnp import survey
from baxter_pnp.kinematics import ArmKinematics, load_start_poses
from baxter_pnp.runtime import PACKAGE_ROOT
from baxter_pnp.sim.cameras import sensor_model, sensor_window

TABLE, TABLE_Z = survey.DEFAULT_TABLE, survey.DEFAULT_TABLE_Z


@pytest.fixture(scope='module')
def setup():
    kinematics = ArmKinematics('left')
    camera = sensor_model('left_hand_camera').windowed(sensor_window(640, 400))     # the fake's 640x400 camera
    T_gripper_camera, clearance = survey.hand_camera_setup(kinematics, camera)
    reach = survey.reachable_table(TABLE, kinematics)
    start = kinematics.fk(list(load_start_poses()['down'].values()))[:3, 3]
    greedy = survey.plan_survey(TABLE, TABLE_Z, camera, T_gripper_camera, clearance, kinematics, table_reach=reach)
    yield kinematics, camera, T_gripper_camera, clearance, reach, start, greedy
    kinematics.close()


def test_reachable_table_is_ik_solvable_and_bounded(setup):
    kinematics, _, _, _, reach, _, _ = setup
    assert 0.2 < reach.mask.mean() < 0.8            # part of the table, not all: the left arm's side
    ys = np.broadcast_to(reach.ys[:, None], reach.mask.shape)
    assert reach.mask[ys > 0.3].mean() > reach.mask[ys < -0.3].mean()       # the left arm reaches its own side
    rng = np.random.default_rng(1)
    cells = np.argwhere(reach.mask)
    for j, i in cells[rng.choice(len(cells), 5, replace=False)]:
        T = survey.down_pose((reach.xs[i], reach.ys[j]), TABLE_Z + reach.height)
        np.testing.assert_allclose(kinematics.fk(reach.joints[j, i]), T, atol=2e-3)
    far = survey.down_pose((1.15, -0.7), TABLE_Z + reach.height)
    assert kinematics.ik(far) is None and not reach.contains([[1.15, -0.7]])[0]


def test_survey_covers_the_reachable_table(setup):
    kinematics, camera, T_gripper_camera, clearance, reach, start, greedy = setup
    ordered = survey.order_viewpoints(greedy, start)
    assert 4 <= len(ordered) <= 10
    fraction = survey.coverage(ordered, TABLE, TABLE_Z, camera, T_gripper_camera, clearance, reach)
    assert fraction >= 0.95
    seed = None
    for T in ordered:
        assert T[2, 3] > TABLE_Z + 0.2 and T[2, 2] < -0.999          # above the table, pointing down
        seed = kinematics.ik(T, seed=seed)
        assert seed is not None
    assert survey.path_length(ordered, start) < survey.path_length(greedy, start)
    # the fingers matter: without their mask the same views claim more, and dropping one view loses coverage
    assert survey.coverage(ordered, TABLE, TABLE_Z, camera, T_gripper_camera, None, reach) > fraction
    assert survey.coverage(greedy[:-2], TABLE, TABLE_Z, camera, T_gripper_camera, clearance, reach) < fraction
    image = os.path.join(PACKAGE_ROOT, 'docs', 'images', 'survey_coverage.png')
    if os.environ.get('BAXTER_PNP_WRITE_DOCS'):
        survey.draw_coverage(image, ordered, TABLE, TABLE_Z, camera, T_gripper_camera, clearance, reach,
                             start=start)
    print('views %d coverage %.4f path %.3f m (greedy order %.3f m)'
          % (len(ordered), fraction, survey.path_length(ordered, start), survey.path_length(greedy, start)))


def test_seen_rejects_points_folded_back_by_distortion(setup):
    _, camera, T_gripper_camera, clearance, _, _, _ = setup
    T_base_camera = survey.down_pose((0.6, 0.2), TABLE_Z + 0.29) @ T_gripper_camera
    centre = T_base_camera[:3, 3].copy()
    centre[2] = TABLE_Z
    far = centre + [0.0, 0.95, 0.0]     # normalised radius 2.2: the plumb-bob polynomial maps it near the centre
    assert survey.seen(T_base_camera, [centre], camera, clearance)[0]
    assert not survey.seen(T_base_camera, [far], camera, None)[0]


def test_order_viewpoints_two_opt():
    rng = np.random.default_rng(3)
    poses = [survey.down_pose(xy, 0.1) for xy in rng.uniform(0, 1, (9, 2))]
    ordered = survey.order_viewpoints(poses, start=np.zeros(3))
    assert survey.path_length(ordered, np.zeros(3)) < survey.path_length(poses, np.zeros(3))
    assert sorted(map(id, ordered)) == sorted(map(id, poses))
    # a line visited out of order comes back in order
    line = [survey.down_pose((x, 0.0), 0.1) for x in (0.3, 0.1, 0.4, 0.2)]
    assert [T[0, 3] for T in survey.order_viewpoints(line, start=np.zeros(3))] == [0.1, 0.2, 0.3, 0.4]


def test_plan_with_a_predicate_and_yaw():
    def disc(T):
        return np.hypot(T[0, 3] - 0.6, T[1, 3] - 0.2) < 0.25
    for yaw in (0.0, 1.0, -2.5):
        assert abs(survey.pose_yaw(survey.down_pose((0.5, 0.1), 0.1, yaw)) - yaw) < 1e-9
    reach = survey.reachable_table(TABLE, disc, cell=0.05)
    assert 0.05 < reach.mask.mean() < 0.25
