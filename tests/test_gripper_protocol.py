"""The electric gripper's end-effector protocol (baxter_pnp.sim.gripper), without ROS or PyBullet.

The fingers are a small kinematic stand-in for SimWorld's gripper; ``_BaxterInterfaceClient`` replays
what ``baxter_interface.Gripper.command`` does for blocking calls (send, wait for the acknowledgement,
then wait for the completion test) against the protocol, in simulated time.
"""
import datetime
import json

import pytest

from baxter_pnp.sim.gripper import DEFAULT_PARAMETERS, ElectricGripperProtocol, GripperCommandError

DT = 0.01                  # s, the fake Baxter's state publication period
SDK_FORMAT = '%Y/%m/%d %H:%M:%S'


class _Fingers:
    """Fingers moving at ``velocity_percent`` % of 200 %/s toward the target; an object at ``obstacle`` % stops them."""

    def __init__(self, obstacle=None):
        self.position, self.target, self.speed = 100.0, 100.0, 0.0
        self.obstacle = obstacle
        self.calls = []

    def command(self, position_percent, force_percent, velocity_percent):
        self.calls.append((position_percent, force_percent, velocity_percent))
        self.target, self.speed = position_percent, 2.0 * velocity_percent

    def step(self, dt):
        limit = self.obstacle if self.obstacle is not None and self.target < self.obstacle else self.target
        delta = limit - self.position
        self.position += max(-self.speed * dt, min(self.speed * dt, delta))

    def state(self):
        closing_on_object = self.obstacle is not None and self.target < self.obstacle
        at_rest = abs(self.position - (self.obstacle if closing_on_object else self.target)) < 1e-9
        gripping = closing_on_object and at_rest
        return {'position_percent': self.position, 'force_percent': 40.0 if gripping else 0.0,
                'moving': not at_rest, 'gripping': gripping,
                'missed': at_rest and self.target == 0.0 and not gripping}


class _BaxterInterfaceClient:
    """baxter_interface.Gripper's command logic, run against the protocol in simulated time."""

    def __init__(self, gripper, fingers):
        self.gripper, self.fingers = gripper, fingers
        self.time, self.sequence = 0.0, 0

    def tick(self):
        self.time += DT
        self.fingers.step(DT)
        self.gripper.update(self.time, self.fingers.state())

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


def _make(obstacle=None):
    fingers = _Fingers(obstacle)
    gripper = ElectricGripperProtocol(fingers.command)
    gripper.update(0.0, fingers.state())
    return gripper, fingers, _BaxterInterfaceClient(gripper, fingers)


def test_properties_pass_the_sdk_checks():
    gripper, _, _ = _make()
    properties, state = gripper.properties(), gripper.state()
    assert properties['ui_type'] == 2
    assert properties['id'] == state['id'] != 0
    firmware = datetime.datetime.strptime(properties['firmware_date'], SDK_FORMAT)
    assert firmware > datetime.datetime.strptime('2014/5/20 00:00:00', SDK_FORMAT)
    assert properties['controls_position'] and properties['controls_force']
    assert state['enabled'] == 1 and state['ready'] == 1 and state['calibrated'] == 0


def test_every_command_is_acknowledged_even_when_refused():
    gripper, fingers, _ = _make()
    with pytest.raises(GripperCommandError, match='not calibrated'):
        gripper.handle_command('go', '{"position": 0.0}', '/app_go', 7)
    state = gripper.state()
    assert (state['command'], state['command_sender'], state['command_sequence']) == ('go', '/app_go', 7)
    assert fingers.calls == []
    with pytest.raises(GripperCommandError, match='unknown'):
        gripper.handle_command('fly', '', '/app_fly', 8)
    assert gripper.state()['command_sequence'] == 8


def test_baxter_interface_sequence_picks_a_block():
    gripper, fingers, client = _make(obstacle=35.0)   # a block that stops the fingers at 35 %
    dead_zone = DEFAULT_PARAMETERS['dead_zone']
    client.command('configure', args=dict(DEFAULT_PARAMETERS))
    assert gripper.parameters == DEFAULT_PARAMETERS
    assert gripper.state()['calibrated'] != 1          # the example code calibrates only in this case

    done, acked, duration = client.command(
        'calibrate', block=True, timeout=5.0, test=lambda s: s['calibrated'] == 1 and s['ready'] == 1)
    assert done and acked < 0.05 and duration < 5.0
    assert gripper.state()['calibrated'] == 1

    def reached(target):
        return lambda s: abs(s['position'] - target) < dead_zone or s['gripping'] == 1

    done, acked, duration = client.command('go', {'position': 100.0}, block=True, timeout=5.0, test=reached(100.0))
    assert done and acked < 0.05 and duration < 0.5
    done, acked, duration = client.command('go', {'position': 0.0}, block=True, timeout=5.0, test=reached(0.0))
    assert done and acked < 0.05 and duration < 1.0
    state = gripper.state()
    assert state['gripping'] == 1 and state['missed'] == 0
    assert state['position'] == pytest.approx(35.0) and state['force'] > 0
    position, force, velocity = fingers.calls[-1]
    assert (position, force, velocity) == (0.0, DEFAULT_PARAMETERS['moving_force'], DEFAULT_PARAMETERS['velocity'])


def test_closing_on_nothing_reports_missed():
    gripper, _, client = _make()
    client.command('calibrate', block=True, timeout=5.0, test=lambda s: s['calibrated'] == 1)
    done, _, _ = client.command('go', {'position': 0.0}, block=True, timeout=5.0,
                                test=lambda s: abs(s['position']) < 5.0 or s['gripping'] == 1)
    assert done
    while gripper.state()['moving'] == 1:
        client.tick()
    state = gripper.state()
    assert state['missed'] == 1 and state['gripping'] == 0


def test_calibration_opens_the_fingers_and_takes_time():
    gripper, fingers, client = _make()
    fingers.position = 20.0
    gripper.handle_command('calibrate', '', '/c', 1)
    assert gripper.state()['ready'] == 0 and fingers.calls[-1][0] == 100.0
    while gripper.state()['calibrated'] != 1:
        client.tick()
        assert client.time < 2.0
    assert client.time >= gripper.calibration_time and fingers.position == pytest.approx(100.0)
    gripper.handle_command('clear_calibration', '', '/c', 2)
    assert gripper.state()['calibrated'] == 0 and gripper.state()['ready'] == 1


def test_configure_validates_and_is_atomic():
    gripper, _, _ = _make()
    gripper.handle_command('configure', '{"velocity": 80, "dead_zone": 2.5}', '/c', 1)
    assert gripper.parameters['velocity'] == 80.0 and gripper.parameters['dead_zone'] == 2.5
    bad_args = [('{"velocity": 180}', r'\[0, 100\]'), ('{"velocity": 10, "speed": 3}', 'unknown'),
                ('{"holding_force": "hard"}', 'number'), ('velocity=3', 'JSON'), ('[1, 2]', 'object')]
    for sequence, (bad, message) in enumerate(bad_args, start=2):
        before = dict(gripper.parameters)
        with pytest.raises(GripperCommandError, match=message):
            gripper.handle_command('configure', bad, '/c', sequence)
        assert gripper.parameters == before


def test_stop_holds_the_current_position_and_go_clips():
    gripper, fingers, client = _make()
    client.command('calibrate', block=True, timeout=5.0, test=lambda s: s['calibrated'] == 1)
    gripper.handle_command('go', '{"position": -20}', '/g', 10)
    assert fingers.calls[-1][0] == 0.0
    for _ in range(10):
        client.tick()
    gripper.handle_command('stop', '', '/s', 11)
    assert fingers.calls[-1][0] == pytest.approx(fingers.position) and 0.0 < fingers.position < 100.0


def test_reboot_drops_enabled_then_loses_calibration_and_parameters():
    gripper, _, client = _make()
    client.command('calibrate', block=True, timeout=5.0, test=lambda s: s['calibrated'] == 1)
    client.command('configure', args={'velocity': 10.0})
    done, _, duration = client.command('reboot', block=True, timeout=5.0,
                                       test=lambda s: s['enabled'] == 1 and s['ready'] == 1)
    assert done and duration >= gripper.reboot_time
    assert gripper.state()['calibrated'] == 0 and gripper.parameters == DEFAULT_PARAMETERS


def test_reset_clears_error():
    gripper, _, client = _make()
    gripper.error = True
    done, _, _ = client.command('reset', block=True, timeout=2.0, test=lambda s: s['error'] == 0 and s['ready'] == 1)
    assert done
