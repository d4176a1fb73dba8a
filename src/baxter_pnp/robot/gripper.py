"""``Gripper``: the electric gripper of one arm with baxter_interface's command protocol (interfaces §7).

Units: positions and parameters in percent (position 0 = closed, 100 = open); timeouts in wall-clock
seconds, except the finger motion of a blocking command, which is timed in ROS time (the robot's clock).
"""
import json
import time

import numpy as np
import rospy

from baxter_pnp.msgs import msg
from baxter_pnp.robot import sdk
from baxter_pnp.robot.errors import RobotError, RobotTimeout
from baxter_pnp.robot.topics import DEFAULT_MAX_AGE, CachedTopic, wait_for_subscriber, wait_until


def _state_flag(field, meaning):
    """A ``Gripper`` method ``field()``: True when the last state's ``field`` is 1 (baxter_interface's predicates)."""
    def flag(self):
        return getattr(self.state(), field) == 1
    flag.__name__, flag.__qualname__ = field, f'Gripper.{field}'
    flag.__doc__ = f'True when the gripper {meaning} (state ``{field}`` == 1; StreamLost if the state is stale).'
    return flag


class Gripper:
    """The electric gripper of one arm, with baxter_interface's command protocol (interfaces §7).

    Construction waits up to ``timeout`` s for the state and the properties, refuses anything but an
    electric gripper, sends the default parameters (``configure``) and, with ``calibrate=True``,
    calibrates the gripper if it reports it is not calibrated. Positions are percent of the travel:
    0 = closed, 100 = open.
    """

    def __init__(self, side, timeout=5.0, calibrate=True, max_age=DEFAULT_MAX_AGE):
        self.side = side
        self.max_age = max_age
        topics = sdk.gripper_topics(side)
        self._state = CachedTopic(topics.state, msg.EndEffectorState)
        self._properties = CachedTopic(topics.properties, msg.EndEffectorProperties)
        self._command_pub = rospy.Publisher(topics.command, msg.EndEffectorCommand, queue_size=10)
        self._sequence = 0
        self.parameters = dict(sdk.GRIPPER_PARAMETERS)
        self._state.wait(timeout, what='no gripper state')
        properties = self._properties.wait(timeout, accept=lambda p: p.ui_type in sdk.GRIPPER_TYPES,
                                           what='no gripper properties with a known ui_type')
        if sdk.GRIPPER_TYPES[properties.ui_type] != 'electric':
            raise RobotError(f'the {side} end effector is a {sdk.GRIPPER_TYPES[properties.ui_type]} gripper '
                             f'({properties.product!r}); only the electric gripper is supported')
        wait_for_subscriber(self._command_pub, timeout)
        self.configure()
        if calibrate and not self.calibrated() and not self.calibrate():
            raise RobotTimeout(f'the {side} gripper did not calibrate')

    # ------------------------------------------------------------------------------ state
    def state(self):
        """The last ``EndEffectorState`` (StreamLost if older than ``max_age`` s)."""
        return self._state.require_fresh(self.max_age)

    def require_fresh(self, max_age=None):
        self._state.require_fresh(self.max_age if max_age is None else max_age)

    def position(self):
        """Finger opening, percent of the travel (0 closed, 100 open)."""
        return float(self.state().position)

    gripping = _state_flag('gripping', 'holds something between the fingers')
    missed = _state_flag('missed', 'closed on nothing')
    moving = _state_flag('moving', 'fingers are moving')
    calibrated = _state_flag('calibrated', 'is calibrated')
    ready = _state_flag('ready', 'accepts commands')
    error = _state_flag('error', 'reports an error')

    # ------------------------------------------------------------------------------ commands
    def command(self, command, block=False, test=None, timeout=0.0, args=None):
        """Send one ``EndEffectorCommand`` as baxter_interface does; the result of ``test`` when blocking.

        ``id`` from the state, ``sender`` = node name + '_' + command, ``sequence`` counting from 1,
        ``args`` as JSON. Blocking: republish at 100 Hz until the state acknowledges the command
        (command_sender and command_sequence, up to ``timeout`` s), then until ``test()`` holds (at
        least 0.5 s more, robot time: the fingers move in the robot's time); returns ``test()``'s final
        value (False on timeout).
        """
        self._sequence = self._sequence % 0x7FFFFFFF + 1
        message = msg.EndEffectorCommand(id=self._state.value.id, command=command,
                                         sender=f'{rospy.get_name()}_{command}', sequence=self._sequence,
                                         args=json.dumps(args) if args is not None else '')
        rospy.loginfo(f'{self.side} gripper: {command} {message.args}'.rstrip())
        self._command_pub.publish(message)
        if not block:
            return True

        def acknowledged():
            state = self._state.value
            return state.command_sender == message.sender and state.command_sequence in (message.sequence, 0)
        started = time.monotonic()
        if not wait_until(acknowledged, timeout, body=lambda: self._command_pub.publish(message)):
            rospy.logdebug(f'{self.side} gripper: no acknowledgement of {command} within {timeout} s')
        remaining = max(0.5, timeout - (time.monotonic() - started))
        return wait_until(test or (lambda: True), remaining, body=lambda: self._command_pub.publish(message),
                           robot_time=True)

    def configure(self, **parameters):
        """Send the gripper parameters (percent): the defaults updated with ``parameters`` (non-blocking)."""
        unknown = sorted(set(parameters) - set(sdk.GRIPPER_PARAMETERS))
        if unknown:
            raise ValueError(f'unknown gripper parameter(s) {unknown} (known: {list(sdk.GRIPPER_PARAMETERS)})')
        self.parameters = dict(sdk.GRIPPER_PARAMETERS, **{k: float(v) for k, v in parameters.items()})
        self.command('configure', args=self.parameters)

    def calibrate(self, timeout=5.0):
        """Calibrate (clearing an old calibration and an error first, as baxter_interface); True when calibrated."""
        if self.calibrated():
            self.command('clear_calibration', block=True, timeout=2.0,
                         test=lambda: self._state.value.calibrated == 0 and self._state.value.ready == 1)
        if self.error():
            self.command('reset', block=True, timeout=2.0,
                         test=lambda: self._state.value.error == 0 and self._state.value.ready == 1)
        done = self.command('calibrate', block=True, timeout=timeout,
                            test=lambda: self._state.value.calibrated == 1 and self._state.value.ready == 1)
        if done:
            self.command('configure', args=self.parameters)
        return done

    def command_position(self, position, block=False, timeout=5.0):
        """Move the fingers to ``position`` percent (clipped to 0-100); with ``block``, True once there or gripping.

        Returns False (warning) if the gripper is not calibrated, as baxter_interface.
        """
        if not self.calibrated():
            rospy.logwarn(f'{self.side} gripper: cannot move until calibrated')
            return False
        position = float(np.clip(position, 0.0, 100.0))

        def there():
            state = self._state.value
            return abs(state.position - position) < self.parameters['dead_zone'] or state.gripping == 1
        return self.command('go', block=block, test=there, timeout=timeout, args={'position': position})

    def open(self, block=False, timeout=5.0):
        return self.command_position(100.0, block=block, timeout=timeout)

    def close(self, block=False, timeout=5.0):
        return self.command_position(0.0, block=block, timeout=timeout)
