"""``Limb``: one arm through the SDK's topics and IK service (interfaces §3-6), and the parsing of its streams.

Frames and units: poses in ``base`` (``T_base_gripper`` = the ``<side>_gripper`` pose in ``base``, 4x4,
metres), joint angles in radians (s0..w2 order), joint velocities in rad/s. Every arm command first
passes the arm's ``baxter_pnp.safety.ArmSafety`` and is logged. Timeouts and stream ages are
wall-clock seconds; the joint-space ramp of ``follow_joint_path`` follows ROS time (the robot's clock).
"""
import collections
import time
from typing import NamedTuple

import numpy as np
import rospy
from geometry_msgs.msg import PoseStamped
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64

from baxter_pnp.kinematics import arm_joint_names
from baxter_pnp.msgs import msg, srv
from baxter_pnp.robot import sdk
from baxter_pnp.robot.errors import IKFailure, RobotError, ServiceUnavailable
from baxter_pnp.robot.topics import DEFAULT_MAX_AGE, CachedTopic, wait_for_service, wait_for_subscriber
from baxter_pnp.transforms import from_xyz_quat, matrix_to_pose_msg, to_xyz_quat

ENDPOINT_HISTORY = 200                # endpoint states kept for endpoint_pose_at (2 s at 100 Hz)


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
        self._speed_ratio = sdk.DEFAULT_SPEED_RATIO
        self.ik_service_name = sdk.ik_service(side)
        self._ik = rospy.ServiceProxy(self.ik_service_name, srv.SolvePositionIK)
        self._joint_states = CachedTopic(sdk.JOINT_STATES_TOPIC, JointState,
                                         lambda message: _arm_joint_state(self.joint_names, message))
        self._endpoint_history = collections.deque(maxlen=ENDPOINT_HISTORY)
        topics = sdk.limb_topics(side)
        self._endpoint = CachedTopic(topics.endpoint_state, msg.EndpointState, self._remember_endpoint,
                                     tcp_nodelay=True)
        self._command_pub = rospy.Publisher(topics.joint_command, msg.JointCommand, queue_size=1, tcp_nodelay=True)
        self._speed_pub = rospy.Publisher(topics.speed_ratio, Float64, queue_size=1, latch=True)
        self._timeout_pub = rospy.Publisher(topics.command_timeout, Float64, queue_size=1, latch=True)
        self._joint_states.wait(timeout, what=f'no {side} arm joint state')
        self._endpoint.wait(timeout, what='no valid endpoint state')
        wait_for_subscriber(self._command_pub, timeout)

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

    def endpoint_pose(self):
        """T_base_gripper (4x4, m): the pose of ``<side>_gripper`` in base reported by the robot."""
        return self._endpoint.require_fresh(self.max_age).T_base_gripper.copy()

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
        wait_for_service(self.ik_service_name, timeout)
        request = srv.SolvePositionIKRequest()
        pose = PoseStamped()
        pose.header.frame_id = sdk.BASE_FRAME
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

    def move_to_joint_positions(self, positions, timeout=15.0, tolerance=sdk.JOINT_ANGLE_TOLERANCE, check=None):
        """Move to ``positions`` (dict joint -> rad, missing joints stay, or 7 values); True once arrived.

        The straight joint-space segment from the current angles: ``follow_joint_path`` with one waypoint.
        """
        return self.follow_joint_path([positions], timeout, tolerance, check)

    def follow_joint_path(self, waypoints, timeout=15.0, tolerance=sdk.JOINT_ANGLE_TOLERANCE, check=None):
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
            time.sleep(1.0 / sdk.COMMAND_RATE_HZ)

    def set_joint_velocities(self, velocities, horizon=sdk.COMMAND_TIMEOUT):
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
        self._timeout_pub.publish(Float64(sdk.COMMAND_TIMEOUT))
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
