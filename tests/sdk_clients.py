"""Clients that touch exactly what ``baxter_interface`` 1.2.0 touches (the SDK is not installable here):
``baxter_dataflow.wait_for`` in ROS time with its timeouts and rates, ``RobotEnable``, ``Limb``, ``Head``,
``DigitalIO``, ``AnalogIO``, ``Navigator``. Used by tests/test_whole_baxter.py and tests/startup_client.py.
"""
import errno
import re
import rospy
from sensor_msgs.msg import JointState
from std_msgs.msg import Bool, Float64

from baxter_pnp.kinematics import arm_joint_names
from baxter_pnp.msgs import msg

JOINT_ANGLE_TOLERANCE = 0.008726646          # baxter_interface.settings
HEAD_PAN_ANGLE_TOLERANCE = 0.1396263401      # baxter_interface.settings
VERSIONS_SDK2ROBOT = {'1.2.0': ['1.2.0']}    # baxter_interface.settings
SMOKE_TESTS = {'1.2.0': ['Enable', 'Messages', 'Services', 'Head', 'MoveArms', 'Grippers', 'BlinkLEDs', 'Cameras']}
NEUTRAL = [0.0, -0.55, 0.0, 0.75, 0.0, 1.26, 0.0]


# ============================================================================ the SDK's waits and clients
def wait_for(test, timeout=1.0, rate=100, timeout_msg='timeout expired', body=None):
    """baxter_dataflow.wait_for: poll ``test`` at ``rate`` Hz of ROS time, calling ``body`` between polls; OSError
    ETIMEDOUT once ``timeout`` ROS seconds have passed."""
    end_time = rospy.get_time() + timeout
    rate = rospy.Rate(rate)
    while not test():
        if rospy.is_shutdown():
            raise OSError(errno.ESHUTDOWN, 'ROS Shutdown')
        if rospy.get_time() >= end_time:
            raise OSError(errno.ETIMEDOUT, timeout_msg)
        if body is not None:
            body()
        rate.sleep()
    return True


class SdkRobotEnable:
    """baxter_interface.RobotEnable(versioned): /robot/state (2 s), the version check, enable / disable."""

    def __init__(self, versioned=False):
        self._state = None
        self._sub = rospy.Subscriber('robot/state', msg.AssemblyState, self._on_state)
        if versioned:
            assert self.version_check(), 'RobotEnable: software version mismatch (the program would exit)'
        wait_for(lambda: self._state is not None, timeout=2.0, timeout_msg='Failed to get robot state on robot/state')
        self._pub = rospy.Publisher('robot/set_super_enable', Bool, queue_size=10)

    def _on_state(self, message):
        self._state = message

    def state(self):
        return self._state

    @staticmethod
    def version_check():
        robot_version = rospy.get_param('rethink/software_version', None)
        match = robot_version and re.search(r'^([0-9]+)\.([0-9]+)\.([0-9]+)', robot_version)   # first 3 digits
        return bool(match) and match.group(0) in VERSIONS_SDK2ROBOT['1.2.0']

    def _toggle(self, status):
        wait_for(lambda: self._state.enabled == status, timeout=2.0 if status else 5.0,
                 timeout_msg=f'Failed to {"en" if status else "dis"}able robot', body=lambda: self._pub.publish(status))

    def enable(self):
        self._toggle(True)

    def disable(self):
        self._toggle(False)


class SdkLimb:
    """baxter_interface.Limb(side): joint states and endpoint state (wait), commands, move_to_joint_positions."""

    def __init__(self, side):
        self.name, self._angles, self._velocities, self._endpoint = side, {}, {}, None
        ns = f'/robot/limb/{side}/'
        self._pub_speed = rospy.Publisher(ns + 'set_speed_ratio', Float64, latch=True, queue_size=10)
        self._pub_command = rospy.Publisher(ns + 'joint_command', msg.JointCommand, tcp_nodelay=True, queue_size=10)
        self._pub_timeout = rospy.Publisher(ns + 'joint_command_timeout', Float64, latch=True, queue_size=10)
        self._subs = [rospy.Subscriber(ns + 'endpoint_state', msg.EndpointState, self._on_endpoint, queue_size=1,
                                       tcp_nodelay=True),
                      rospy.Subscriber('robot/joint_states', JointState, self._on_joints, queue_size=1, tcp_nodelay=True)]
        wait_for(lambda: len(self._angles) > 0, timeout_msg=f'{side} limb init failed to get current joint_states')
        wait_for(lambda: self._endpoint is not None, timeout_msg=f'{side} limb init failed to get endpoint_state')

    def _on_joints(self, message):
        for i, name in enumerate(message.name):
            if self.name in name:
                self._angles[name], self._velocities[name] = message.position[i], message.velocity[i]

    def _on_endpoint(self, message):
        self._endpoint = message

    def joint_names(self):
        return arm_joint_names(self.name)

    def joint_angle(self, joint):
        return self._angles[joint]

    def joint_angles(self):
        return dict(self._angles)

    def joint_velocities(self):
        return dict(self._velocities)

    def endpoint_pose(self):
        return self._endpoint.pose

    def set_command_timeout(self, timeout):
        self._pub_timeout.publish(Float64(timeout))

    def set_joint_position_speed(self, speed):
        self._pub_speed.publish(Float64(speed))

    def _command(self, mode, values):
        self._pub_command.publish(msg.JointCommand(mode=mode, names=list(values), command=list(values.values())))

    def set_joint_positions(self, positions):
        self._command(msg.JointCommand.POSITION_MODE, positions)

    def set_joint_velocities(self, velocities):
        self._command(msg.JointCommand.VELOCITY_MODE, velocities)

    def exit_control_mode(self, timeout=0.2):
        self.set_command_timeout(timeout)
        self.set_joint_positions(self.joint_angles())

    def move_to_joint_positions(self, positions, timeout=15.0):
        wait_for(lambda: all(abs(a - self._angles[j]) < JOINT_ANGLE_TOLERANCE for j, a in positions.items()),
                 timeout=timeout, rate=100, timeout_msg=f'{self.name} limb failed to reach commanded joint positions',
                 body=lambda: self.set_joint_positions(positions))

    def move_to_neutral(self, timeout=15.0):
        self.move_to_joint_positions(dict(zip(self.joint_names(), NEUTRAL)), timeout)


class SdkHead:
    """baxter_interface.Head: head_state (5 s), set_pan (speed ratio), command_nod."""

    def __init__(self):
        self._state = {}
        self._pub_pan = rospy.Publisher('/robot/head/command_head_pan', msg.HeadPanCommand, queue_size=10)
        self._pub_nod = rospy.Publisher('/robot/head/command_head_nod', Bool, queue_size=10)
        self._sub = rospy.Subscriber('/robot/head/head_state', msg.HeadState, self._on_state)
        wait_for(lambda: len(self._state) != 0, timeout=5.0,
                 timeout_msg='Failed to get current head state from /robot/head/head_state')

    def _on_state(self, message):
        self._state = {'pan': message.pan, 'panning': message.isTurning, 'nodding': message.isNodding}

    def pan(self):
        return self._state['pan']

    def panning(self):
        return self._state['panning']

    def nodding(self):
        return self._state['nodding']

    def set_pan(self, angle, speed=1.0, timeout=10.0):
        command = msg.HeadPanCommand(angle, speed, True)
        self._pub_pan.publish(command)
        if timeout != 0:
            wait_for(lambda: abs(self.pan() - angle) <= HEAD_PAN_ANGLE_TOLERANCE, timeout=timeout, rate=100,
                     timeout_msg=f'Failed to move head to pan command {angle}',
                     body=lambda: self._pub_pan.publish(command))

    def command_nod(self, timeout=5.0):
        self._pub_nod.publish(True)
        wait_for(self.nodding, timeout=timeout, rate=100, timeout_msg='Failed to initiate head nod command',
                 body=lambda: self._pub_nod.publish(True))
        wait_for(lambda: not self.nodding(), timeout=timeout, rate=100,
                 timeout_msg='Failed to complete head nod command', body=lambda: self._pub_nod.publish(False))


class SdkDigitalIO:
    """baxter_interface.DigitalIO(name): its state (2 s), set_output (waits 2 s for the state to follow)."""

    def __init__(self, component_id):
        self._id, self._state, self._is_output, self.changes = component_id, None, False, []
        self._sub = rospy.Subscriber(f'/robot/digital_io/{component_id}/state', msg.DigitalIOState, self._on_state)
        wait_for(lambda: self._state is not None, timeout=2.0,
                 timeout_msg=f'Failed to get current digital_io state from /robot/digital_io/{component_id}')
        if self._is_output:
            self._pub = rospy.Publisher('/robot/digital_io/command', msg.DigitalOutputCommand, queue_size=10)

    def _on_state(self, message):
        new_state = message.state == msg.DigitalIOState.PRESSED
        if self._state is None:
            self._is_output = not message.isInputOnly
        elif new_state != self._state:
            self.changes.append(new_state)            # baxter_interface: the state_changed signal
        self._state = new_state

    @property
    def is_output(self):
        return self._is_output

    @property
    def state(self):
        return self._state

    def set_output(self, value, timeout=2.0):
        if not self._is_output:
            raise IOError(errno.EACCES, f'Component is not an output [digital_io: {self._id}]')
        command = msg.DigitalOutputCommand(name=self._id, value=bool(value))
        self._pub.publish(command)
        wait_for(lambda: self.state == bool(value), timeout=timeout, rate=100,
                 timeout_msg=f'Failed to command digital io to: {value!r}', body=lambda: self._pub.publish(command))


class SdkAnalogIO:
    """baxter_interface.AnalogIO(name): its state (2 s), set_output (waits 2 s for the state to follow)."""

    def __init__(self, component_id):
        self._id, self._state, self._is_output = component_id, {}, False
        self._sub = rospy.Subscriber(f'/robot/analog_io/{component_id}/state', msg.AnalogIOState, self._on_state)
        wait_for(lambda: len(self._state) != 0, timeout=2.0,
                 timeout_msg=f'Failed to get current analog_io state from /robot/analog_io/{component_id}')
        if self._is_output:
            self._pub = rospy.Publisher('/robot/analog_io/command', msg.AnalogOutputCommand, queue_size=10)

    def _on_state(self, message):
        self._is_output, self._state['value'] = not message.isInputOnly, message.value

    def state(self):
        return self._state['value']

    def set_output(self, value, timeout=2.0):
        command = msg.AnalogOutputCommand(name=self._id, value=value)
        self._pub.publish(command)
        wait_for(lambda: self.state() == value, timeout=timeout, rate=100,
                 timeout_msg=f'Failed to command analog io to: {value}', body=lambda: self._pub.publish(command))


class SdkNavigator:
    """baxter_interface.Navigator(location): navigator state, its inner and outer lights as DigitalIO."""

    def __init__(self, location):
        self._state, self.button0_presses = None, 0
        self._sub = rospy.Subscriber(f'robot/navigators/{location}_navigator/state', msg.NavigatorState,
                                     self._on_state)
        self.inner_light = SdkDigitalIO(f'{location}_inner_light')
        self.outer_light = SdkDigitalIO(f'{location}_outer_light')
        wait_for(lambda: self._state is not None,
                 timeout_msg=f'Navigator init failed to get current state from {location}_navigator/state')

    def _on_state(self, message):
        if self._state is not None and message.buttons[0] and not self._state.buttons[0]:
            self.button0_presses += 1                 # baxter_interface: the button0_changed signal (True)
        self._state = message

    @property
    def wheel(self):
        return self._state.wheel

    @property
    def button0(self):
        return self._state.buttons[0]

    @property
    def lights(self):
        return dict(zip(self._state.light_names, self._state.lights))
