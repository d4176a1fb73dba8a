"""Baxter's electric gripper end-effector protocol, as a pure state machine (no ROS, no PyBullet).

It speaks the ``baxter_core_msgs/EndEffector{Command,State,Properties}`` protocol the way
``baxter_interface.Gripper`` expects it (reference/baxter_interfaces.md section 7):

- properties: ``ui_type`` ELECTRIC_GRIPPER (2), the same ``id`` as the state, a ``firmware_date`` in the
  SDK's ``%Y/%m/%d %H:%M:%S`` format that passes the SDK 1.2.0 version check silently;
- every received command is acknowledged at once (repeats of the same command/sender/sequence are
  not executed twice): its ``command``, ``sender`` and ``sequence`` are echoed
  in the state's ``command``, ``command_sender`` and ``command_sequence``, so baxter_interface's blocking
  calls go straight to their completion test instead of burning their timeout (the official simulator
  never acknowledges);
- the gripper starts uncalibrated; ``go`` is refused until ``calibrate`` has completed (the fingers open
  fully, then ``calibrated`` and ``ready`` become 1), like a real electric gripper; ``clear_calibration``,
  ``reset`` (clears ``error``), ``reboot`` (``enabled`` and ``ready`` drop for a while, calibration and
  parameters are lost), ``configure`` (JSON ``velocity``, ``moving_force``, ``holding_force``,
  ``dead_zone``, each 0-100 %), ``go`` (JSON ``{"position": p}``, 0 = closed, 100 = open), ``stop``,
  ``grip`` (close), ``release`` / ``prepare_to_grip`` (open), ``no_op`` and ``set`` (acknowledged only).

Finger motion is delegated to ``actuate(position_percent, force_percent, velocity_percent)`` (in the fake
Baxter: ``SimWorld.command_gripper`` for one side); what the fingers do is fed back through ``update``
(``SimWorld.gripper_state``: ``position_percent``, ``force_percent``, ``moving``, ``gripping``, ``missed``).
Times are in seconds of whatever clock the caller uses (the simulated clock in the fake Baxter).
The command's ``id`` is not checked (whether the real robot does is unverified).
"""
import json
import math

from baxter_pnp.robot.sdk import GRIPPER_PARAMETERS, GRIPPER_TYPES

ELECTRIC_GRIPPER = next(code for code, kind in GRIPPER_TYPES.items() if kind == 'electric')   # ui_type
HARDWARE_ID = 65538                       # the official simulator's id for an electric gripper
STATE_FALSE, STATE_TRUE = 0, 1            # EndEffectorState tri-state values used here
POSITION_CLOSED, POSITION_OPEN = 0.0, 100.0
# baxter_interface.Gripper's defaults, sent with `configure` at construction (percent of the maximum).
DEFAULT_PARAMETERS = GRIPPER_PARAMETERS
PROPERTIES = {
    'ui_type': ELECTRIC_GRIPPER,
    'manufacturer': 'Rethink Research Robot',
    'product': 'Electric Gripper',
    'serial_number': '3712199347',
    'hardware_rev': '2',
    'firmware_rev': '3.0.0 5.5',
    'firmware_date': '2014/7/24 18:30:00',   # later than the SDK 1.2.0 warning date 2014/5/20 00:00:00
    'has_calibration': True,
    'controls_grip': True,
    'senses_grip': True,
    'reverses_grip': True,
    'controls_force': True,
    'senses_force': True,
    'controls_position': True,
    'senses_position': True,
    'properties': '',
}


class GripperCommandError(ValueError):
    """A command was acknowledged but not executed (unknown, malformed, or not allowed in this state)."""


class ElectricGripperProtocol:
    """State of one electric gripper and its reaction to ``EndEffectorCommand``s.

    ``actuate(position_percent, force_percent, velocity_percent)`` moves the fingers. ``calibration_time``
    and ``reboot_time`` (s) are the shortest durations of those procedures.
    """

    def __init__(self, actuate, hardware_id=HARDWARE_ID, calibration_time=0.5, reboot_time=1.0):
        self._actuate = actuate
        self.hardware_id = int(hardware_id)
        self.calibration_time = float(calibration_time)
        self.reboot_time = float(reboot_time)
        self.parameters = dict(DEFAULT_PARAMETERS)
        self.enabled = True
        self.calibrated = False
        self.error = False
        self._calibrating_since = None     # time the running calibration started, or None
        self._rebooting_since = None       # time the running reboot started, or None
        self._fingers = {'position_percent': POSITION_OPEN, 'force_percent': 0.0,
                         'moving': False, 'gripping': False, 'missed': False}
        self._now = 0.0
        self._ack = ('', '', 0)            # (command, sender, sequence) of the last command received

    # ------------------------------------------------------------------ published content
    @property
    def ready(self):
        """True when the gripper accepts motion commands' procedures (not calibrating, not rebooting)."""
        return self._calibrating_since is None and self._rebooting_since is None

    def properties(self):
        """Field values of the ``EndEffectorProperties`` message."""
        return dict(PROPERTIES, id=self.hardware_id)

    def state(self):
        """Field values of the ``EndEffectorState`` message (``timestamp`` in seconds)."""
        fingers = self._fingers
        command, sender, sequence = self._ack
        flag = {False: STATE_FALSE, True: STATE_TRUE}
        return {
            'timestamp': self._now,
            'id': self.hardware_id,
            'enabled': flag[self.enabled],
            'calibrated': flag[self.calibrated],
            'ready': flag[self.ready],
            'moving': flag[bool(fingers['moving'])],
            'gripping': flag[bool(fingers['gripping'])],
            'missed': flag[bool(fingers['missed'])],
            'error': flag[self.error],
            'reverse': STATE_FALSE,
            'position': float(fingers['position_percent']),
            'force': float(fingers['force_percent']),
            'state': '',
            'command': command,
            'command_sender': sender,
            'command_sequence': sequence,
        }

    # ------------------------------------------------------------------ time
    def update(self, now, fingers):
        """Advance to time ``now`` (s) with the fingers' measured state (``SimWorld.gripper_state`` dict)."""
        self._now = float(now)
        self._fingers = dict(fingers)
        if self._rebooting_since is not None and now - self._rebooting_since >= self.reboot_time:
            self._rebooting_since = None
            self.enabled = True
        if (self._calibrating_since is not None and now - self._calibrating_since >= self.calibration_time
                and not fingers['moving']):
            self._calibrating_since = None
            self.calibrated = True

    # ------------------------------------------------------------------ commands
    def handle_command(self, command, args='', sender='', sequence=0):
        """Acknowledge and execute one ``EndEffectorCommand`` (``args``: JSON text or '').

        baxter_interface republishes a command at 100 Hz until it sees the acknowledgement and the
        completion test: a repeat of the last command (same command, sender and non-zero sequence) is
        not executed again, so that e.g. a repeated ``calibrate`` does not restart the calibration.
        Raises ``GripperCommandError`` (after acknowledging) when the command is not executed.
        """
        received = (str(command), str(sender), int(sequence))
        if received == self._ack and received[2] != 0:
            return
        self._ack = received
        handler = self._HANDLERS.get(command)
        if handler is None:
            raise GripperCommandError(f'unknown end-effector command {command!r}')
        if self._rebooting_since is not None and command != 'no_op':
            raise GripperCommandError(f'{command!r} ignored: the gripper is rebooting')
        handler(self, _parse_args(command, args))

    def _configure(self, args):
        unknown = sorted(set(args) - set(DEFAULT_PARAMETERS))
        if unknown:
            raise GripperCommandError(f'configure: unknown parameter(s) {", ".join(unknown)} '
                                      f'(known: {", ".join(DEFAULT_PARAMETERS)})')
        for key, value in args.items():
            if not _is_number(value) or not 0.0 <= value <= 100.0:
                raise GripperCommandError(f'configure: {key} must be a number in [0, 100], got {value!r}')
        self.parameters.update({key: float(value) for key, value in args.items()})

    def _go(self, args):
        if 'position' not in args or not _is_number(args['position']):
            raise GripperCommandError(f'go: args must hold a numeric "position" (0-100), got {args!r}')
        if not self.calibrated or not self.ready:
            raise GripperCommandError('go refused: the gripper is not calibrated (send "calibrate" first)')
        self._move(min(max(float(args['position']), POSITION_CLOSED), POSITION_OPEN))

    def _grip(self, args):
        self._go({'position': POSITION_CLOSED})

    def _release(self, args):
        self._go({'position': POSITION_OPEN})

    def _stop(self, args):
        self._move(float(self._fingers['position_percent']))

    def _calibrate(self, args):
        self.calibrated = False
        self._calibrating_since = self._now
        self._move(POSITION_OPEN)

    def _clear_calibration(self, args):
        self.calibrated = False
        self._calibrating_since = None

    def _reset(self, args):
        self.error = False

    def _reboot(self, args):
        self.enabled = False
        self.calibrated = False
        self.error = False
        self._calibrating_since = None
        self._rebooting_since = self._now
        self.parameters = dict(DEFAULT_PARAMETERS)

    def _acknowledge_only(self, args):
        pass

    def _move(self, position_percent):
        self._actuate(position_percent, self.parameters['moving_force'], self.parameters['velocity'])

    _HANDLERS = {
        'configure': _configure, 'go': _go, 'grip': _grip, 'release': _release, 'prepare_to_grip': _release,
        'stop': _stop, 'calibrate': _calibrate, 'clear_calibration': _clear_calibration, 'reset': _reset,
        'reboot': _reboot, 'no_op': _acknowledge_only, 'set': _acknowledge_only,
    }


def _is_number(value):
    return isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)


def _parse_args(command, args):
    """The command's JSON arguments as a dict ('' means none)."""
    if not args:
        return {}
    try:
        parsed = json.loads(args)
    except ValueError as error:
        raise GripperCommandError(f'{command}: args are not valid JSON ({error}): {args!r}') from None
    if not isinstance(parsed, dict):
        raise GripperCommandError(f'{command}: args must be a JSON object, got {args!r}')
    return parsed
