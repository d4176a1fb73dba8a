"""calibrate_hand_eye.py end to end: a real rosmaster, the real fake Baxter on ``config/scenes/hand_eye.yaml``
(a 9x6 chessboard on the table; the true camera mount 11.2 mm / 2.5 deg off the URDF's that tf publishes), the
real calibration task. Judged on the scene's ``camera_error`` (the ground truth the application never reads)
and on the fake's ground-truth block and endpoint poses.
"""
import json

import numpy as np
import pytest
import yaml

from baxter_pnp import hand_eye
from baxter_pnp.calibrate_app import oriented_corners
from baxter_pnp.bench.hand_eye_bench import urdf_T_hand_camera
from baxter_pnp.runtime import PACKAGE_ROOT
from baxter_pnp.sim.launcher import run_script
from baxter_pnp.sim.scene import DEFAULT_SCENE_YAML, load_scene
from baxter_pnp.transforms import invert, pose_error
from test_pick_square import ground_truth_block, gripper_pose, run_pick

HAND_EYE_SCENE = PACKAGE_ROOT + '/config/scenes/hand_eye.yaml'


def run_calibration(ros_master, tmp_path, *args):
    """calibrate_hand_eye.py ARGS -o tmp/hand_eye.yaml --result-json ...; (ScriptRun, output path, result dict)."""
    output, result_path = tmp_path / 'hand_eye.yaml', tmp_path / 'calibration_result.json'
    run = run_script(ros_master, 'calibrate_hand_eye.py', ['-o', output, '--result-json', result_path, *args],
                     timeout=400, log_path=tmp_path / 'calibrate_hand_eye.log')
    assert not run.timed_out, run.log()[-3000:]
    result = json.loads(result_path.read_text()) if result_path.exists() else None
    return run, output, result


def test_oriented_corners_undoes_a_grid_found_from_the_other_end():
    predicted = np.array([[10.0, 10.0], [20.0, 10.0], [30.0, 12.0]])
    found = predicted[::-1] + 0.3
    np.testing.assert_allclose(oriented_corners(found, predicted), predicted + 0.3)
    np.testing.assert_allclose(oriented_corners(predicted + 0.3, predicted), predicted + 0.3)


def test_calibration_recovers_the_mount_and_a_pick_with_it_is_centred(ros_master, ros_node, fake_baxter, tmp_path):
    """Issue 12's acceptance on the fake: the recovered mount within 1.0 mm and 0.2 deg of the true one, the
    reported 1-sigma covering the error (within 3 sigma), at most 3 min of robot time, the table plane where the
    board lies; then a pick with ``--hand-eye`` holds the block within 2 mm of the gripper axis (the URDF's mount
    put it about 9 mm off: README)."""
    scene = load_scene(HAND_EYE_SCENE)
    fake = fake_baxter('--real-time-factor', '0', '--scene', HAND_EYE_SCENE)
    try:
        run, output, result = run_calibration(ros_master, tmp_path)
        log = run.log()
        assert run.returncode == 0, log[-3000:]
        assert result['success'] and result['time_s'] <= 180.0, result
        calibration = hand_eye.load_hand_eye(str(output))
        T_hand_camera_true = urdf_T_hand_camera() @ scene.camera_error.T_published_true
        translation, rotation = pose_error(T_hand_camera_true, calibration.T_parent_child)
        assert 1000 * translation < 1.0 and np.degrees(rotation) < 0.2, (translation, np.degrees(rotation))
        # 3 sigma (norms of the per-axis 1-sigma) covers the error: the reported uncertainty is honest
        assert 1000 * translation <= 3 * calibration.std_mm and np.degrees(rotation) <= 3 * calibration.std_deg, \
            (1000 * translation, calibration.std_mm, np.degrees(rotation), calibration.std_deg)
        normal, offset = calibration.table_plane
        board = scene.boards[0]
        board_top_z = scene.table.top_z + board.thickness
        assert normal[2] > np.cos(np.radians(0.2)), normal          # flat within 0.2 deg
        assert abs(offset / normal[2] - board_top_z) < 0.001        # the board's face within 1 mm
        assert 'static_transform_publisher' in log and 'left_hand left_hand_camera' in log

        z_before = ground_truth_block()[2, 3]
        pick_run, pick_result = run_pick(ros_master, tmp_path, '--hand-eye', output)
        assert pick_run.returncode == 0 and pick_result['success'], pick_run.log()[-3000:]
        assert 'hand-eye from calibration' in pick_run.log() and 'the plane of' in pick_run.log()
        T_base_block = ground_truth_block()
        assert T_base_block[2, 3] - z_before > 0.09, 'the block was not lifted'
        block_in_gripper = (invert(gripper_pose()) @ T_base_block)[:3, 3]
        assert np.hypot(*block_in_gripper[:2]) < 0.002, 'grasp off-centre by %s m' % block_in_gripper[:2]
    finally:
        fake.stop()


def test_no_board_in_view_fails_cleanly_and_writes_no_file(ros_master, ros_node, fake_baxter, tmp_path):
    """The default scene has no chessboard: exit 1, failure ``board_not_found`` with a message saying what to
    do, no calibration file (and an older one left as it was)."""
    fake = fake_baxter('--real-time-factor', '0', '--scene', DEFAULT_SCENE_YAML)
    try:
        (tmp_path / 'hand_eye.yaml').write_text('older: file\n')
        run, output, result = run_calibration(ros_master, tmp_path)
        assert run.returncode == 1, run.log()[-3000:]
        assert result['failure_reason'] == 'board_not_found' and 'lay it flat' in run.log()
        assert output.read_text() == 'older: file\n'
    finally:
        fake.stop()


@pytest.mark.parametrize('content, named', [({'parent_frame': 'right_hand', 'child_frame': 'right_hand_camera',
                                              'translation': [0.03, 0.0, 0.02], 'rotation_xyzw': [0, 0, 0, 1]},
                                             'not the left arm'),
                                            ({'parent_frame': 'left_hand'}, 'hand_eye')])
def test_a_wrong_hand_eye_file_is_a_bad_parameter(content, named, tmp_path):
    """``--hand-eye`` with another arm's calibration or a broken file: ParameterError naming ``hand_eye``
    (the scripts exit 2 before connecting)."""
    from baxter_pnp.params import ParameterError
    from baxter_pnp.task.settings import SessionConfig
    path = tmp_path / 'hand_eye.yaml'
    path.write_text(yaml.safe_dump(content))
    with pytest.raises(ParameterError, match=named):
        SessionConfig.from_dict({'hand_eye': str(path)})
