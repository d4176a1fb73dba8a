"""What the fake Baxter's tests use to watch and drive it through ROS (tests/test_fake_baxter*.py, test_faults.py).

``Recorder`` keeps a topic's messages, ``publisher`` waits until the fake subscribes, ``sim_sleep`` waits in
simulated time, ``edge`` brackets when a published state changed, ``Robot`` bundles the main topics of one fake
Baxter, ``GripperAckClock`` reads the fake's own clock through the gripper protocol. Times are the fake's seconds
(simulated, or wall seconds under ``--clock wall``: header stamps, or this process's ``rospy.get_time()``) unless a
name says ``wall``; wall timeouts only bound waits.
"""
import collections
import threading
import time

import numpy as np
import pytest
import rospy
from geometry_msgs.msg import PoseArray, PoseStamped
from sensor_msgs.msg import JointState
from std_msgs.msg import Bool, Empty, Float64

from baxter_pnp.kinematics import ArmKinematics
from baxter_pnp.msgs import msg, srv
from baxter_pnp.sim.scene import load_scene
from baxter_pnp.transforms import make_transform, matrix_to_pose_msg, pose_msg_to_matrix

LEFT = ['left_s0', 'left_s1', 'left_e0', 'left_e1', 'left_w0', 'left_w1', 'left_w2']
GRIPPER = '/robot/end_effector/left_gripper'
IK_SERVICE = '/ExternalTools/left/PositionKinematicsNode/IKService'
STEP = 1 / 240.0           # s, the fake's physics step: its clock advances by these


# ============================================================================ topics
class Recorder:
    """Keeps the last ``keep`` messages of a topic with their (wall, monotonic) time of arrival."""

    def __init__(self, topic, msg_type, keep=3000):
        self._messages = collections.deque(maxlen=keep)
        self._lock = threading.Lock()
        self._subscriber = rospy.Subscriber(topic, msg_type, self._callback, queue_size=keep, tcp_nodelay=True)

    def _callback(self, message):
        with self._lock:
            self._messages.append((time.monotonic(), message))

    @property
    def messages(self):
        """[(wall arrival time, message)] held, oldest first (a copy)."""
        with self._lock:
            return list(self._messages)

    def clear(self):
        with self._lock:
            self._messages.clear()

    def latest(self, timeout=5.0):
        return self.wait_for(lambda m: True, timeout)

    def wait_for(self, predicate, timeout=10.0, oldest=False):
        """The newest (or ``oldest``) held message satisfying ``predicate``; fails after ``timeout`` wall s."""
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            held = [message for _, message in self.messages]
            for message in (held if oldest else reversed(held)):
                if predicate(message):
                    return message
            time.sleep(0.005)
        raise AssertionError(f'no matching message on {self._subscriber.name} within {timeout} s')

    def close(self):
        self._subscriber.unregister()


def sim_sleep(seconds, wall_timeout=30.0):
    """Wait until the simulated clock has advanced ``seconds``."""
    end = rospy.get_time() + seconds
    deadline = time.monotonic() + wall_timeout
    while rospy.get_time() < end:
        assert time.monotonic() < deadline, 'simulated time does not advance'
        time.sleep(0.002)


def publisher(topic, msg_type, **kwargs):
    """A publisher that is already connected to the fake Baxter's subscriber."""
    pub = rospy.Publisher(topic, msg_type, queue_size=10, **kwargs)
    deadline = time.monotonic() + 5.0
    while pub.get_num_connections() == 0:
        assert time.monotonic() < deadline, f'nobody subscribes to {topic}'
        time.sleep(0.01)
    return pub


def publish_until(pub, message, condition, timeout):
    """baxter_interface's wait_for: publish at ~100 Hz until ``condition()``; returns the simulated seconds taken."""
    start = rospy.get_time()
    deadline = time.monotonic() + timeout
    while not condition():
        assert time.monotonic() < deadline, f'condition not met within {timeout} s'
        pub.publish(message)
        time.sleep(0.01)
    return rospy.get_time() - start


def rate_hz(stamps):
    """Publication rate (Hz) of messages received with these simulated time stamps (s): publications per second,
    a gap of about k typical intervals counted as k publications (k - 1 of them not received: a loaded machine
    with a fake several times faster than real time drops some), so that drops do not bias it. Typical: the mean
    of the intervals up to 1.6 medians (stamps fall on physics steps: at 100 Hz on 240 Hz steps the intervals
    alternate 8.3 and 12.5 ms)."""
    stamps = np.unique(np.asarray(stamps, dtype=float))
    gaps = np.diff(stamps)
    typical = gaps[gaps <= 1.6 * np.median(gaps)].mean()
    return float(np.maximum(np.round(gaps / typical), 1.0).sum() / (stamps[-1] - stamps[0]))


def published_rate_hz(messages):
    """Publication rate (Hz, simulated time) of stamped messages: header.seq counts every publication,
    so messages this process may have dropped do not bias it."""
    first, last = messages[0].header, messages[-1].header
    return (last.seq - first.seq) / (last.stamp - first.stamp).to_sec()


def edge(messages, predicate, after=float('-inf')):
    """(before, at): the stamp (s) of the first of ``messages`` (stamped, in arrival order) stamped after ``after``
    that satisfies ``predicate``, and the stamp of the message received just before it. A change of what the
    fake publishes, made at a step of simulated time t, shows in the messages stamped after t: before <= t < at.
    Messages the fake dropped (its publishers queue 10 when this process is slow) only widen that bracket."""
    previous = None
    for message in messages:
        stamp = message.header.stamp.to_sec()
        if stamp > after and predicate(message):
            assert previous is not None, 'no message before the edge'
            return previous, stamp
        previous = stamp
    raise AssertionError('no message satisfies the predicate')


def joint_angles(message, names=LEFT):
    """(len(names),) joint angles (rad) of a JointState, in ``names`` order."""
    return np.array([message.position[message.name.index(n)] for n in names])


def joint_velocity(message, name):
    """Velocity (rad/s) of joint ``name`` in a JointState."""
    return message.velocity[message.name.index(name)]


def gripper_down(xyz, yaw):
    """T_base_gripper (4x4) at ``xyz`` (m, base) pointing straight down (gripper z = -base z), the fingers closing
    along base y turned by ``yaw`` (rad) about base z."""
    c, s = np.cos(yaw), np.sin(yaw)
    return make_transform(np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]]) @ np.diag([1.0, -1.0, -1.0]), xyz)


def pose_stamped(T_base_gripper, frame_id='base'):
    """PoseStamped of a 4x4 pose in ``frame_id``."""
    pose = PoseStamped()
    pose.header.frame_id = frame_id
    matrix_to_pose_msg(T_base_gripper, pose.pose)
    return pose


class GripperAckClock:
    """Reads the fake's simulated clock through the gripper protocol, whatever this process's ``/clock`` lags.

    ``send()`` publishes a ``no_op`` (acknowledged, nothing else); ``stamp(sequence)`` is the ``timestamp`` of
    the first gripper state acknowledging it (or a later no_op of this sender): the fake's time at or after the
    moment the command reached it, so an upper bound of the fake's time at any instant before ``send()``.
    """

    def __init__(self, sender='/pytest_clock'):
        self.sender = sender
        self.sequence = 0
        self.states = Recorder(f'{GRIPPER}/state', msg.EndEffectorState)
        self.commands = publisher(f'{GRIPPER}/command', msg.EndEffectorCommand, tcp_nodelay=True)
        self._id = self.states.latest().id

    def send(self):
        self.sequence += 1
        self.commands.publish(msg.EndEffectorCommand(id=self._id, command='no_op', sender=self.sender,
                                                     sequence=self.sequence))
        return self.sequence

    def stamp(self, sequence, timeout=10.0):
        state = self.states.wait_for(lambda s: s.command_sender == self.sender and s.command_sequence >= sequence,
                                     timeout, oldest=True)
        return state.timestamp.to_sec()

    def close(self):
        self.states.close()
        self.commands.unregister()


# ============================================================================ fixtures and the Robot view
@pytest.fixture(scope='module')
def kin():
    return ArmKinematics('left')


@pytest.fixture(scope='module')
def scene():
    return load_scene()


class Robot:
    """The main fake Baxter node seen through ROS: recorders and connected publishers."""

    def __init__(self, process):
        self.process = process
        self.joint_states = Recorder('/robot/joint_states', JointState)
        self.endpoint = Recorder('/robot/limb/left/endpoint_state', msg.EndpointState)
        self.state = Recorder('/robot/state', msg.AssemblyState)
        self.gripper_state = Recorder(f'{GRIPPER}/state', msg.EndEffectorState)
        self.objects = Recorder('/fake_baxter/object_poses', PoseArray, keep=100)
        self.joint_command = publisher('/robot/limb/left/joint_command', msg.JointCommand, tcp_nodelay=True)
        self.speed_ratio = publisher('/robot/limb/left/set_speed_ratio', Float64, latch=True)
        self.command_timeout = publisher('/robot/limb/left/joint_command_timeout', Float64, latch=True)
        self.gripper_command = publisher(f'{GRIPPER}/command', msg.EndEffectorCommand)
        self.enable = publisher('/robot/set_super_enable', Bool)
        self.reset = publisher('/robot/set_super_reset', Empty)
        self.stop = publisher('/robot/set_super_stop', Empty)
        self.ik = rospy.ServiceProxy(IK_SERVICE, srv.SolvePositionIK)
        self.gripper_sequence = 0
        for recorder in (self.joint_states, self.endpoint, self.state, self.gripper_state, self.objects):
            recorder.latest()

    def angles(self):
        return joint_angles(self.joint_states.latest())

    def block_pose(self, index=0):
        return pose_msg_to_matrix(self.objects.latest().poses[index])

    def command_positions(self, targets, mode=1):
        self.joint_command.publish(msg.JointCommand(mode=mode, names=list(targets),
                                                    command=[float(v) for v in targets.values()]))

    def move_to(self, targets, tolerance=0.01, timeout=60.0, mode=1):
        """Send one position command; return the joint_states received until every joint is within ``tolerance``."""
        self.joint_states.clear()
        self.command_positions(targets, mode)
        goal = np.array([targets[name] for name in LEFT])
        deadline = time.monotonic() + timeout
        while np.max(np.abs(self.angles() - goal)) >= tolerance:
            assert time.monotonic() < deadline, f'arm did not reach {targets}: at {self.angles()}'
            time.sleep(0.005)
        return [m for _, m in self.joint_states.messages]

    def solve_ik(self, T_base_gripper, seed_mode=0, seeds=()):
        request = srv.SolvePositionIKRequest(seed_mode=seed_mode, seed_angles=list(seeds))
        request.pose_stamp.append(pose_stamped(T_base_gripper))
        response = self.ik(request)
        assert response.isValid[0], f'no IK solution for\n{T_base_gripper}'
        return dict(zip(response.joints[0].name, response.joints[0].position))

    def gripper(self, command, args='', test=lambda s: True, timeout=5.0):
        """baxter_interface.Gripper.command(block=True): returns (simulated s until acknowledged, until done)."""
        self.gripper_sequence += 1
        sender = f'/pytest_{command}'
        message = msg.EndEffectorCommand(id=self.gripper_state.latest().id, command=command, args=args,
                                         sender=sender, sequence=self.gripper_sequence)
        start = rospy.get_time()
        self.gripper_command.publish(message)
        acknowledged = self.gripper_state.wait_for(
            lambda s: s.command_sender == sender and s.command_sequence == self.gripper_sequence, timeout)
        publish_until(self.gripper_command, message, lambda: test(self.gripper_state.latest()), timeout)
        return acknowledged.timestamp.to_sec() - start, rospy.get_time() - start

    def calibrate_gripper(self):
        """What the SDK examples do: calibrate only when not calibrated. Returns gripper() timings or None."""
        if self.gripper_state.latest().calibrated == 1:
            return None
        return self.gripper('calibrate', test=lambda s: s.calibrated == 1 and s.ready == 1)


@pytest.fixture(scope='module')
def robot(ros_node, fake_baxter):
    """One fake Baxter (``--enable``, real time) per test module, seen through ``Robot``."""
    process = fake_baxter('--enable')
    robot = Robot(process)
    yield robot
    assert process.process.poll() is None, 'the fake Baxter died during the tests:\n' + process.log()[-3000:]
