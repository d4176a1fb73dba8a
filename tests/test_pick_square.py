"""pick_square.py end to end: a real rosmaster, the real fake Baxter, the real application.

Each run picks the default scene's 40 mm green square (in each mode), or looks for a colour that is not there;
success is judged on the fake's ground truth (``/fake_baxter/object_poses``, ``endpoint_state``: which only tests
and benchmarks read as truth) as well as on the app's result. The place, the published outputs and the parameters
are in ``test_pick_outputs.py`` (which shares the helpers here).
"""
import json
import re

import numpy as np
import pytest
import rospy
import yaml
from geometry_msgs.msg import PoseArray

from baxter_pnp.msgs import msg
from baxter_pnp.sim.launcher import run_script
from baxter_pnp.sim.scene import DEFAULT_SCENE_YAML
from baxter_pnp.transforms import invert, pose_msg_to_matrix

TABLE_TOP_Z = -0.15
BLOCK_HEIGHT = 0.02
BACKOFF_HEIGHT = 0.05       # m, config backoff_height (README: "backs off upward")
RETREAT_HEIGHT = 0.05       # m, the rise after a failure (task.motion.RETREAT_HEIGHT)


def ground_truth_block():
    """T_base_block of the scene's first object, from the fake's ground-truth topic."""
    poses = rospy.wait_for_message('/fake_baxter/object_poses', PoseArray, timeout=10.0)
    return pose_msg_to_matrix(poses.poses[0])


def gripper_pose():
    """T_base_gripper (the gripper tip) from the fake's endpoint state: the forward kinematics of its true angles."""
    state = rospy.wait_for_message('/robot/limb/left/endpoint_state', msg.EndpointState, timeout=10.0)
    return pose_msg_to_matrix(state.pose)


def run_pick(ros_master, tmp_path, *args):
    """Run pick_square.py ARGS --result-json to completion (240 s wall at most); (ScriptRun, result dict or None)."""
    result_path = tmp_path / 'result.json'
    run = run_script(ros_master, 'pick_square.py', ['--result-json', result_path, *args], timeout=240,
                     log_path=tmp_path / 'pick_square.log')
    assert not run.timed_out, run.log()[-3000:]
    result = json.loads(result_path.read_text()) if result_path.exists() else None
    return run, result


@pytest.mark.parametrize('mode, start_pose, look, camera', [
    ('pbvs', 'down', 'clean', ()), ('ibvs', 'down', 'clean', ()),
    ('hybrid', 'angled', 'baxter', ('--camera-exposure', '65', '--camera-gain', '3'))])
def test_pick_each_mode(mode, start_pose, look, camera, ros_master, ros_node, fake_baxter, tmp_path):
    """One verified pick per mode; the hybrid one under the real hand camera's look (``appearance: baxter``: grey
    textured table in dim light, vignetting, colour cast and noise; docs/fake_baxter.md, "Appearance"), its camera
    opened with an exposure and a gain of the app's (the fake's frames 1.55 x brighter)."""
    with open(DEFAULT_SCENE_YAML) as f:
        scene = yaml.safe_load(f)
    scene['appearance'] = look
    scene_path = tmp_path / 'scene.yaml'
    scene_path.write_text(yaml.safe_dump(scene))
    # paced at 1x, as a robot: unpaced on a loaded machine the IBVS pick once took 32 s of simulated time (the
    # fake's clock running on while the application computed), over the bound of 30 s robot time
    fake = fake_baxter('--real-time-factor', '1', '--clock', 'sim', '--scene', scene_path)
    try:
        z_before = ground_truth_block()[2, 3]
        run, result = run_pick(ros_master, tmp_path, '--mode', mode, '--start-pose', start_pose, *camera)
        assert run.returncode == 0, run.log()[-3000:]
        assert ('exposure 65, gain 3' in run.log()) == bool(camera), run.log()[:3000]
        assert result['success'] and result['mode'] == mode and result['failure_reason'] is None
        assert result['steps'] >= 1 and 0 < result['time_s'] < 30, run.log()[-6000:]
        # every step says what posed the block: the configured estimator, its top face or silhouette on the table, or a
        # prediction
        assert {step['pose_method'] for step in result['history']} <= {'sqp', 'on_table', 'silhouette', 'predicted'}
        T_base_block = ground_truth_block()
        # the app lifts 10 cm (lift_height); 5 mm of margin for the block settling in the fingers (+1.7 mm seen)
        assert T_base_block[2, 3] - z_before == pytest.approx(0.10, abs=0.005), 'the block was not lifted 10 cm'
        block_in_gripper = (invert(gripper_pose()) @ T_base_block)[:3, 3]
        # README: centring 0.2-0.3 mm median, p90 0.5 mm over the trial batches; 2 mm leaves room for noise
        assert np.hypot(*block_in_gripper[:2]) < 0.002, 'grasp off-centre by %s m' % block_in_gripper[:2]
    finally:
        fake.stop()


def test_no_block_in_view_backs_off_four_times_and_retreats(ros_master, ros_node, fake_baxter, tmp_path):
    """A colour that is not on the table, ``--no-survey`` (the thesis's behaviour): the app backs off upward 4
    times (max_lost, 5 cm each), gives up (block_lost, exit status 1) and retreats 5 cm up (README, "Failure
    modes"); heights from the fake's endpoint state (the forward kinematics of its true joint angles)."""
    fake = fake_baxter('--real-time-factor', '0')
    try:
        T_base_gripper_start = gripper_pose()       # the fake boots in the app's start pose (down)
        run, result = run_pick(ros_master, tmp_path, '--colour', 'red', '--no-survey')
        log = run.log()
        assert run.returncode == 1, log[-3000:]
        assert not result['success'] and result['failure_reason'] == 'block_lost'
        assert result['steps'] == 0 and not result['history']
        backoffs = re.findall(r're-acquisition (\d) of (\d)\): backing off 50 mm upward', log)
        assert backoffs == [(str(k), '4') for k in range(1, 5)], backoffs
        assert len(re.findall(r'pick: retreat: gripper to', log)) == 1
        rise = gripper_pose()[:3, 3] - T_base_gripper_start[:3, 3]
        # 4 back-offs and the retreat, 5 cm each, straight up; each is relative to the pose reached, so only the
        # last one's arrival tolerance (0.003 rad per joint, a few mm at the tip) is in the result: 5 mm margin
        np.testing.assert_allclose(rise, [0.0, 0.0, 4 * BACKOFF_HEIGHT + RETREAT_HEIGHT], atol=0.005)
    finally:
        fake.stop()
