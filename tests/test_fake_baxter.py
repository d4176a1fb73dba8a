"""The fake Baxter node against a real rosmaster, through ROS only (topics, services, parameters).

One node (``--enable``, real time) serves most tests; a first one boots with a camera open, as fast as
the CPU allows, to measure the image rate and the real-time factor a camera costs. All times are
simulated seconds (header stamps, or this process's ``rospy.get_time()`` which follows ``/clock``)
unless a name says ``wall``; wall timeouts only bound the waiting. Ground truth comes from ``/fake_baxter/object_poses`` and the forward
kinematics of ``ArmKinematics`` on the published joint angles.
"""
import argparse
import collections
import errno
import math
import struct
import threading
import time

import cv2
import numpy as np
import pytest
import rospy
from geometry_msgs.msg import PoseArray, PoseStamped
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import CameraInfo, Image, JointState, Range
from std_msgs.msg import Bool, Empty, Float64
from tf2_msgs.msg import TFMessage

from baxter_pnp.camera import CameraModel, load_default_camera
from baxter_pnp.kinematics import ArmKinematics, load_start_poses
from baxter_pnp.models import model_for
from baxter_pnp.msgs import msg, srv
from baxter_pnp.ros_image import msg_to_bgr
from baxter_pnp.sim.clock import RateSchedule, RealTimePacer
from baxter_pnp.sim.cameras import camera_settings_problem, parse_camera_option
from baxter_pnp.sim.node import ik_stages, parse_joint_command
from baxter_pnp.sim.scene import load_scene
from baxter_pnp.transforms import (from_xyz_quat, invert, make_transform, matrix_to_pose_msg, pose_msg_to_matrix,
                                   rotation_angle_between)
from ros_graph import FakeBaxterProcess

pytestmark = pytest.mark.timeout(300)

LEFT = ['left_s0', 'left_s1', 'left_e0', 'left_e1', 'left_w0', 'left_w1', 'left_w2']
GRIPPER = '/robot/end_effector/left_gripper'
IK_SERVICE = '/ExternalTools/left/PositionKinematicsNode/IKService'
MODES = [(1280, 800), (960, 600), (640, 400), (480, 300), (384, 240), (320, 200)]


# ============================================================================ helpers
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
    """Rate (Hz) of messages received with these simulated time stamps (s)."""
    stamps = np.sort(np.asarray(stamps))
    return (len(stamps) - 1) / (stamps[-1] - stamps[0])


def published_rate_hz(messages):
    """Publication rate (Hz, simulated time) of stamped messages: header.seq counts every publication,
    so messages this process may have dropped do not bias it."""
    first, last = messages[0].header, messages[-1].header
    return (last.seq - first.seq) / (last.stamp - first.stamp).to_sec()


def green_mask(image_bgr):
    b, g, r = (image_bgr[..., k].astype(int) for k in range(3))
    return ((g > 90) & (g > r + 50) & (g > b + 50)).astype(np.uint8)


# ============================================================================ fixtures
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
        message = self.joint_states.latest()
        return np.array([message.position[message.name.index(name)] for name in LEFT])

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
        pose = PoseStamped()
        pose.header.frame_id = 'base'
        matrix_to_pose_msg(T_base_gripper, pose.pose)
        request.pose_stamp.append(pose)
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
    process = fake_baxter('--enable')
    robot = Robot(process)
    yield robot
    assert process.process.poll() is None, 'the fake Baxter died during the tests:\n' + process.log()[-3000:]


# ============================================================================ pure parts (no ROS graph)
def test_rate_schedule_keeps_the_average_rate_on_a_coarser_step_grid():
    schedule = RateSchedule(100.0)
    step = 1 / 240.0
    due = [k * step for k in range(2400) if schedule.due(k * step)]
    assert len(due) == 1000 and np.max(np.diff(due)) <= 0.01 + step
    paused = RateSchedule(20.0)
    assert paused.due(0.0) and paused.due(5.0) and not paused.due(5.01) and paused.due(5.05)


def test_real_time_pacer_sleeps_to_the_factor_and_does_not_rush_after_a_lag():
    wall = [0.0]
    sleeps = []

    def sleep(seconds):
        sleeps.append(seconds)
        wall[0] += seconds

    pacer = RealTimePacer(2.0, wall_clock=lambda: wall[0], sleep=sleep)
    pacer.pace(0.0)
    pacer.pace(1.0)                                   # 1 simulated s at factor 2 = 0.5 wall s
    assert sleeps == [pytest.approx(0.5)]
    wall[0] += 3.0                                    # the CPU stalled for 3 s
    pacer.pace(1.1)
    pacer.pace(1.2)                                   # paced from the stall on, no burst to catch up
    assert sleeps[-1] == pytest.approx(0.05) and len(sleeps) == 2
    flat_out = RealTimePacer(0.0, wall_clock=lambda: wall[0], sleep=sleep)
    flat_out.pace(0.0)
    flat_out.pace(5.0)
    assert len(sleeps) == 2                           # factor 0: never sleeps


def test_joint_command_validation_and_ik_stages():
    assert parse_joint_command(1, ['left_s0'], [0.2], LEFT) == {'left_s0': 0.2}
    for mode, names, values, message in [(9, ['left_s0'], [0.0], 'unknown mode'),
                                         (1, ['left_s0'], [float('nan')], 'non-finite'),
                                         (2, ['left_s0', 'left_s0'], [0.0, 0.0], 'repeated'),
                                         (1, ['right_s0'], [0.0], 'unknown joint'),
                                         (1, ['left_s0'], [0.0, 1.0], 'names but')]:
        with pytest.raises(ValueError, match=message):
            parse_joint_command(mode, names, values, LEFT)
    seed, current = np.ones(7), np.zeros(7)
    assert [t for t, _ in ik_stages(0, seed, current)] == [1, 2, 3]
    assert [t for t, _ in ik_stages(0, None, current)] == [2, 3]
    assert [t for t, _ in ik_stages(1, seed, current)] == [1]
    assert [t for t, _ in ik_stages(2, seed, current)] == [2]
    assert [t for t, _ in ik_stages(3, None, current)] == [3]
    with pytest.raises(ValueError, match='SEED_USER'):
        ik_stages(1, None, current)


def test_camera_settings_and_option():
    assert camera_settings_problem('left_hand_camera', 1280, 800, 30.0) is None
    assert camera_settings_problem('left_hand_camera', 800, 800, 30.0)[0] == errno.EINVAL
    assert camera_settings_problem('left_hand_camera', 640, 400, 0.0)[0] == errno.EINVAL
    assert camera_settings_problem('torso_camera', 640, 400, 20.0)[0] == errno.ENODEV
    assert parse_camera_option('head_camera:320x200') == ('head_camera', 320, 200, 20.0)
    assert parse_camera_option('left_hand_camera:640x400@12.5') == ('left_hand_camera', 640, 400, 12.5)
    for bad in ('left_hand_camera', 'left_hand_camera:640x480@20', 'left_hand_camera:640x400@0'):
        with pytest.raises(argparse.ArgumentTypeError):
            parse_camera_option(bad)


# ============================================================================ start-up
def test_bad_scene_is_a_clear_error_with_exit_code_2(tmp_path):
    bad = tmp_path / 'bad.yaml'
    bad.write_text('objects:\n  - {shape: square, side: -0.04, color: [0, 1, 0], xy: [0.7, 0.2]}\n')
    process = FakeBaxterProcess(['--scene', str(bad)], log_path=tmp_path / 'bad.log')
    assert process.run_to_exit() == 2
    assert 'objects[0].side' in process.log()


def test_camera_opened_at_boot_publishes_at_its_fps_and_costs_this_real_time_factor(ros_node, fake_baxter,
                                                                                     record_property):
    process = fake_baxter('--open-camera', 'left_hand_camera:640x400@20', '--real-time-factor', '0',
                          '--image-encoding', 'rgb8', '--start-pose', 'angled')
    joints = rospy.wait_for_message('/robot/joint_states', JointState, timeout=5.0)
    angled = load_start_poses()['angled']
    np.testing.assert_allclose([joints.position[joints.name.index(n)] for n in LEFT], [angled[n] for n in LEFT],
                               atol=0.01)
    images = Recorder('/cameras/left_hand_camera/image', Image, keep=200)
    infos = Recorder('/cameras/left_hand_camera/camera_info', CameraInfo, keep=200)
    clock = Recorder('/clock', Clock, keep=10)
    try:
        images.latest(timeout=10.0)
        start_wall, start_sim = time.monotonic(), clock.latest().clock.to_sec()
        time.sleep(4.0)
        real_time_factor = (clock.latest().clock.to_sec() - start_sim) / (time.monotonic() - start_wall)
        received = [m for _, m in images.messages]
        image = images.latest()
        info = infos.latest()
    finally:
        for recorder in (images, infos, clock):
            recorder.close()
        process.stop()
    record_property('real_time_factor_640x400_20fps', real_time_factor)
    print(f'\nreal-time factor with left_hand_camera 640x400 @ 20 fps: {real_time_factor:.2f}')
    assert published_rate_hz(received) == pytest.approx(20.0, rel=0.10)
    assert rate_hz([m.header.stamp.to_sec() for m in received]) == pytest.approx(20.0, rel=0.10)
    assert len(received) >= 10
    assert (image.width, image.height, image.encoding, image.header.frame_id) == (640, 400, 'rgb8', 'left_hand_camera')
    assert msg_to_bgr(image).shape == (400, 640, 3)
    published = CameraModel.from_camera_info(info)
    expected = load_default_camera().scaled(640, 400)
    np.testing.assert_allclose(published.K, expected.K)
    np.testing.assert_allclose(published.D, expected.D)


def test_boot_is_fast_and_announced(robot):
    assert robot.process.boot_seconds < 5.0
    assert 'fake_baxter ready' in robot.process.log()
    assert rospy.get_param('/rethink/software_version') == '1.2.0'
    assert rospy.get_param('/use_sim_time') is True
    assert '<robot' in rospy.get_param('/robot_description')


# ============================================================================ state topics
def test_state_topics_rates_and_content(robot, kin):
    for recorder in (robot.joint_states, robot.endpoint, robot.state, robot.gripper_state):
        recorder.clear()
    sim_sleep(2.0)
    joint_states = robot.joint_states.messages
    rates = [published_rate_hz([m for _, m in joint_states]),
             published_rate_hz([m for _, m in robot.endpoint.messages]),
             rate_hz([m.timestamp.to_sec() for _, m in robot.gripper_state.messages])]
    # AssemblyState has no stamp: count the ones that arrived between two joint_states messages.
    (first_arrival, first), (last_arrival, last) = joint_states[0], joint_states[-1]
    states = [t for t, _ in robot.state.messages if first_arrival <= t <= last_arrival]
    rates.append(len(states) / (last.header.stamp - first.header.stamp).to_sec())
    assert rates == pytest.approx([100.0] * 4, rel=0.10)

    joints = robot.joint_states.latest()
    assert len(joints.name) == len(joints.position) == len(joints.velocity) == len(joints.effort) == 19
    assert set(LEFT) <= set(joints.name) and 'right_w2' in joints.name and 'l_gripper_l_finger_joint' in joints.name
    endpoint = robot.endpoint.wait_for(lambda m: m.header.stamp >= joints.header.stamp)
    assert endpoint.header.frame_id == 'base'
    T_fk = kin.fk(robot.angles())
    T_endpoint = pose_msg_to_matrix(endpoint.pose)
    assert np.linalg.norm(T_endpoint[:3, 3] - T_fk[:3, 3]) < 1e-3
    assert rotation_angle_between(T_endpoint, T_fk) < math.radians(0.1)
    assert abs(endpoint.twist.linear.z) < 1e-2          # holding still

    state = robot.state.latest()
    assert state.ready and state.enabled and not state.stopped


def test_tf_chain_matches_forward_kinematics(robot, kin):
    static = rospy.wait_for_message('/tf_static', TFMessage, timeout=5.0)
    dynamic = rospy.wait_for_message('/tf', TFMessage, timeout=5.0)
    edges = {t.child_frame_id: (t.header.frame_id, t.transform) for t in static.transforms + dynamic.transforms}
    camera_parent, camera_mount = edges['left_hand_camera']
    assert camera_parent == 'left_hand'
    np.testing.assert_allclose([camera_mount.translation.x, camera_mount.translation.y, camera_mount.translation.z],
                               [0.03825, 0.012, 0.015355], atol=1e-6)
    for frame in ('left_hand_range', 'left_gripper', 'l_gripper_l_finger', 'right_hand', 'head'):
        assert frame in edges

    def T_base(frame):
        T = np.eye(4)
        while frame != 'base':
            frame, t = edges[frame]
            T = from_xyz_quat([t.translation.x, t.translation.y, t.translation.z],
                              [t.rotation.x, t.rotation.y, t.rotation.z, t.rotation.w]) @ T
        return T

    angles_at_tf_time = robot.angles()   # the arm is holding still
    for frame in ('left_gripper', 'left_hand_camera'):
        T_fk = kin.fk(angles_at_tf_time, frame)
        assert np.linalg.norm(T_base(frame)[:3, 3] - T_fk[:3, 3]) < 1e-3


def test_range_sensor_sees_the_table_where_geometry_says(robot, kin, scene):
    message = rospy.wait_for_message('/robot/range/left_hand_range/state', Range, timeout=5.0)
    assert (message.min_range, message.max_range) == pytest.approx((0.004, 0.4))
    assert message.header.frame_id == 'left_hand_range'
    T_base_range = kin.fk(robot.angles(), 'left_hand_range')
    origin, direction = T_base_range[:3, 3], T_base_range[:3, 0]
    to_table = (scene.table.top_z - origin[2]) / direction[2] if direction[2] < 0 else math.inf
    if to_table > 0.4:
        assert message.range == math.inf
    else:
        assert message.range == pytest.approx(to_table, abs=0.005)


def test_object_poses_are_the_scene_ground_truth(robot, scene):
    message = robot.objects.latest()
    assert message.header.frame_id == 'base' and len(message.poses) == len(scene.objects)
    T = robot.block_pose(0)
    obj = scene.objects[0]
    np.testing.assert_allclose(T[:3, 3], [*obj.xy, scene.table.top_z + obj.height], atol=2e-3)
    yaw = math.atan2(T[1, 0], T[0, 0])
    symmetry = 2 * math.pi / 4
    assert abs((yaw - obj.yaw + symmetry / 2) % symmetry - symmetry / 2) < math.radians(1.0)


# ============================================================================ enable / disable / stop / reset
def test_enable_disable_stop_reset(robot):
    latest = robot.state.latest
    assert publish_until(robot.enable, Bool(False), lambda: not latest().enabled, 5.0) < 2.0
    q_before = robot.angles()
    target = dict(zip(LEFT, q_before))
    target['left_s0'] += 0.2
    robot.command_positions(target)                       # ignored while disabled
    sim_sleep(0.5)
    assert np.max(np.abs(robot.angles() - q_before)) < 0.005
    assert 'not enabled' in robot.process.log()

    assert publish_until(robot.stop, Empty(), lambda: latest().stopped, 3.0) < 2.0
    assert not latest().enabled
    robot.enable.publish(Bool(True))                      # refused while stopped
    sim_sleep(0.3)
    assert latest().stopped and not latest().enabled

    def is_reset():
        s = latest()
        return not (s.enabled or s.stopped or s.error or s.estop_button or s.estop_source)
    assert publish_until(robot.reset, Empty(), is_reset, 3.0) < 2.0
    assert publish_until(robot.enable, Bool(True), lambda: latest().enabled, 2.0) < 2.0
    assert latest().ready


# ============================================================================ arm commands
def test_position_moves_arrive_and_respect_the_speed_ratio(robot, kin):
    limits = kin.velocity_limits
    start = robot.angles()
    for ratio, delta, mode in ((0.3, 0.6, 1), (1.0, -0.6, 4)):     # POSITION_MODE, then RAW_POSITION_MODE
        robot.speed_ratio.publish(Float64(ratio))
        sim_sleep(0.05)
        target = dict(zip(LEFT, robot.angles()))
        target['left_s0'] += delta
        target['left_w1'] += delta / 2
        robot.endpoint.clear()
        states = robot.move_to(target, mode=mode)
        sim_sleep(0.3)
        assert np.max(np.abs(robot.angles() - [target[n] for n in LEFT])) < 0.01   # stays there
        index = [states[0].name.index(n) for n in LEFT]
        reported = np.array([np.array(m.velocity)[index] for m in states])
        positions = np.array([np.array(m.position)[index] for m in states])
        stamps = np.array([m.header.stamp.to_sec() for m in states])
        every = max(1, len(stamps) // 40)
        measured = np.diff(positions[::every], axis=0) / np.diff(stamps[::every])[:, None]
        peak = np.max(np.abs(np.vstack([reported, measured])), axis=0)
        assert np.all(peak <= ratio * limits * 1.05 + 0.01), (ratio, peak)
        assert peak[0] > 0.8 * min(ratio * limits[0], math.sqrt(3.0 * 0.6))   # it did use the allowed speed
        # The endpoint twist is the Jacobian times the joint velocities (the official simulator publishes zeros).
        by_stamp = {m.header.stamp: m for m in states}
        fastest = max((m for _, m in robot.endpoint.messages if m.header.stamp in by_stamp),
                      key=lambda m: abs(by_stamp[m.header.stamp].velocity[index[0]]))
        joints = by_stamp[fastest.header.stamp]
        expected = kin.jacobian(np.array(joints.position)[index]) @ np.array(joints.velocity)[index]
        twist = fastest.twist
        reported = [twist.linear.x, twist.linear.y, twist.linear.z, twist.angular.x, twist.angular.y, twist.angular.z]
        assert np.linalg.norm(expected[:3]) > 0.1
        np.testing.assert_allclose(reported, expected, atol=0.01 + 0.05 * np.linalg.norm(expected[:3]))
    robot.speed_ratio.publish(Float64(0.3))
    robot.move_to(dict(zip(LEFT, start)))


def test_velocity_mode_follows_and_times_out_to_holding(robot):
    w2 = LEFT.index('left_w2')
    for timeout, velocity in ((None, 0.5), (0.6, -0.5)):
        if timeout is not None:
            robot.command_timeout.publish(Float64(timeout))
            sim_sleep(0.05)
        command = msg.JointCommand(mode=2, names=['left_w2'], command=[velocity])
        end = rospy.get_time() + 0.8
        while rospy.get_time() < end:
            robot.joint_command.publish(command)
            time.sleep(0.005)
        last_command = rospy.get_time()
        joints = robot.joint_states.latest()
        assert joints.velocity[joints.name.index('left_w2')] == pytest.approx(velocity, abs=0.05)
        stopped = robot.joint_states.wait_for(
            lambda m: m.header.stamp.to_sec() > last_command and abs(m.velocity[m.name.index('left_w2')]) < 0.02,
            oldest=True)
        assert stopped.header.stamp.to_sec() - last_command == pytest.approx(timeout or 0.2, abs=0.1)
        held = robot.angles()[w2]
        sim_sleep(0.5)
        assert abs(robot.angles()[w2] - held) < 0.005
    robot.command_timeout.publish(Float64(0.2))


def test_bad_joint_commands_are_ignored_with_an_error(robot):
    q_before = robot.angles()
    bad_commands = [
        msg.JointCommand(mode=1, names=['left_s0'], command=[float('nan')]),
        msg.JointCommand(mode=1, names=['left_s0'], command=[float('inf')]),
        msg.JointCommand(mode=1, names=['left_elbow'], command=[0.1]),
        msg.JointCommand(mode=1, names=['left_s0', 'left_s1'], command=[0.1]),
        msg.JointCommand(mode=7, names=['left_s0'], command=[0.1]),
        msg.JointCommand(mode=2, names=['right_s0'], command=[0.5]),
    ]
    for command in bad_commands:
        robot.joint_command.publish(command)
        sim_sleep(0.05)
    sim_sleep(0.3)
    assert np.max(np.abs(robot.angles() - q_before)) < 0.005
    log = robot.process.log()
    assert 'non-finite' in log and 'unknown joint name' in log and 'unknown mode' in log
    assert robot.process.process.poll() is None


# ============================================================================ IK service
def test_ik_round_trip_over_50_reachable_poses(robot, kin):
    rng = np.random.default_rng(7)
    configurations = [rng.uniform(kin.lower + 0.1, kin.upper - 0.1) for _ in range(50)]
    request = srv.SolvePositionIKRequest(seed_mode=0)
    targets = []
    for q in configurations:
        pose = PoseStamped()
        pose.header.frame_id = 'base'
        targets.append(kin.fk(q))
        matrix_to_pose_msg(targets[-1], pose.pose)
        request.pose_stamp.append(pose)
    response = robot.ik(request)
    result_types = struct.unpack('<%dB' % len(response.result_type), response.result_type)  # baxter_examples
    assert all(response.isValid) and all(r in (1, 2, 3) for r in result_types)
    for T_target, joints in zip(targets, response.joints):
        assert list(joints.name) == LEFT
        q = np.array(joints.position)
        assert np.all(q >= kin.lower - 1e-9) and np.all(q <= kin.upper + 1e-9)
        T = kin.fk(q)
        assert np.linalg.norm(T[:3, 3] - T_target[:3, 3]) < 1e-3
        assert rotation_angle_between(T, T_target) < math.radians(0.5)


def test_ik_seed_modes_and_clean_failure(robot, kin):
    current = robot.angles()
    pose = PoseStamped()
    pose.header.frame_id = 'base'
    matrix_to_pose_msg(kin.fk(current), pose.pose)
    response = robot.ik(srv.SolvePositionIKRequest(pose_stamp=[pose], seed_mode=2))
    assert response.isValid[0] and response.result_type[0] == 2
    np.testing.assert_allclose(response.joints[0].position, current, atol=0.02)

    seed = JointState(name=LEFT, position=list(current))
    response = robot.ik(srv.SolvePositionIKRequest(pose_stamp=[pose], seed_angles=[seed], seed_mode=1))
    assert response.isValid[0] and response.result_type[0] == 1

    mount = PoseStamped()                       # a pose given in another URDF frame is transformed to base
    mount.header.frame_id = 'left_arm_mount'
    matrix_to_pose_msg(invert(kin.fk(current, 'left_arm_mount')) @ kin.fk(current), mount.pose)
    unknown = PoseStamped(pose=pose.pose)
    unknown.header.frame_id = 'kitchen'
    response = robot.ik(srv.SolvePositionIKRequest(pose_stamp=[mount, unknown], seed_mode=2))
    assert list(response.isValid) == [True, False] and list(response.result_type) == [2, 0]
    np.testing.assert_allclose(response.joints[0].position, current, atol=0.02)

    far = PoseStamped()
    far.header.frame_id = 'base'
    far.pose.position.x, far.pose.position.y, far.pose.position.z = 2.0, 2.0, 2.0
    far.pose.orientation.w = 1.0
    response = robot.ik(srv.SolvePositionIKRequest(pose_stamp=[far], seed_mode=0))
    assert list(response.isValid) == [False] and list(response.result_type) == [0]
    assert list(response.joints[0].position) == []

    with pytest.raises(rospy.ServiceException):
        robot.ik(srv.SolvePositionIKRequest(pose_stamp=[pose], seed_mode=1))   # SEED_USER without seeds


# ============================================================================ cameras
def _block_silhouette(camera, T_camera_block, model):
    """Filled mask of the block's silhouette (convex hull of its projected prism vertices)."""
    top = model.vertices
    corners = np.vstack([top, top - [0.0, 0.0, model.height]])
    pixels = camera.project((corners @ T_camera_block[:3, :3].T) + T_camera_block[:3, 3])
    mask = np.zeros((camera.height, camera.width), np.uint8)
    hull = cv2.convexHull(np.round(pixels * 16).astype(np.int32))
    cv2.fillConvexPoly(mask, hull, 1, lineType=cv2.LINE_8, shift=4)
    return mask


def _centroid(mask):
    m = cv2.moments(mask, binaryImage=True)
    return np.array([m['m10'] / m['m00'], m['m01'] / m['m00']]), m['m00']


def test_every_camera_mode_shows_the_block_where_the_model_projects_it(robot, kin, scene):
    assert scene.camera_error.focal_scale == 1.0 and not any(scene.camera_error.xyz + scene.camera_error.rpy)
    assert set(rospy.ServiceProxy('/cameras/list', srv.ListCameras)().cameras) == {
        'left_hand_camera', 'right_hand_camera', 'head_camera'}
    open_camera = rospy.ServiceProxy('/cameras/open', srv.OpenCamera)
    close_camera = rospy.ServiceProxy('/cameras/close', srv.CloseCamera)
    images = Recorder('/cameras/left_hand_camera/image', Image, keep=20)
    infos = Recorder('/cameras/left_hand_camera/camera_info', CameraInfo, keep=20)
    block = model_for(scene.objects[0].shape, scene.objects[0].side, scene.objects[0].height)
    T_base_camera = kin.fk(robot.angles(), 'left_hand_camera')
    T_camera_block = invert(T_base_camera) @ robot.block_pose(0)
    try:
        for width, height in MODES:
            opened_at = rospy.get_time()
            settings = msg.CameraSettings(width=width, height=height, fps=10.0)
            assert open_camera('left_hand_camera', settings).err == 0
            image = images.wait_for(lambda m: m.width == width and m.header.stamp.to_sec() >= opened_at, 20.0)
            info = infos.wait_for(lambda m: m.width == width and m.header.stamp == image.header.stamp, 5.0)
            assert (image.height, image.encoding, info.height) == (height, 'bgra8', height)
            camera = CameraModel.from_camera_info(info)
            seen, seen_area = _centroid(green_mask(msg_to_bgr(image)))
            expected, expected_area = _centroid(_block_silhouette(camera, T_camera_block, block))
            assert np.linalg.norm(seen - expected) < 2.0, (width, seen, expected)
            assert seen_area == pytest.approx(expected_area, rel=0.15)
        assert close_camera('left_hand_camera').err == 0
        closed_at = rospy.get_time()
        sim_sleep(0.5)
        assert all(m.header.stamp.to_sec() <= closed_at for _, m in images.messages)
    finally:
        images.close()
        infos.close()


def test_camera_services_errors_and_two_open_limit(robot):
    open_camera = rospy.ServiceProxy('/cameras/open', srv.OpenCamera)
    close_camera = rospy.ServiceProxy('/cameras/close', srv.CloseCamera)

    def settings(width=320, height=200, fps=1.0):
        return msg.CameraSettings(width=width, height=height, fps=fps)

    assert open_camera('left_hand_camera', settings(800, 800)).err == errno.EINVAL
    assert open_camera('left_hand_camera', settings(fps=0.0)).err == errno.EINVAL
    assert open_camera('torso_camera', settings()).err != 0
    assert close_camera('head_camera').err in (0, errno.EINVAL)
    try:
        assert open_camera('left_hand_camera', settings()).err == 0
        assert open_camera('right_hand_camera', settings()).err == 0
        assert open_camera('head_camera', settings()).err != 0              # a third one
        assert open_camera('left_hand_camera', settings(640, 400)).err == 0   # re-open = new settings
        assert close_camera('right_hand_camera').err == 0
        assert open_camera('head_camera', settings()).err == 0
    finally:
        for name in ('left_hand_camera', 'right_hand_camera', 'head_camera'):
            close_camera(name)
    assert close_camera('left_hand_camera').err == errno.EINVAL


# ============================================================================ gripper
def test_gripper_protocol_over_ros(robot):
    properties = rospy.wait_for_message(f'{GRIPPER}/properties', msg.EndEffectorProperties, timeout=5.0)
    state = robot.gripper_state.latest()
    assert properties.ui_type == 2 and properties.id == state.id
    assert properties.firmware_date == '2014/7/24 18:30:00'
    acknowledged, _ = robot.gripper('configure', '{"velocity": 50.0, "moving_force": 40.0, '
                                                    '"holding_force": 30.0, "dead_zone": 5.0}')
    assert acknowledged < 0.5
    assert robot.gripper_state.latest().calibrated == 0        # boots uncalibrated, like the real gripper
    acknowledged, done = robot.calibrate_gripper()
    assert acknowledged < 0.5 and done < 5.0
    for position in (100.0, 0.0):
        acknowledged, done = robot.gripper(
            'go', '{"position": %.1f}' % position,
            test=lambda s: abs(s.position - position) < 5.0 or s.gripping == 1)
        assert acknowledged < 0.5 and done < 5.0
    closed_at = rospy.get_time()
    final = robot.gripper_state.wait_for(lambda s: s.timestamp.to_sec() >= closed_at and s.moving == 0)
    assert final.missed == 1 and final.gripping == 0          # closed on nothing
    robot.gripper('go', '{"position": 100.0}', test=lambda s: s.position > 95.0)


def _expected_ranges(T_base_range, table_z, T_base_block, model, edge_margin=0.003):
    """Distances (m) the range ray (+x of ``left_hand_range``) may report: the block's top face if it
    passes through it, else the table (both when it passes within ``edge_margin`` of the top face's edge)."""
    direction = T_base_range[:3, 0]
    ranges = []
    T_block_range = invert(T_base_block) @ T_base_range
    origin_b, direction_b = T_block_range[:3, 3], T_block_range[:3, 0]
    if direction_b[2] < 0:
        distance = -origin_b[2] / direction_b[2]
        hit = origin_b + distance * direction_b
        inside = cv2.pointPolygonTest(model.vertices[:, :2].astype(np.float32), (float(hit[0]), float(hit[1])), True)
        if inside > -edge_margin:
            ranges.append(distance)
        if inside > edge_margin:
            return ranges
    if direction[2] < 0:
        ranges.append((table_z - T_base_range[2, 3]) / direction[2])
    return ranges


def test_pick_up_the_block_through_ros(robot, scene, kin):
    obj = scene.objects[0]
    T_block = robot.block_pose(0)
    yaw = math.atan2(T_block[1, 0], T_block[0, 0])
    pointing_down = make_transform(np.diag([1.0, -1.0, -1.0]))   # gripper z = -base z, fingers close along block y
    T_grasp = make_transform(None, T_block[:3, 3] + [0.0, 0.0, -0.012]) @ \
        make_transform(np.array([[math.cos(yaw), -math.sin(yaw), 0], [math.sin(yaw), math.cos(yaw), 0], [0, 0, 1]])) @ \
        pointing_down
    above = make_transform(None, [0.0, 0.0, 0.10])

    robot.calibrate_gripper()
    robot.gripper('go', '{"position": 100.0}', test=lambda s: s.position > 95.0)
    robot.move_to(robot.solve_ik(above @ T_grasp))
    sim_sleep(0.05)
    reading = rospy.wait_for_message('/robot/range/left_hand_range/state', Range, timeout=5.0).range
    expected = _expected_ranges(kin.fk(robot.angles(), 'left_hand_range'), scene.table.top_z, T_block,
                                model_for(obj.shape, obj.side, obj.height))
    assert any(abs(reading - distance) < 0.005 for distance in expected), (reading, expected)
    robot.move_to(robot.solve_ik(T_grasp, seed_mode=2))
    robot.gripper('go', '{"position": 0.0}', test=lambda s: s.gripping == 1 or (s.moving == 0 and s.position < 5))
    closed_at = rospy.get_time()
    state = robot.gripper_state.wait_for(lambda s: s.timestamp.to_sec() >= closed_at and s.moving == 0)
    assert state.gripping == 1 and state.missed == 0
    assert state.position == pytest.approx(100.0 * (obj.side - 0.016) / 2 / 0.020833, abs=8.0)
    z_before = robot.block_pose(0)[2, 3]
    robot.move_to(robot.solve_ik(above @ T_grasp, seed_mode=2))
    sim_sleep(0.5)
    lifted = robot.block_pose(0)[2, 3] - z_before
    assert lifted == pytest.approx(0.10, abs=0.01)
    assert robot.gripper_state.latest().gripping == 1
    robot.gripper('go', '{"position": 100.0}', test=lambda s: s.position > 95.0)
