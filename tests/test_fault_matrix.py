"""Fault matrix: pick_square.py against the fake Baxter with injected faults (docs/fake_baxter.md).

Each case asserts the specific behaviour (picked anyway, or aborted cleanly with the right
``failure_reason``) and, in every case, that the gripper tip never went below the table: the fake's
endpoint state is the forward kinematics of its true joint angles, i.e. the ground truth of the
gripper pose, recorded for the whole run.
"""
import json
import os
import signal
import threading

import numpy as np
import pytest
import rosgraph
import rosnode
import rospy
import yaml
from geometry_msgs.msg import PoseArray

from baxter_pnp.msgs import msg
from baxter_pnp.sim.launcher import FakeBaxterProcess, run_script, wait_until
from baxter_pnp.sim.scene import DEFAULT_SCENE_YAML
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
    code, result, log, fake = run_case(ros_master, fake_baxter, tmp_path, faults, distractors)
    assert_picked(code, result, log)
    assert 'no IK solution' in log          # the alternatives were needed, and worked
    fake.stop()


def test_camera_stall_blackout_and_nudged_block(ros_master, ros_node, fake_baxter, tmp_path):
    """The camera stalls, then goes black, and the block is pushed 3 cm during the approach: picked anyway."""
    faults = {'camera': {'stall': {'at': 2.0, 'duration': 1.5}, 'blackout': {'at': 4.0, 'duration': 0.5}},
              'nudge': {'at': 2.6, 'offset': [0.03, -0.02]}, 'time_origin': 'camera_open'}
    code, result, log, fake = run_case(ros_master, fake_baxter, tmp_path, faults)
    assert_picked(code, result, log)
    poses = rospy.wait_for_message('/fake_baxter/object_poses', PoseArray, timeout=10.0)
    assert poses.poses[0].position.x == pytest.approx(0.70 + 0.03, abs=0.02)     # it was moved, then picked
    fake.stop()


def test_missed_grasp_is_retried_with_a_twin_block_nearby(ros_master, ros_node, fake_baxter, tmp_path):
    """The first close finds nothing (fingers pass through); a second green square lies 12 cm away: regrasp."""
    twin = [{'shape': 'square', 'side': 0.04, 'height': 0.02, 'color': [0.1, 0.7, 0.1], 'xy': [0.60, 0.32],
             'yaw': 0.0}]
    code, result, log, fake = run_case(ros_master, fake_baxter, tmp_path, {'gripper': {'miss_first': 1}}, twin)
    assert code == 0 and result['success'] and result['grasp_attempts'] == 2, log[-3000:]
    assert 'missed' in log
    assert max(block_z(0), block_z(1)) > TABLE_TOP_Z + 0.07
    fake.stop()


@pytest.mark.parametrize('faults, reason', [
    ({'ik': {'absent': True}}, 'service_unavailable'),
    ({'ik': {'fail_region': {'min': [0.5, 0.1, -0.3], 'max': [0.9, 0.4, 0.1]}}}, 'ik_failure'),
    ({'estop_at': 2.5, 'time_origin': 'camera_open'}, 'robot_stopped'),
])
def test_aborts_cleanly(faults, reason, ros_master, ros_node, fake_baxter, tmp_path):
    code, result, log, fake = run_case(ros_master, fake_baxter, tmp_path, faults)
    assert code == 1 and not result['success'] and result['failure_reason'] == reason, log[-3000:]
    assert block_z() == pytest.approx(TABLE_TOP_Z + 0.02, abs=0.003), 'the block should still be on the table'
    fake.stop()


def test_robot_killed_and_restarted_mid_run(ros_master, ros_node, fake_baxter, tmp_path):
    """The fake dies during the approach and a new one boots: the app waits, re-enables, and picks."""
    def kill_and_restart(fake):
        log = tmp_path / 'pick.log'
        wait_until(lambda: log.exists() and 'step 2:' in log.read_text(), timeout=120, what='the servo loop')
        os.killpg(fake.process.pid, signal.SIGKILL)        # no clean shutdown
        fake.process.wait(timeout=10.0)
        rosnode.cleanup_master_blacklist(rosgraph.Master('/pytest'), ['/fake_baxter'])   # `rosnode cleanup`
        fake_baxter('--real-time-factor', '0', '--seed', '2')

    code, result, log, _ = run_case(ros_master, fake_baxter, tmp_path, during=kill_and_restart)
    assert code == 0 and result['success'], log[-3000:]
    assert 'the robot is back' in log
    assert block_z() > TABLE_TOP_Z + 0.07
