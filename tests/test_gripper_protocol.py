"""The electric gripper's end-effector protocol (baxter_pnp.sim.gripper) driving the fake's own fingers, no ROS graph.

The protocol actuates and reads ``SimWorld``'s left gripper in PyBullet, wired as the fake Baxter's node does
(``SimWorld.command_gripper``, ``SimWorld.gripper_state`` at 100 Hz of simulated time), so ``gripping``,
``missed`` and ``moving`` come from the physics. ``_BaxterInterfaceClient`` replays what
``baxter_interface.Gripper.command`` does for blocking calls (send, wait for the acknowledgement, then wait for
the completion test) in simulated seconds. Positions and parameters are percent (position 0 closed, 100 open).
"""
import datetime
import json
import math

import pytest

from baxter_pnp.kinematics import ArmKinematics
from baxter_pnp.sim.clock import RateSchedule
from baxter_pnp.sim.gripper import DEFAULT_PARAMETERS, ElectricGripperProtocol, GripperCommandError
from baxter_pnp.sim.scene import load_scene
from baxter_pnp.sim.world import FINGER_TRAVEL, GRIPPER_MAX_SPEED, SimWorld
from fake_baxter_client import gripper_down

STATE_RATE_HZ = 100.0      # the fake Baxter's gripper state publication rate (simulated)
SDK_FORMAT = '%Y/%m/%d %H:%M:%S'
PAD_GAP = 0.016            # m between the finger pads' inner faces when closed (urdf/baxter.urdf)
# Parameters unlike baxter_interface's defaults, so that a configure that did nothing shows.
FAST_FIRM = {'velocity': 80.0, 'moving_force': 60.0, 'holding_force': 20.0, 'dead_zone': 3.0}


class _Fingers:
    """SimWorld's left gripper as the protocol's actuator; ``calls`` records every actuation (position, force,
    velocity percent) before it reaches the world."""

    def __init__(self, world):
        self.world = world
        self.calls = []

    def command(self, position_percent, force_percent, velocity_percent):
        self.calls.append((position_percent, force_percent, velocity_percent))
        self.world.command_gripper('left', position_percent, force_percent, velocity_percent)

    def state(self):
        return self.world.gripper_state('left')

    @property
    def position(self):
        return self.state()['position_percent']


class _BaxterInterfaceClient:
    """baxter_interface.Gripper's command logic against the protocol, in simulated time (``time``, s)."""

    def __init__(self, gripper, fingers):
        self.gripper, self.fingers = gripper, fingers
        self.sequence = 0
        self._schedule = RateSchedule(STATE_RATE_HZ, start=fingers.world.time)

    @property
    def time(self):
        return self.fingers.world.time

    def tick(self):
        """Step the world to the next gripper state publication and update the protocol, as the node does."""
        world = self.fingers.world
        world.step()
        while not self._schedule.due(world.time):
            world.step()
        self.gripper.update(world.time, self.fingers.state())

    def run(self, seconds):
        end = self.time + seconds
        while self.time < end:
            self.tick()

    def command(self, cmd, args=None, block=False, test=lambda state: True, timeout=0.0):
        """Returns (test result, seconds until acknowledged, seconds until done) like Gripper.command."""
        self.sequence += 1
        sender = '/pnp_' + cmd
        self._send(cmd, sender, args)
        if not block:
            return True, None, None
        start = self.time
        acknowledged_after = None
        while self.time - start <= timeout:
            state = self.gripper.state()
            if acknowledged_after is None and state['command_sender'] == sender and \
                    state['command_sequence'] in (self.sequence, 0):
                acknowledged_after = self.time - start
            if acknowledged_after is not None and test(state):
                return True, acknowledged_after, self.time - start
            self._send(cmd, sender, args)   # baxter_interface republishes at 100 Hz while waiting
            self.tick()
        return False, acknowledged_after, None

    def _send(self, cmd, sender, args):
        try:
            self.gripper.handle_command(cmd, json.JSONEncoder().encode(args) if args else '', sender, self.sequence)
        except GripperCommandError:
            pass


@pytest.fixture(scope='module')
def kin():
    arm = ArmKinematics('left')
    yield arm
    arm.close()


@pytest.fixture
def world():
    """The default scene: the arm in the 'down' start pose, 29 cm above the table, fingers open on nothing."""
    w = SimWorld(load_scene())
    yield w
    w.close()


def _make(world):
    fingers = _Fingers(world)
    gripper = ElectricGripperProtocol(fingers.command)
    gripper.update(world.time, fingers.state())
    return gripper, fingers, _BaxterInterfaceClient(gripper, fingers)


def _around_the_block(world, kin):
    """Put the open fingers around the scene's block (teleport, as a grasp pose 8 mm above the table); returns
    the expected closed position (percent) on its side."""
    (T_block,) = world.object_poses()
    T_grasp = gripper_down(T_block[:3, 3] + [0.0, 0.0, -0.012], math.atan2(T_block[1, 0], T_block[0, 0]))
    positions, _, _ = world.joint_state()
    q_now = [positions[world.joint_names().index(name)] for name in kin.joint_names]
    q_grasp = kin.ik(T_grasp, seed=q_now)
    assert q_grasp is not None
    world.set_arm_positions('left', dict(zip(kin.joint_names, q_grasp)))
    world.step(24)
    side = world.scene.objects[0].side
    return 100.0 * (side - PAD_GAP) / 2 / FINGER_TRAVEL


def test_properties_pass_the_sdk_checks(world):
    gripper, _, _ = _make(world)
    properties, state = gripper.properties(), gripper.state()
    assert properties['ui_type'] == 2
    assert properties['id'] == state['id'] != 0
    firmware = datetime.datetime.strptime(properties['firmware_date'], SDK_FORMAT)
    assert firmware > datetime.datetime.strptime('2014/5/20 00:00:00', SDK_FORMAT)
    assert properties['controls_position'] and properties['controls_force']
    assert state['enabled'] == 1 and state['ready'] == 1 and state['calibrated'] == 0


def test_every_command_is_acknowledged_even_when_refused(world):
    gripper, fingers, _ = _make(world)
    with pytest.raises(GripperCommandError, match='not calibrated'):
        gripper.handle_command('go', '{"position": 0.0}', '/app_go', 7)
    state = gripper.state()
    assert (state['command'], state['command_sender'], state['command_sequence']) == ('go', '/app_go', 7)
    assert fingers.calls == []
    with pytest.raises(GripperCommandError, match='unknown'):
        gripper.handle_command('fly', '', '/app_fly', 8)
    assert gripper.state()['command_sequence'] == 8


def test_baxter_interface_sequence_picks_a_block(world, kin):
    """configure (values unlike the defaults), calibrate, open, close on the block: the physics reports gripping
    at the block's width, squeezing with the configured force."""
    gripper, fingers, client = _make(world)
    closed_on_block = _around_the_block(world, kin)
    assert all(FAST_FIRM[key] != DEFAULT_PARAMETERS[key] for key in DEFAULT_PARAMETERS)
    client.command('configure', args=dict(FAST_FIRM))
    assert gripper.parameters == FAST_FIRM
    assert gripper.state()['calibrated'] != 1          # the example code calibrates only in this case

    done, acked, duration = client.command(
        'calibrate', block=True, timeout=5.0, test=lambda s: s['calibrated'] == 1 and s['ready'] == 1)
    assert done and acked < 0.05 and duration < 5.0
    assert gripper.state()['calibrated'] == 1

    def reached(target):
        return lambda s: abs(s['position'] - target) < FAST_FIRM['dead_zone'] or s['gripping'] == 1

    done, acked, duration = client.command('go', {'position': 100.0}, block=True, timeout=5.0, test=reached(100.0))
    assert done and acked < 0.05 and duration < 0.5
    done, acked, duration = client.command('go', {'position': 0.0}, block=True, timeout=5.0, test=reached(0.0))
    # The fingers close at the configured velocity ((100 - closed_on_block) % at 80 % of GRIPPER_MAX_SPEED: 0.28 s;
    # 0.44 s at the default 50 %), then must stand still ~0.1 s (the low-passed finger speed) before gripping.
    travel_time = (100.0 - closed_on_block) / 100 * FINGER_TRAVEL / (FAST_FIRM['velocity'] / 100 * GRIPPER_MAX_SPEED)
    assert done and acked < 0.05 and travel_time < duration < travel_time + 0.15
    client.run(0.3)                                     # the squeeze settles
    state = gripper.state()
    assert state['gripping'] == 1 and state['missed'] == 0 and state['moving'] == 0
    assert state['position'] == pytest.approx(closed_on_block, abs=5.0)   # 2 mm of pad compliance = 4.8 %
    assert state['force'] == pytest.approx(FAST_FIRM['moving_force'], rel=0.1)   # contact force jitters
    assert fingers.calls[-1] == (0.0, FAST_FIRM['moving_force'], FAST_FIRM['velocity'])


def test_closing_on_nothing_reports_missed(world):
    gripper, _, client = _make(world)
    client.command('calibrate', block=True, timeout=5.0, test=lambda s: s['calibrated'] == 1)
    done, _, _ = client.command('go', {'position': 0.0}, block=True, timeout=5.0,
                                test=lambda s: abs(s['position']) < 5.0 or s['gripping'] == 1)
    assert done
    while gripper.state()['moving'] == 1:
        client.tick()
        assert client.time < 5.0
    state = gripper.state()
    assert state['missed'] == 1 and state['gripping'] == 0 and state['position'] < 2.0


def test_calibration_opens_the_fingers_and_takes_time(world):
    gripper, fingers, client = _make(world)
    world.command_gripper('left', 20.0)
    client.run(1.0)
    assert fingers.position == pytest.approx(20.0, abs=1.0)
    start = client.time
    gripper.handle_command('calibrate', '', '/c', 1)
    assert gripper.state()['ready'] == 0 and fingers.calls[-1][0] == 100.0
    while gripper.state()['calibrated'] != 1:
        client.tick()
        assert client.time - start < 2.0
    assert client.time - start >= gripper.calibration_time and fingers.position == pytest.approx(100.0, abs=1.0)
    gripper.handle_command('clear_calibration', '', '/c', 2)
    assert gripper.state()['calibrated'] == 0 and gripper.state()['ready'] == 1


def test_configure_validates_and_is_atomic(world):
    gripper, _, _ = _make(world)
    gripper.handle_command('configure', '{"velocity": 80, "dead_zone": 2.5}', '/c', 1)
    assert gripper.parameters == dict(DEFAULT_PARAMETERS, velocity=80.0, dead_zone=2.5)
    bad_args = [('{"velocity": 180}', r'\[0, 100\]'), ('{"velocity": 10, "speed": 3}', 'unknown'),
                ('{"holding_force": "hard"}', 'number'), ('velocity=3', 'JSON'), ('[1, 2]', 'object')]
    for sequence, (bad, message) in enumerate(bad_args, start=2):
        before = dict(gripper.parameters)
        with pytest.raises(GripperCommandError, match=message):
            gripper.handle_command('configure', bad, '/c', sequence)
        assert gripper.parameters == before


def test_stop_holds_the_current_position_and_go_clips(world):
    gripper, fingers, client = _make(world)
    client.command('calibrate', block=True, timeout=5.0, test=lambda s: s['calibrated'] == 1)
    gripper.handle_command('go', '{"position": -20}', '/g', 10)
    assert fingers.calls[-1][0] == 0.0
    client.run(0.2)
    gripper.handle_command('stop', '', '/s', 11)
    stopped_at = fingers.position
    assert fingers.calls[-1][0] == pytest.approx(stopped_at) and 0.0 < stopped_at < 100.0
    client.run(0.5)
    assert fingers.position == pytest.approx(stopped_at, abs=1.0) and gripper.state()['moving'] == 0


def test_reboot_drops_enabled_then_loses_calibration_and_parameters(world):
    gripper, fingers, client = _make(world)
    client.command('calibrate', block=True, timeout=5.0, test=lambda s: s['calibrated'] == 1)
    client.command('configure', args={'velocity': 10.0})
    client.command('go', {'position': 50.0})
    assert gripper.parameters['velocity'] == 10.0 and fingers.calls[-1][2] == 10.0     # configured, in use
    done, _, duration = client.command('reboot', block=True, timeout=5.0,
                                       test=lambda s: s['enabled'] == 1 and s['ready'] == 1)
    assert done and duration >= gripper.reboot_time
    assert gripper.state()['calibrated'] == 0 and gripper.parameters == DEFAULT_PARAMETERS
    client.command('calibrate', block=True, timeout=5.0, test=lambda s: s['calibrated'] == 1)
    assert fingers.calls[-1][2] == DEFAULT_PARAMETERS['velocity']                      # the default again


def test_reset_clears_error(world):
    gripper, _, client = _make(world)
    gripper.error = True
    done, _, _ = client.command('reset', block=True, timeout=2.0, test=lambda s: s['error'] == 0 and s['ready'] == 1)
    assert done
