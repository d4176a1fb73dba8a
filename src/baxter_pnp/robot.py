"""Thin clients of the Baxter SDK's ROS topics and services: the robot edge of the package.

The classes follow baxter_interface (reference/baxter_interfaces.md §2-8) and use nothing but the
SDK's topics and services, so the same code drives a real Baxter and the fake one:

- ``RobotEnable``: ``/robot/state``, enable / disable / reset / stop.
- ``Limb(side, safety)``: joint angles, endpoint pose, the IK service, position and velocity commands.
  Every arm command first passes ``safety`` (a ``baxter_pnp.safety.ArmSafety``) and is logged.
- ``Gripper(side)``: the electric gripper's command protocol (calibrate, open, close, state).
- ``HandCamera(side)``: opens the hand camera and delivers BGR frames with their ``CameraModel``.
- ``hand_eye_transform(side)``: the camera mount, from tf (or the URDF if tf does not answer).

Watchdog: every subscribed stream (``CachedTopic``) keeps its last valid message and when it arrived;
``require_fresh(max_age)`` raises ``StreamLost`` naming the topic when nothing valid came for longer.
Messages with NaN/inf or of an unsupported kind are rejected (logged), never cached.

Clocks: timeouts and stream ages are wall-clock seconds, so a stalled simulated clock cannot hang a
call; motion timing (the joint-space ramp of ``move_to_joint_positions``) follows ROS time, which is
the robot's clock (the simulated clock with the fake Baxter). Frames: ``base`` for poses (4x4, metres),
radians for joints. Nothing here calls ``rospy.init_node``: the application does.
"""
import collections
import errno
import json
import threading
import time
from typing import NamedTuple

import numpy as np
import rospy
from geometry_msgs.msg import PoseStamped
from sensor_msgs.msg import CameraInfo, Image, JointState
from std_msgs.msg import Bool, Empty, Float64

from baxter_pnp.camera import CameraModel
from baxter_pnp.kinematics import arm_joint_names
from baxter_pnp.msgs import msg, srv
from baxter_pnp.ros_image import msg_to_bgr
from baxter_pnp.transforms import from_xyz_quat, invert, matrix_to_pose_msg, to_xyz_quat

JOINT_ANGLE_TOLERANCE = 0.008726646   # rad (0.5 deg): baxter_interface's "arrived" threshold
ROBOT_TIME_BACKSTOP = 10.0             # a wait in robot time gives up after this many times its timeout of wall time
CAMERA_INFO_GRACE = 1.0                # s (wall): frames may arrive before the first camera_info
COMMAND_TIMEOUT = 0.2                 # s: the robot drops velocity commands older than this (SDK default)
DEFAULT_SPEED_RATIO = 0.3             # the robot's position-mode speed ratio until set_speed_ratio is called
COMMAND_RATE_HZ = 100.0               # joint command stream rate (as baxter_interface)
DEFAULT_MAX_AGE = 0.5                 # s: a robot stream older than this is considered lost
ENDPOINT_HISTORY = 200                # endpoint states kept for endpoint_pose_at (2 s at 100 Hz)
CAMERA_MODES = ((1280, 800), (960, 600), (640, 400), (480, 300), (384, 240), (320, 200))
# baxter_interface.Gripper's default parameters (percent), sent with 'configure'.
GRIPPER_PARAMETERS = {'velocity': 50.0, 'moving_force': 40.0, 'holding_force': 30.0, 'dead_zone': 5.0}
GRIPPER_TYPES = {1: 'suction', 2: 'electric', 3: 'custom'}    # EndEffectorProperties.ui_type


class RobotError(RuntimeError):
    """The robot did not do what was asked, or an interface it must provide is missing."""


class RobotTimeout(RobotError):
    """The robot did not reach the expected state within the timeout."""


class StreamLost(RobotError):
    """A robot topic stopped delivering valid messages (``topic``: its name, ``age``: seconds since the last)."""

    def __init__(self, topic, age, max_age):
        self.topic, self.age = topic, age
        since = 'no valid message received yet' if age == float('inf') else f'last valid message {age:.2f} s ago'
        super().__init__(f'stream lost: {topic} ({since}, max age {max_age:.2f} s)')


class ServiceUnavailable(RobotError):
    """A ROS service the robot must provide is not advertised."""


class IKFailure(RobotError):
    """The robot's IK service found no joint solution (the message gives the reason)."""


def _wait_until(condition, timeout, body=None, rate_hz=COMMAND_RATE_HZ, robot_time=False):
    """Call ``body()`` at ``rate_hz`` (wall clock) until ``condition()``; True if it held within ``timeout`` s.

    With ``robot_time`` the timeout counts ROS time (the robot's: a simulator running slower than real
    time gets the same motion time as a real robot), with a wall-clock backstop of
    ``ROBOT_TIME_BACKSTOP`` x ``timeout`` in case the robot's clock stops."""
    deadline = time.monotonic() + (ROBOT_TIME_BACKSTOP * timeout if robot_time else timeout)
    robot_deadline = rospy.get_time() + timeout if robot_time else None
    while not condition():
        if rospy.is_shutdown():
            raise RobotError('ROS is shutting down')
        if time.monotonic() > deadline or (robot_time and rospy.get_time() > robot_deadline):
            return False
        if body is not None:
            body()
        time.sleep(1.0 / rate_hz)
    return True


def _wait_for_subscriber(publisher, timeout):
    """Wait until ``publisher`` has a subscriber (a first message would otherwise be lost); RobotTimeout if none."""
    if not _wait_until(lambda: publisher.get_num_connections() > 0, timeout, rate_hz=50.0):
        raise RobotTimeout(f'nobody subscribes to {publisher.resolved_name} after {timeout} s: '
                           f'is the robot (or the fake Baxter) running?')


def _wait_for_service(name, timeout):
    try:
        rospy.wait_for_service(name, timeout=timeout)
    except rospy.ROSException:
        raise ServiceUnavailable(f'service {name} is not available (waited {timeout} s): is the robot '
                                 f'(or the fake Baxter) running?') from None


class CachedTopic:
    """One subscribed topic: the last valid value, when it arrived (wall clock), and a freshness check.

    ``convert(message)`` turns a message into the cached value; it returns None for a message that is
    not meant for this client (ignored silently) and raises ValueError for an invalid one (logged as
    an error, not cached).
    """

    def __init__(self, topic, message_type, convert=None, buff_size=65536, tcp_nodelay=False):
        self.topic = topic
        self._convert = convert or (lambda message: message)
        self._latest = None                  # (value, wall time of arrival)
        self._arrived = threading.Condition()
        self._subscriber = rospy.Subscriber(topic, message_type, self._callback, queue_size=1,
                                            buff_size=buff_size, tcp_nodelay=tcp_nodelay)

    def _callback(self, message):
        try:
            value = self._convert(message)
        except ValueError as error:
            rospy.logerr_throttle_identical(5.0, f'{self.topic}: message rejected: {error}')
            return
        if value is None:
            return
        with self._arrived:
            self._latest = (value, time.monotonic())
            self._arrived.notify_all()

    @property
    def value(self):
        """The last valid value, or None."""
        latest = self._latest
        return None if latest is None else latest[0]

    def age(self):
        """Seconds (wall clock) since the last valid message; inf if none came."""
        latest = self._latest
        return float('inf') if latest is None else time.monotonic() - latest[1]

    def require_fresh(self, max_age=DEFAULT_MAX_AGE):
        """The last valid value if it is at most ``max_age`` s old; StreamLost otherwise."""
        latest = self._latest
        age = float('inf') if latest is None else time.monotonic() - latest[1]
        if age > max_age:
            raise StreamLost(self.topic, age, max_age)
        return latest[0]

    def wait(self, timeout, accept=None, what=None):
        """The first valid value (with ``accept(value)`` true, if given) within ``timeout`` s, else RobotTimeout."""
        deadline = time.monotonic() + timeout
        with self._arrived:
            while True:
                value = self.value
                if value is not None and (accept is None or accept(value)):
                    return value
                remaining = deadline - time.monotonic()
                if remaining <= 0 or rospy.is_shutdown():
                    raise RobotTimeout(f'{what or "no valid message"} on {self.topic} within {timeout} s')
                self._arrived.wait(min(remaining, 0.1))

    def unregister(self):
        self._subscriber.unregister()


# ==================================================================================== robot state
class RobotEnable:
    """``/robot/state`` and the enable / disable / reset / stop requests, with baxter_interface's semantics."""

    def __init__(self, timeout=2.0):
        self._state = CachedTopic('/robot/state', msg.AssemblyState)
        self._enable_pub = rospy.Publisher('/robot/set_super_enable', Bool, queue_size=10)
        self._reset_pub = rospy.Publisher('/robot/set_super_reset', Empty, queue_size=10)
        self._stop_pub = rospy.Publisher('/robot/set_super_stop', Empty, queue_size=10)
        self._state.wait(timeout, what='no robot state')

    def state(self):
        """The last ``AssemblyState`` (fields ready, enabled, stopped, error, estop_button, estop_source)."""
        return self._state.value

    def require_fresh(self, max_age=DEFAULT_MAX_AGE):
        self._state.require_fresh(max_age)

    def enable(self, timeout=2.0):
        """Enable the robot (resetting it first if it is stopped); RobotTimeout if it does not within ``timeout`` s."""
        if self.state().stopped:
            self.reset()
        rospy.loginfo('robot: enable')
        self._toggle(True, timeout)

    def disable(self, timeout=5.0):
        """Disable the robot; RobotTimeout if it is still enabled after ``timeout`` s."""
        rospy.loginfo('robot: disable')
        self._toggle(False, timeout)

    def _toggle(self, enable, timeout):
        if not _wait_until(lambda: self.state().enabled == enable, timeout,
                           body=lambda: self._enable_pub.publish(Bool(enable))):
            raise RobotTimeout(f'failed to {"enable" if enable else "disable"} the robot within {timeout} s '
                               f'(robot state: {self._describe()})')

    def reset(self, timeout=3.0):
        """Clear a stop or an error; False (warning) if the robot reports an error it cannot clear.

        Raises RobotError when the e-stop button is pressed, RobotTimeout when nothing clears.
        """
        state = self.state()
        if state.stopped and state.estop_button == msg.AssemblyState.ESTOP_BUTTON_PRESSED:
            raise RobotError('cannot reset the robot: its e-stop button is pressed (release it first)')
        rospy.loginfo('robot: reset')

        def cleared():
            s = self.state()
            return not (s.enabled or s.stopped or s.error or s.estop_button or s.estop_source)
        if _wait_until(cleared, timeout, body=lambda: self._reset_pub.publish(Empty())):
            return True
        state = self.state()
        if state.error and not state.stopped:
            rospy.logwarn(f'robot: reset did not clear the error state ({self._describe()})')
            return False
        raise RobotTimeout(f'failed to reset the robot within {timeout} s (robot state: {self._describe()})')

    def stop(self, timeout=3.0):
        """Stop the robot (as the e-stop does); RobotTimeout if it is not stopped within ``timeout`` s."""
        rospy.loginfo('robot: stop')
        if not _wait_until(lambda: self.state().stopped, timeout, body=lambda: self._stop_pub.publish(Empty())):
            raise RobotTimeout(f'failed to stop the robot within {timeout} s (robot state: {self._describe()})')

    def _describe(self):
        s = self.state()
        return (f'enabled={s.enabled} stopped={s.stopped} error={s.error} '
                f'estop_button={s.estop_button} estop_source={s.estop_source}')


# ==================================================================================== limb
class ArmJointState(NamedTuple):
    """The 7 arm joints of one /robot/joint_states message, s0..w2: angles (rad), velocities (rad/s; None if absent)."""
    positions: np.ndarray
    velocities: np.ndarray


class EndpointState(NamedTuple):
    """Endpoint (``<side>_gripper``) pose in base (4x4, m), twist [v (m/s); w (rad/s)] in base, stamp (ROS time, s)."""
    T_base_gripper: np.ndarray
    twist: np.ndarray
    stamp: float = 0.0


def _arm_joint_state(joint_names, message):
    """ArmJointState of ``joint_names`` from a JointState; None when the message lacks one of them."""
    index = {name: i for i, name in enumerate(message.name)}
    if not all(name in index for name in joint_names):
        return None
    rows = [index[name] for name in joint_names]

    def column(values, what):
        if len(values) != len(message.name):
            return None
        array = np.array([values[i] for i in rows], dtype=float)
        if not np.all(np.isfinite(array)):
            raise ValueError(f'non-finite joint {what}: {dict(zip(joint_names, array.round(4)))}')
        return array
    positions = column(message.position, 'position')
    if positions is None:
        raise ValueError(f'{len(message.position)} positions for {len(message.name)} joint names')
    return ArmJointState(positions, column(message.velocity, 'velocity'))


def _endpoint_state(message):
    """EndpointState from a baxter_core_msgs/EndpointState; ValueError for non-finite values or a bad quaternion."""
    p, q, v, w = message.pose.position, message.pose.orientation, message.twist.linear, message.twist.angular
    position, quaternion = np.array([p.x, p.y, p.z]), np.array([q.x, q.y, q.z, q.w])
    twist = np.array([v.x, v.y, v.z, w.x, w.y, w.z])
    if not (np.all(np.isfinite(position)) and np.all(np.isfinite(quaternion)) and np.all(np.isfinite(twist))):
        raise ValueError(f'non-finite endpoint state: position {position}, quaternion {quaternion}, twist {twist}')
    if abs(np.linalg.norm(quaternion) - 1.0) > 1e-3:
        raise ValueError(f'endpoint orientation is not a unit quaternion: {quaternion}')
    return EndpointState(from_xyz_quat(position, quaternion), twist, message.header.stamp.to_sec())


class Limb:
    """One arm (``side`` 'left' or 'right') through the SDK's topics; every command passes ``safety`` first.

    ``safety`` is the ``baxter_pnp.safety.ArmSafety`` of this arm. Construction waits up to
    ``timeout`` s for joint states and the endpoint state. Readings older than ``max_age`` s raise
    ``StreamLost``.
    """

    def __init__(self, side, safety, timeout=5.0, max_age=DEFAULT_MAX_AGE):
        self.side = side
        self.joint_names = arm_joint_names(side)
        if safety.side != side:
            raise ValueError(f'the safety checks are for the {safety.side} arm, not the {side} arm')
        self.safety = safety
        self.max_age = max_age
        self._speed_ratio = DEFAULT_SPEED_RATIO
        limb = f'/robot/limb/{side}'
        self.ik_service_name = f'/ExternalTools/{side}/PositionKinematicsNode/IKService'
        self._ik = rospy.ServiceProxy(self.ik_service_name, srv.SolvePositionIK)
        self._joint_states = CachedTopic('/robot/joint_states', JointState,
                                         lambda message: _arm_joint_state(self.joint_names, message))
        self._endpoint_history = collections.deque(maxlen=ENDPOINT_HISTORY)
        self._endpoint = CachedTopic(f'{limb}/endpoint_state', msg.EndpointState, self._remember_endpoint,
                                     tcp_nodelay=True)
        self._command_pub = rospy.Publisher(f'{limb}/joint_command', msg.JointCommand, queue_size=1,
                                            tcp_nodelay=True)
        self._speed_pub = rospy.Publisher(f'{limb}/set_speed_ratio', Float64, queue_size=1, latch=True)
        self._timeout_pub = rospy.Publisher(f'{limb}/joint_command_timeout', Float64, queue_size=1, latch=True)
        self._joint_states.wait(timeout, what=f'no {side} arm joint state')
        self._endpoint.wait(timeout, what='no valid endpoint state')
        _wait_for_subscriber(self._command_pub, timeout)

    def _remember_endpoint(self, message):
        state = _endpoint_state(message)
        self._endpoint_history.append(state)
        return state

    # ------------------------------------------------------------------------------ readings
    def endpoint_pose_at(self, stamp):
        """T_base_gripper (4x4) at ROS time ``stamp`` (s): the recorded endpoint states around it, the
        translation interpolated linearly (a camera frame's pose while the arm moves). The latest pose if
        ``stamp`` is newer than the history, the oldest recorded one if older."""
        self.require_fresh()
        history = list(self._endpoint_history)
        stamps = np.array([state.stamp for state in history])
        k = int(np.searchsorted(stamps, stamp))
        if k <= 0 or k >= len(history):
            return history[min(max(k, 0), len(history) - 1)].T_base_gripper.copy()
        before, after = history[k - 1], history[k]
        s = (stamp - before.stamp) / max(after.stamp - before.stamp, 1e-9)
        T = (before if s < 0.5 else after).T_base_gripper.copy()
        T[:3, 3] = (1 - s) * before.T_base_gripper[:3, 3] + s * after.T_base_gripper[:3, 3]
        return T

    def require_fresh(self, max_age=None):
        """StreamLost unless joint states and the endpoint state are at most ``max_age`` s old."""
        for stream in (self._joint_states, self._endpoint):
            stream.require_fresh(self.max_age if max_age is None else max_age)

    def joint_positions(self):
        """(7,) current joint angles (rad), s0..w2."""
        return self._joint_states.require_fresh(self.max_age).positions.copy()

    def joint_angles(self):
        """{joint name: angle (rad)} (as baxter_interface)."""
        return dict(zip(self.joint_names, self.joint_positions()))

    def joint_velocities(self):
        """(7,) joint velocities (rad/s), or None if the robot does not publish them."""
        velocities = self._joint_states.require_fresh(self.max_age).velocities
        return None if velocities is None else velocities.copy()

    def endpoint_pose(self):
        """T_base_gripper (4x4, m): the pose of ``<side>_gripper`` in base reported by the robot."""
        return self._endpoint.require_fresh(self.max_age).T_base_gripper.copy()

    def endpoint_twist(self):
        """(6,) [v (m/s); w (rad/s)] of the endpoint in base (zeros on robots that do not fill it)."""
        return self._endpoint.require_fresh(self.max_age).twist.copy()

    def _vector(self, values, fill):
        """(7,) array from a {joint: value} dict (missing joints from ``fill``) or a 7-sequence."""
        if isinstance(values, dict):
            unknown = sorted(set(values) - set(self.joint_names))
            if unknown:
                raise ValueError(f'unknown joint name(s) for the {self.side} arm: {unknown}')
            return np.array([values.get(name, fill[k]) for k, name in enumerate(self.joint_names)], dtype=float)
        return np.asarray(values, dtype=float)

    # ------------------------------------------------------------------------------ IK
    def solve_ik(self, T_base_gripper, seed=None, timeout=5.0):
        """{joint: angle (rad)} placing ``<side>_gripper`` at ``T_base_gripper`` (4x4, base): the robot's IK service.

        ``seed``: joint angles (dict or 7 values) to start from (SEED_USER); default: the service's
        automatic seeding. Raises IKFailure when there is no solution, ServiceUnavailable when the
        service is not advertised within ``timeout`` s.
        """
        T_base_gripper = np.asarray(T_base_gripper, dtype=float)
        if T_base_gripper.shape != (4, 4) or not np.all(np.isfinite(T_base_gripper)):
            raise ValueError(f'IK target must be a finite 4x4 transform, got {T_base_gripper!r}')
        _wait_for_service(self.ik_service_name, timeout)
        request = srv.SolvePositionIKRequest()
        pose = PoseStamped()
        pose.header.frame_id = 'base'
        pose.header.stamp = rospy.Time.now()
        matrix_to_pose_msg(T_base_gripper, pose.pose)
        request.pose_stamp = [pose]
        if seed is None:
            request.seed_mode = request.SEED_AUTO
        else:
            q_seed = self._vector(seed, self.joint_positions())
            request.seed_angles = [JointState(name=list(self.joint_names), position=[float(a) for a in q_seed])]
            request.seed_mode = request.SEED_USER
        xyz, quat = to_xyz_quat(T_base_gripper)
        target = f'position {np.round(xyz, 4).tolist()} m, quaternion {np.round(quat, 4).tolist()}'
        try:
            response = self._ik(request)
        except rospy.ServiceException as error:
            if 'connect' in str(error) or 'transport' in str(error):     # the server went away mid-call
                raise ServiceUnavailable(f'{self.ik_service_name} is unreachable: {error}') from None
            raise IKFailure(f'{self.ik_service_name} call failed for {target}: {error}') from None
        result_types = list(bytearray(response.result_type)) if isinstance(response.result_type, (bytes, str)) \
            else list(response.result_type)
        valid = bool(response.isValid and response.isValid[0] and result_types
                     and result_types[0] != srv.SolvePositionIKResponse.RESULT_INVALID)
        if not valid:
            raise IKFailure(f'no joint solution for the {self.side} gripper at {target} (IK service result_type '
                            f'{result_types[:1]}, isValid {list(response.isValid[:1])})')
        solution = dict(zip(response.joints[0].name, response.joints[0].position))
        missing = [name for name in self.joint_names if name not in solution]
        if missing or not np.all(np.isfinite([solution[name] for name in self.joint_names if name in solution])):
            raise IKFailure(f'{self.ik_service_name} returned an unusable solution for {target}: {solution}')
        return {name: float(solution[name]) for name in self.joint_names}

    # ------------------------------------------------------------------------------ commands
    def _publish(self, mode, q):
        self._command_pub.publish(msg.JointCommand(mode=mode, command=[float(a) for a in q],
                                                   names=list(self.joint_names)))

    def _ramp_duration(self, q_start, q_target):
        """Seconds (robot time) for the slowest joint to cover its change at the speed ratio x its velocity limit."""
        velocity_limits = self.safety.limits.velocity_limits
        if velocity_limits is None:
            return 0.0
        return float(np.max(np.abs(q_target - q_start) / (self._speed_ratio * velocity_limits)))

    def move_to_joint_positions(self, positions, timeout=15.0, tolerance=JOINT_ANGLE_TOLERANCE, check=None):
        """Move to ``positions`` (dict joint -> rad, missing joints stay, or 7 values); True once arrived.

        The straight joint-space segment from the current angles: ``follow_joint_path`` with one waypoint.
        """
        return self.follow_joint_path([positions], timeout, tolerance, check)

    def follow_joint_path(self, waypoints, timeout=15.0, tolerance=JOINT_ANGLE_TOLERANCE, check=None):
        """Move through ``waypoints`` (each a dict joint -> rad or 7 values) without stopping; True once at the last.

        Every segment (from the current angles to the first waypoint, then waypoint to waypoint) first
        passes ``safety.check_joint_target`` (UnsafeCommand, nothing sent). Then POSITION_MODE commands
        are streamed at 100 Hz along the piecewise-linear joint-space path, each segment timed so that no
        joint exceeds the speed ratio x its velocity limit, until every joint is within ``tolerance`` rad
        of the last waypoint (True) or ``timeout`` wall seconds passed (False, warning). StreamLost if the
        joint states stop meanwhile. ``check()``, if given, is called at every command and may raise to
        abandon the move (e.g. the robot was stopped).
        """
        path = [self.joint_positions()]
        for waypoint in waypoints:
            path.append(self._vector(waypoint, path[-1]))
        for q_from, q_to in zip(path, path[1:]):
            self.safety.check_joint_target(q_to, q_from)
        ends = np.cumsum([0.0] + [self._ramp_duration(a, b) for a, b in zip(path, path[1:])])
        q_target = path[-1]
        change = np.abs(q_target - path[0])
        rospy.loginfo(f'{self.side} arm: move to joint positions {np.round(q_target, 4).tolist()} rad '
                      f'({len(waypoints)} segment(s), largest change {change.max():.3f} rad on '
                      f'{self.joint_names[int(np.argmax(change))]}, ramp {ends[-1]:.2f} s at speed ratio '
                      f'{self._speed_ratio:.2f}, timeout {timeout:.1f} s)')
        ros_start, deadline = rospy.get_time(), time.monotonic() + timeout
        while True:
            q = self._joint_states.require_fresh(self.max_age).positions
            elapsed = rospy.get_time() - ros_start
            if elapsed >= ends[-1] and np.all(np.abs(q_target - q) < tolerance):
                rospy.loginfo(f'{self.side} arm: arrived (largest error {np.abs(q_target - q).max():.4f} rad)')
                return True
            if time.monotonic() > deadline:
                rospy.logwarn(f'{self.side} arm: did not arrive within {timeout:.1f} s (largest error '
                              f'{np.abs(q_target - q).max():.4f} rad, tolerance {tolerance:.4f} rad)')
                return False
            if rospy.is_shutdown():
                raise RobotError('ROS is shutting down')
            if check is not None:
                check()
            self._publish(msg.JointCommand.POSITION_MODE, _point_on_path(path, ends, elapsed))
            time.sleep(1.0 / COMMAND_RATE_HZ)

    def set_joint_velocities(self, velocities, horizon=COMMAND_TIMEOUT):
        """Command joint velocities (dict joint -> rad/s, missing joints 0, or 7 values) in VELOCITY_MODE.

        ``safety.check_velocity`` checks them over ``horizon`` s (the robot applies a velocity command
        until the command timeout, 0.2 s by default); UnsafeCommand means nothing was sent. The robot
        holds its position when commands stop coming for the command timeout: re-send faster than that.
        """
        q = self.joint_positions()
        qdot = self._vector(velocities, np.zeros(7))
        self.safety.check_velocity(qdot, horizon, q)
        rospy.loginfo(f'{self.side} arm: joint velocities {np.round(qdot, 4).tolist()} rad/s')
        self._publish(msg.JointCommand.VELOCITY_MODE, qdot)

    def set_speed_ratio(self, ratio):
        """Position-mode speed as a fraction (0, 1] of the joints' maximum speed (the robot's default is 0.3)."""
        if not 0.0 < ratio <= 1.0:
            raise ValueError(f'speed ratio must be in (0, 1], got {ratio}')
        rospy.loginfo(f'{self.side} arm: speed ratio {ratio:.2f}')
        self._speed_ratio = float(ratio)
        self._speed_pub.publish(Float64(self._speed_ratio))

    def exit_control_mode(self):
        """Leave velocity mode: restore the 0.2 s command timeout and hold the current angles (always allowed)."""
        q = self.joint_positions()
        rospy.loginfo(f'{self.side} arm: exit control mode, hold {np.round(q, 4).tolist()} rad')
        self._timeout_pub.publish(Float64(COMMAND_TIMEOUT))
        self._publish(msg.JointCommand.POSITION_MODE, q)


def _point_on_path(path, ends, t):
    """Angles at time ``t`` (s) on a piecewise-linear joint path: ``path`` (k+1 configurations), ``ends``
    (k+1 cumulative segment end times, ends[0] = 0)."""
    if t >= ends[-1]:
        return path[-1]
    k = int(np.searchsorted(ends, t, side='right')) - 1
    k = min(max(k, 0), len(path) - 2)
    span = ends[k + 1] - ends[k]
    s = 1.0 if span <= 0 else (t - ends[k]) / span
    return path[k] + s * (path[k + 1] - path[k])


# ==================================================================================== gripper
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
        namespace = f'/robot/end_effector/{side}_gripper'
        self._state = CachedTopic(f'{namespace}/state', msg.EndEffectorState)
        self._properties = CachedTopic(f'{namespace}/properties', msg.EndEffectorProperties)
        self._command_pub = rospy.Publisher(f'{namespace}/command', msg.EndEffectorCommand, queue_size=10)
        self._sequence = 0
        self.parameters = dict(GRIPPER_PARAMETERS)
        self._state.wait(timeout, what='no gripper state')
        properties = self._properties.wait(timeout, accept=lambda p: p.ui_type in GRIPPER_TYPES,
                                           what='no gripper properties with a known ui_type')
        if GRIPPER_TYPES[properties.ui_type] != 'electric':
            raise RobotError(f'the {side} end effector is a {GRIPPER_TYPES[properties.ui_type]} gripper '
                             f'({properties.product!r}); only the electric gripper is supported')
        _wait_for_subscriber(self._command_pub, timeout)
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

    def gripping(self):
        return self.state().gripping == 1

    def missed(self):
        return self.state().missed == 1

    def moving(self):
        return self.state().moving == 1

    def calibrated(self):
        return self.state().calibrated == 1

    def ready(self):
        return self.state().ready == 1

    def error(self):
        return self.state().error == 1

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
        if not _wait_until(acknowledged, timeout, body=lambda: self._command_pub.publish(message)):
            rospy.logdebug(f'{self.side} gripper: no acknowledgement of {command} within {timeout} s')
        remaining = max(0.5, timeout - (time.monotonic() - started))
        return _wait_until(test or (lambda: True), remaining, body=lambda: self._command_pub.publish(message),
                           robot_time=True)

    def configure(self, **parameters):
        """Send the gripper parameters (percent): the defaults updated with ``parameters`` (non-blocking)."""
        unknown = sorted(set(parameters) - set(GRIPPER_PARAMETERS))
        if unknown:
            raise ValueError(f'unknown gripper parameter(s) {unknown} (known: {list(GRIPPER_PARAMETERS)})')
        self.parameters = dict(GRIPPER_PARAMETERS, **{k: float(v) for k, v in parameters.items()})
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


# ==================================================================================== camera
class Frame(NamedTuple):
    """One camera frame: uint8 BGR (H, W, 3) image, its CameraModel, and its header stamp (ROS time, s)."""
    image_bgr: np.ndarray
    camera: CameraModel
    stamp: float


class HandCamera:
    """The hand camera of one arm: opened through ``/cameras/open`` when ``/cameras/list`` exists.

    Without ``/cameras/list`` (e.g. the Gazebo simulator) the camera is assumed to stream already.
    Frames in bgra8, bgr8, rgb8 or mono8 are converted to BGR and paired with the last
    ``camera_info``; a frame with another encoding, without a camera_info, or whose size does not
    match is logged as an error and dropped (frames in the first ``CAMERA_INFO_GRACE`` s after subscribing,
    while the camera_info subscription connects, are dropped silently).
    """

    def __init__(self, side, resolution=(640, 400), fps=20, timeout=5.0, service_timeout=2.0):
        self.name = f'{side}_hand_camera'
        self.resolution = tuple(resolution)
        if self.resolution not in CAMERA_MODES:
            raise ValueError(f'resolution {resolution} is not a camera mode (one of {CAMERA_MODES})')
        self.image_topic = f'/cameras/{self.name}/image'
        self.info_topic = f'/cameras/{self.name}/camera_info'
        self.timeout = timeout
        self.fps = fps
        self.service_timeout = service_timeout
        self.opened = self._open(fps, service_timeout)
        self._subscribed_at = time.monotonic()
        self._info = CachedTopic(self.info_topic, CameraInfo, CameraModel.from_camera_info)
        self._frames = CachedTopic(self.image_topic, Image, self._frame, buff_size=1 << 24)

    def _open(self, fps, service_timeout):
        """Open the camera through /cameras/open if the robot has /cameras/list; True if opened."""
        try:
            rospy.wait_for_service('/cameras/list', timeout=service_timeout)
        except rospy.ROSException:
            rospy.loginfo(f'{self.name}: no /cameras/list service: assuming the camera streams already')
            return False
        available = rospy.ServiceProxy('/cameras/list', srv.ListCameras)().cameras
        if self.name not in available:
            raise RobotError(f'camera {self.name} is not available (powered cameras: {list(available)}); '
                             f'close another camera first')
        _wait_for_service('/cameras/open', service_timeout)
        width, height = self.resolution
        settings = msg.CameraSettings(width=width, height=height, fps=float(fps))
        err = rospy.ServiceProxy('/cameras/open', srv.OpenCamera)(self.name, settings).err
        if err != 0:
            raise RobotError(f'/cameras/open {self.name} {width}x{height}@{fps} failed: '
                             f'{errno.errorcode.get(err, err)}')
        rospy.loginfo(f'{self.name}: opened at {width}x{height}, {fps} fps')
        return True

    def reopen(self):
        """Open the camera again with the same settings (after the robot restarted, say)."""
        self.opened = self._open(self.fps, self.service_timeout)

    def close(self):
        """Stop receiving frames and close the camera if this object opened it (err 0 or EINVAL accepted).

        A robot that no longer serves ``/cameras/close`` only earns a warning.
        """
        self._frames.unregister()
        self._info.unregister()
        if not self.opened:
            return
        self.opened = False
        try:
            err = rospy.ServiceProxy('/cameras/close', srv.CloseCamera)(self.name).err
        except rospy.ServiceException as error:     # the robot is gone: nothing left to close
            rospy.logwarn(f'{self.name}: not closed: {error}')
            return
        if err not in (0, errno.EINVAL):
            raise RobotError(f'/cameras/close {self.name} failed: {errno.errorcode.get(err, err)}')

    def _frame(self, message):
        camera = self._info.value
        if camera is None:
            if time.monotonic() - self._subscribed_at < CAMERA_INFO_GRACE:     # both topics are just connecting
                rospy.logdebug(f'{self.name}: frame before the first camera_info: dropped')
                return None
            raise ValueError(f'no valid camera_info on {self.info_topic} yet: frame dropped')
        if (message.width, message.height) != (camera.width, camera.height):
            raise ValueError(f'frame is {message.width}x{message.height} but camera_info is '
                             f'{camera.width}x{camera.height}: frame dropped')
        if self.opened and (message.width, message.height) != self.resolution:
            raise ValueError(f'frame is {message.width}x{message.height}, the camera was opened at '
                             f'{self.resolution[0]}x{self.resolution[1]}: frame dropped')
        return Frame(msg_to_bgr(message), camera, message.header.stamp.to_sec())

    def latest(self):
        """The last valid Frame (image_bgr, camera, stamp), or None if none arrived yet."""
        return self._frames.value

    def require_fresh(self, max_age=DEFAULT_MAX_AGE):
        """The last Frame if at most ``max_age`` s old (wall clock); StreamLost otherwise."""
        return self._frames.require_fresh(max_age)

    def wait_for_frame(self, after_stamp=None, timeout=None):
        """The first valid Frame stamped later than ``after_stamp`` (ROS time, s; None: any); RobotTimeout otherwise."""
        return self._frames.wait(self.timeout if timeout is None else timeout,
                                 accept=lambda frame: after_stamp is None or frame.stamp > after_stamp,
                                 what='no new valid frame' if after_stamp is not None else 'no valid frame')


# ==================================================================================== hand-eye
class HandEye(NamedTuple):
    """The hand camera's mount: T_hand_camera, T_gripper_camera (4x4, m) and their source ('tf' or 'urdf')."""
    T_hand_camera: np.ndarray
    T_gripper_camera: np.ndarray
    source: str


def _tf_matrix(transform_stamped):
    t, q = transform_stamped.transform.translation, transform_stamped.transform.rotation
    return from_xyz_quat((t.x, t.y, t.z), (q.x, q.y, q.z, q.w))


def hand_eye_transform(side, timeout=2.0, urdf_path=None):
    """The ``<side>_hand_camera`` pose in ``<side>_hand`` and in ``<side>_gripper``, from tf.

    Falls back (with a warning) to the URDF (``ArmKinematics``, ``urdf_path`` or urdf/baxter.urdf)
    when tf does not provide both transforms within ``timeout`` wall seconds.
    """
    import tf2_ros
    hand, gripper, camera = f'{side}_hand', f'{side}_gripper', f'{side}_hand_camera'
    buffer = tf2_ros.Buffer()
    listener = tf2_ros.TransformListener(buffer)
    try:
        latest = rospy.Time(0)
        if _wait_until(lambda: buffer.can_transform(hand, camera, latest) and
                       buffer.can_transform(gripper, camera, latest), timeout, rate_hz=50.0):
            return HandEye(_tf_matrix(buffer.lookup_transform(hand, camera, latest)),
                           _tf_matrix(buffer.lookup_transform(gripper, camera, latest)), 'tf')
    finally:
        listener.unregister()
    rospy.logwarn(f'tf has no {hand} -> {camera} and {gripper} -> {camera} after {timeout} s: '
                  f'using the URDF instead')
    from baxter_pnp.kinematics import ArmKinematics
    kinematics = ArmKinematics(side, urdf_path)
    try:
        q = np.clip(np.zeros(7), kinematics.lower, kinematics.upper)
        T_base_camera = kinematics.fk(q, camera)
        return HandEye(invert(kinematics.fk(q, hand)) @ T_base_camera,
                       invert(kinematics.fk(q, gripper)) @ T_base_camera, 'urdf')
    finally:
        kinematics.close()
