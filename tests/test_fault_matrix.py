"""Fault matrix: pick_square.py against the fake Baxter with injected faults (docs/fake_baxter.md).

Each case (noisy camera with distractors, stall and blackout with a nudged block, a missed grasp, the block
partly occluded, absent or failing IK, an e-stop, a killed and restarted robot) asserts the specific
behaviour (picked anyway, or aborted cleanly with the right ``failure_reason``) and, in every case, that
the gripper tip never went below the table: the fake's endpoint state is the forward kinematics of its
true joint angles, i.e. the ground truth of the gripper pose, recorded for the whole run.
"""
import json
import math
import os
import signal
import threading

import cv2
import numpy as np
import pytest
import rosgraph
import rosnode
import rospy
import yaml
from geometry_msgs.msg import PoseArray

from baxter_pnp.bench import trial_scenes
from baxter_pnp.msgs import msg
from baxter_pnp.sim.faults import OCCLUDER_THICKNESS
from baxter_pnp.sim.launcher import run_script, wait_until
from baxter_pnp.sim.scene import DEFAULT_SCENE_YAML, Scene
from baxter_pnp.sim.world import SimWorld
from baxter_pnp.transforms import pose_msg_to_matrix

TABLE_TOP_Z = -0.15


class GripperHeightMonitor:
    """Lowest gripper-tip z (base) seen on the fake's endpoint state while it runs."""

    def __init__(self):
        self.lowest = np.inf
        self._lock = threading.Lock()
        self._subscriber = rospy.Subscriber('/robot/limb/left/endpoint_state', msg.EndpointState, self._on_state)

    def _on_state(self, state):
        with self._lock:
            self.lowest = min(self.lowest, state.pose.position.z)

    def close(self):
        self._subscriber.unregister()


def scene_with(tmp_path, faults=None, extra_objects=()):
    with open(DEFAULT_SCENE_YAML) as f:
        scene = yaml.safe_load(f)
    scene['objects'] += list(extra_objects)
    if faults:
        scene['faults'] = faults
    path = tmp_path / 'scene.yaml'
    path.write_text(yaml.safe_dump(scene))
    return path


def block_z(index=0):
    poses = rospy.wait_for_message('/fake_baxter/object_poses', PoseArray, timeout=10.0)
    return pose_msg_to_matrix(poses.poses[index])[2, 3]


@pytest.fixture
def fake_baxter(fake_baxter):
    """conftest's ``fake_baxter``, with each fake a case started stopped when the case ends, passed or failed
    (a failed case must not leave its fake running: the next case's fake would refuse to start)."""
    started = []

    def start(*args, **kwargs):
        started.append(fake_baxter(*args, **kwargs))
        return started[-1]
    yield start
    for process in started:
        process.stop()


def run_case(ros_master, fake_baxter, tmp_path, faults=None, extra_objects=(), app_args=(), during=None):
    """Start the fake on the faulty scene, run the app (``during(fake)`` meanwhile, if given), return
    (exit code, result dict, log, lowest tip z, fake process)."""
    fake = fake_baxter('--real-time-factor', '0', '--scene', scene_with(tmp_path, faults, extra_objects), '--seed', '1')
    monitor = GripperHeightMonitor()
    result_path = tmp_path / 'result.json'
    args = ['--result-json', result_path, *app_args]
    if during is None:
        run = run_script(ros_master, 'pick_square.py', args, timeout=240, log_path=tmp_path / 'pick.log')
    else:
        worker = threading.Thread(target=lambda: setattr(worker, 'run', run_script(
            ros_master, 'pick_square.py', args, timeout=240, log_path=tmp_path / 'pick.log')))
        worker.start()
        during(fake)
        worker.join()
        run = worker.run
    monitor.close()
    result = json.loads(result_path.read_text()) if result_path.exists() else None
    assert not run.timed_out, run.log()[-3000:]
    assert monitor.lowest >= TABLE_TOP_Z + 0.002, 'gripper tip went down to z = %.4f m' % monitor.lowest
    return run.returncode, result, run.log(), fake


def assert_picked(code, result, log):
    assert code == 0 and result['success'], log[-3000:]
    assert block_z() > TABLE_TOP_Z + 0.02 + 0.05, 'the block was not lifted'


def test_noisy_camera_slow_commands_flaky_ik_and_distractors(ros_master, ros_node, fake_baxter, tmp_path):
    """20 % dropped frames, 100 ms latency, dimmer light, late joint commands, 30 % IK failures, a green
    triangle and a red square on the table: picked anyway."""
    faults = {'camera': {'drop_probability': 0.2, 'latency': 0.1, 'brightness_gain': 0.7},
              'joint_command_delay': 0.1, 'ik': {'failure_probability': 0.3}}
    distractors = [{'shape': 'triangle', 'side': 0.04, 'height': 0.02, 'color': [0.1, 0.7, 0.1], 'xy': [0.62, 0.32],
                    'yaw': 0.0},
                   {'shape': 'square', 'side': 0.04, 'height': 0.02, 'color': [0.8, 0.1, 0.1], 'xy': [0.76, 0.18],
                    'yaw': 0.2}]
    code, result, log, _ = run_case(ros_master, fake_baxter, tmp_path, faults, distractors)
    assert_picked(code, result, log)
    assert 'no IK solution' in log          # the alternatives were needed, and worked


def test_camera_stall_blackout_and_nudged_block(ros_master, ros_node, fake_baxter, tmp_path):
    """The camera stalls, then goes black, and the block is pushed 3 cm during the approach: picked anyway."""
    faults = {'camera': {'stall': {'at': 2.0, 'duration': 1.5}, 'blackout': {'at': 4.0, 'duration': 0.5}},
              'nudge': {'at': 2.6, 'offset': [0.03, -0.02]}, 'time_origin': 'camera_open'}
    code, result, log, _ = run_case(ros_master, fake_baxter, tmp_path, faults)
    assert_picked(code, result, log)
    poses = rospy.wait_for_message('/fake_baxter/object_poses', PoseArray, timeout=10.0)
    assert poses.poses[0].position.x == pytest.approx(0.70 + 0.03, abs=0.02)     # it was moved, then picked


def test_missed_grasp_is_retried_with_a_twin_block_nearby(ros_master, ros_node, fake_baxter, tmp_path):
    """The first close finds nothing (fingers pass through); a second green square lies 12 cm away: regrasp."""
    twin = [{'shape': 'square', 'side': 0.04, 'height': 0.02, 'color': [0.1, 0.7, 0.1], 'xy': [0.60, 0.32],
             'yaw': 0.0}]
    code, result, log, _ = run_case(ros_master, fake_baxter, tmp_path, {'gripper': {'miss_first': 1}}, twin)
    assert code == 0 and result['success'] and result['grasp_attempts'] == 2, log[-3000:]
    assert 'missed' in log
    assert max(block_z(0), block_z(1)) > TABLE_TOP_Z + 0.07


@pytest.mark.parametrize('faults, reason', [
    ({'ik': {'absent': True}}, 'service_unavailable'),
    ({'ik': {'fail_region': {'min': [0.5, 0.1, -0.3], 'max': [0.9, 0.4, 0.1]}}}, 'ik_failure'),
    ({'estop_at': 2.5, 'time_origin': 'camera_open'}, 'robot_stopped'),
])
def test_aborts_cleanly(faults, reason, ros_master, ros_node, fake_baxter, tmp_path):
    code, result, log, _ = run_case(ros_master, fake_baxter, tmp_path, faults)
    assert code == 1 and not result['success'] and result['failure_reason'] == reason, log[-3000:]
    assert block_z() == pytest.approx(TABLE_TOP_Z + 0.02, abs=0.003), 'the block should still be on the table'


def test_robot_killed_and_restarted_mid_run(ros_master, ros_node, fake_baxter, tmp_path):
    """The fake dies during the approach and a new one boots: the app waits, re-enables, and picks."""
    restarted = []

    def kill_and_restart(fake):
        log = tmp_path / 'pick.log'
        wait_until(lambda: log.exists() and 'step 2:' in log.read_text(), timeout=120, what='the servo loop')
        os.killpg(fake.process.pid, signal.SIGKILL)        # no clean shutdown
        fake.process.wait(timeout=10.0)
        rosnode.cleanup_master_blacklist(rosgraph.Master('/pytest'), ['/fake_baxter'])   # `rosnode cleanup`
        restarted.append(fake_baxter('--real-time-factor', '0', '--seed', '2'))

    code, result, log, _ = run_case(ros_master, fake_baxter, tmp_path, during=kill_and_restart)
    assert code == 0 and result['success'], log[-3000:]
    assert 'the robot is back' in log
    assert block_z() > TABLE_TOP_Z + 0.07


def occluder_hiding(block, fraction, height, start_pose='down', table_top_z=TABLE_TOP_Z):
    """``faults.occluder`` mapping of a plate ``height`` (m) above the table whose shadow, seen from the
    camera at ``start_pose``, covers the strip of the block's top face along its +x edge, ``fraction`` of
    the side wide (and overhangs the face elsewhere). The shadow is the plate scaled about the camera's
    centre (a homothety maps the plate's rectangle to a rectangle of the same yaw on the top-face plane)."""
    centre = trial_scenes.start_view(start_pose)[0][:3, 3]
    side, yaw = block['side'], block['yaw']
    scale = (centre[2] - (table_top_z + height + OCCLUDER_THICKNESS)) / (centre[2] - (table_top_z + block['height']))
    rotation = np.array([[math.cos(yaw), -math.sin(yaw)], [math.sin(yaw), math.cos(yaw)]])
    shadow_size = np.array([(1 + fraction) * side, 2 * side])
    shadow_centre = np.asarray(block['xy']) + rotation @ [side / 2 - fraction * side + shadow_size[0] / 2, 0.0]
    return {'xy': (centre[:2] + (shadow_centre - centre[:2]) * scale).tolist(),
            'size': (shadow_size * scale).tolist(), 'height': height, 'yaw': yaw}


def green_top_pixels(scene_dict, start_pose='down'):
    """Number of lit green pixels (the block's top face) in the fake's render of the first look from ``start_pose``."""
    world = SimWorld(Scene.from_dict(scene_dict))
    world.command_gripper('left', 100.0, velocity_percent=100.0)      # open, as at the application's first look
    world.step(240)
    image = world.render_camera('left_hand_camera', trial_scenes.start_view(start_pose)[2])
    world.close()
    hsv = cv2.cvtColor(image, cv2.COLOR_BGR2HSV)
    return int(np.sum((hsv[..., 0] > 45) & (hsv[..., 0] < 75) & (hsv[..., 1] > 100) & (hsv[..., 2] > 150)))


def test_partly_occluded_block_is_not_grasped_and_the_run_aborts_cleanly(ros_master, ros_node, fake_baxter, tmp_path):
    """A grey plate 6 cm above the table hides 30 % of the block's top face from the start view (a strip
    along one edge, so the visible part is a clean 40 x 28 mm rectangle, a wrong square to a careless
    detector). What the application does: it never takes the rectangle for the square, backs off upward
    four times (the plate still hides the strip from straight above), and aborts with ``block_lost``
    without a single servo step; the block is not touched. (Moving sideways would reveal the whole face:
    if the application learns that, it should pick the block instead, and this test must change.)"""
    with open(DEFAULT_SCENE_YAML) as f:
        scene = yaml.safe_load(f)
    block = scene['objects'][0]
    occluder = occluder_hiding(block, 0.3, 0.06)
    hidden = 1 - green_top_pixels({**scene, 'faults': {'occluder': occluder}}) / green_top_pixels(scene)
    assert 0.27 < hidden < 0.35, hidden                     # the plate does hide ~30 % of the face
    code, result, log, _ = run_case(ros_master, fake_baxter, tmp_path, {'occluder': occluder})
    assert code == 1 and not result['success'] and result['failure_reason'] == 'block_lost', log[-3000:]
    assert result['steps'] == 0 and 'no whole green square in view after 4 re-acquisition moves' in log
    poses = rospy.wait_for_message('/fake_baxter/object_poses', PoseArray, timeout=10.0)
    np.testing.assert_allclose(pose_msg_to_matrix(poses.poses[0])[:3, 3], [*block['xy'], TABLE_TOP_Z + 0.02],
                               atol=1e-3)                   # untouched
