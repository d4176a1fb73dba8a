"""Integration tests of baxter_pnp.robot: a private rosmaster and the fake Baxter as a separate process.

The tests run in file order: first what needs no robot (fallbacks, frame validation), then the
robot clients against one fake Baxter, and last the watchdog after that fake Baxter is stopped.
"""
import subprocess
import sys
import time

import numpy as np
import pytest
import rospy
from rosgraph_msgs.msg import Log
from scipy.spatial.transform import Rotation
from sensor_msgs.msg import CameraInfo, Image, JointState

from baxter_pnp.camera import load_default_camera
from baxter_pnp.kinematics import ArmKinematics
from baxter_pnp.msgs import msg
from baxter_pnp.robot import (Gripper, HandCamera, IKFailure, Limb, RobotEnable, RobotTimeout, ServiceUnavailable,
                              StreamLost, hand_eye_transform)
from baxter_pnp.robot.camera import camera_controls
from baxter_pnp.robot.limb import _arm_joint_state, _endpoint_state
from baxter_pnp.ros_image import bgr_to_msg
from baxter_pnp.safety import ArmSafety, UnsafeCommand
from baxter_pnp.transforms import from_xyz_rpy, make_transform, matrix_to_pose_msg
from fake_baxter_client import Recorder, joint_velocity, sim_sleep

TABLE_Z = -0.15
DOWN = Rotation.from_euler('xyz', [0, np.pi, 0])        # gripper pointing straight down (the 'down' start pose)
# URDF joint left_hand -> left_hand_camera (reference/baxter_kinematics.md §2).
T_HAND_CAMERA_URDF = from_xyz_rpy((0.03825, 0.012, 0.015355), (0, 0, -1.57079633))


@pytest.fixture(scope='module')
def kinematics():
    arm = ArmKinematics('left')
    yield arm
    arm.close()


def wait_for_connection(publisher, timeout=5.0):
    deadline = time.monotonic() + timeout
    while publisher.get_num_connections() == 0:
        assert time.monotonic() < deadline, f'nobody subscribed to {publisher.resolved_name}'
        time.sleep(0.02)


# ============================================================================ without a robot
IMPORT_PROBE = """
import sys
import baxter_pnp.robot.sdk
heavy = sorted(name for name in ('rospy', 'numpy') if name in sys.modules)
import baxter_pnp.sim.node
print('probe:', heavy, sorted(name for name in sys.modules if name.startswith('baxter_pnp.robot')))
"""


def test_the_sdk_module_is_cheap_and_all_the_fake_baxter_loads_of_the_robot_package():
    result = subprocess.run([sys.executable, '-c', IMPORT_PROBE], capture_output=True, text=True, timeout=120)
    assert result.returncode == 0, result.stderr
    assert "probe: [] ['baxter_pnp.robot', 'baxter_pnp.robot.sdk']" in result.stdout.splitlines()


def test_joint_state_messages_are_filtered_and_validated(kinematics):
    names = kinematics.joint_names
    real_robot_order = ['head_pan', 'left_e0', 'left_e1', 'left_s0', 'left_s1', 'left_w0', 'left_w1', 'left_w2',
                        'right_s0']
    angles = {'left_s0': 0.1, 'left_s1': -0.5, 'left_e0': 0.2, 'left_e1': 1.0, 'left_w0': 0.3, 'left_w1': 0.9,
              'left_w2': -0.2}
    message = JointState(name=real_robot_order, position=[angles.get(n, 9.0) for n in real_robot_order],
                         velocity=[0.0] * 9, effort=[0.0] * 9)
    state = _arm_joint_state(names, message)
    np.testing.assert_array_equal(state.positions, [angles[n] for n in names])
    assert _arm_joint_state(names, JointState(name=['l_gripper_l_finger_joint'], position=[0.01])) is None
    message.position[2] = float('nan')
    with pytest.raises(ValueError, match='non-finite joint position'):
        _arm_joint_state(names, message)


def test_endpoint_messages_are_validated():
    T = make_transform(DOWN, (0.6, 0.2, 0.1))
    message = msg.EndpointState()
    matrix_to_pose_msg(T, message.pose)
    message.twist.linear.x, message.twist.angular.z = 0.05, -0.3
    message.header.stamp = rospy.Time(12, 500000000)
    state = _endpoint_state(message)
    np.testing.assert_allclose(state.T_base_gripper, T, atol=1e-12)
    np.testing.assert_array_equal(state.twist, [0.05, 0.0, 0.0, 0.0, 0.0, -0.3])     # [v (m/s); w (rad/s)] in base
    assert state.stamp == 12.5
    message.twist.angular.z = float('inf')
    with pytest.raises(ValueError, match='non-finite'):
        _endpoint_state(message)
    message.twist.angular.z = 0.0
    message.pose.orientation.w += 0.5
    with pytest.raises(ValueError, match='unit quaternion'):
        _endpoint_state(message)


class _RosoutLines:
    """The text of every /rosout log line this process's node publishes from now on (what ``rqt_console`` shows)."""

    def __init__(self):
        self.lines = []
        self._subscriber = rospy.Subscriber('/rosout', Log, lambda m: self.lines.append(m.msg), queue_size=100)
        deadline = time.monotonic() + 5.0
        while not self.lines:                       # lines logged before the subscription connects are lost
            assert time.monotonic() < deadline, '/rosout does not reach this subscriber'
            rospy.loginfo('test_robot_interface: listening to /rosout')
            time.sleep(0.05)

    def wait_for(self, *fragments, timeout=5.0):
        """The first line holding every ``fragment``; fails after ``timeout`` wall s."""
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            found = [line for line in list(self.lines) if all(f in line for f in fragments)]
            if found:
                return found[0]
            time.sleep(0.02)
        raise AssertionError(f'no /rosout line with {fragments} within {timeout} s; got {self.lines}')

    def close(self):
        self._subscriber.unregister()


def test_nan_or_inf_joint_and_endpoint_states_are_logged_and_never_cached(ros_node, kinematics):
    """README "Failure modes", bad input: a real ``Limb`` on the master, this process playing the robot. NaN/inf
    joint or endpoint states are rejected with a /rosout line naming the problem; the cached readings stay the
    last good ones (the endpoint history too), and rejected messages do not keep a stream fresh."""
    names = kinematics.joint_names
    q_good = np.array([0.1, -0.5, 0.2, 1.0, 0.3, 0.9, -0.2])
    T_good = kinematics.fk(q_good)

    def joint_state(positions, velocities=np.zeros(7)):
        return JointState(name=list(names), position=list(positions), velocity=list(velocities),
                          effort=[0.0] * 7)

    def endpoint_state(T, twist=np.zeros(6), stamp=1.0):
        message = msg.EndpointState()
        message.header.stamp = rospy.Time.from_sec(stamp)
        matrix_to_pose_msg(T, message.pose)
        (message.twist.linear.x, message.twist.linear.y, message.twist.linear.z,
         message.twist.angular.x, message.twist.angular.y, message.twist.angular.z) = twist
        return message

    rosout = _RosoutLines()
    joints = rospy.Publisher('/robot/joint_states', JointState, queue_size=10, latch=True)
    endpoint = rospy.Publisher('/robot/limb/left/endpoint_state', msg.EndpointState, queue_size=10, latch=True)
    commands = rospy.Subscriber('/robot/limb/left/joint_command', msg.JointCommand, lambda m: None)  # "the robot"
    try:
        joints.publish(joint_state(q_good))
        endpoint.publish(endpoint_state(T_good))
        limb = Limb('left', ArmSafety.for_arm(kinematics), max_age=5.0)
        np.testing.assert_array_equal(limb.joint_positions(), q_good)
        bad_position, bad_velocity = q_good.copy(), np.zeros(7)
        bad_position[2], bad_velocity[4] = float('nan'), float('inf')
        # One at a time: the clients keep only the newest message of a burst (queue_size 1).
        for publisher, message, problem in [
                (joints, joint_state(bad_position), ('non-finite joint position', 'nan')),
                (joints, joint_state(q_good, bad_velocity), ('non-finite joint velocity', 'inf')),
                (endpoint, endpoint_state(make_transform(DOWN, (np.nan, 0.2, 0.1)), stamp=2.0),
                 ('non-finite endpoint state', 'position [nan')),
                (endpoint, endpoint_state(T_good, twist=(0.0, 0.0, 0.0, 0.0, 0.0, np.inf), stamp=3.0),
                 ('non-finite endpoint state', 'inf]'))]:
            publisher.publish(message)
            rosout.wait_for(f'{publisher.resolved_name}: message rejected', *problem)
        np.testing.assert_array_equal(limb.joint_positions(), q_good)
        np.testing.assert_allclose(limb.endpoint_pose(), T_good, atol=1e-9)
        np.testing.assert_allclose(limb.endpoint_pose_at(3.0), T_good, atol=1e-9)     # only the good one held
        time.sleep(0.3)
        bad_velocity[5] = -np.inf                                   # a new text: never throttled as identical
        joints.publish(joint_state(q_good, bad_velocity))          # arrives (logged), but is no sign of life
        rosout.wait_for('non-finite joint velocity', '-inf')
        with pytest.raises(StreamLost, match='/robot/joint_states'):
            limb.require_fresh(0.3)
        q_next = q_good + 0.01
        joints.publish(joint_state(q_next))                        # a good message is taken again
        deadline = time.monotonic() + 5.0
        while not np.array_equal(limb.joint_positions(), q_next):
            assert time.monotonic() < deadline, 'the good joint state after the bad ones was not taken'
            time.sleep(0.01)
    finally:
        for topic in (joints, endpoint, commands):
            topic.unregister()
        rosout.close()


def test_clients_time_out_without_a_robot(ros_node, kinematics):
    started = time.monotonic()
    with pytest.raises(RobotTimeout, match='/robot/state'):
        RobotEnable(timeout=0.5)
    with pytest.raises(RobotTimeout, match='/robot/joint_states'):
        Limb('left', ArmSafety.for_arm(kinematics), timeout=0.5)
    assert time.monotonic() - started < 3.0


def test_hand_eye_falls_back_to_the_urdf_without_tf(ros_node):
    hand_eye = hand_eye_transform('left', timeout=0.3)
    assert hand_eye.source == 'urdf'
    np.testing.assert_allclose(hand_eye.T_hand_camera, T_HAND_CAMERA_URDF, atol=1e-6)
    # The sim gripper tip is 0.1577 m along the hand's z axis.
    np.testing.assert_allclose(hand_eye.T_gripper_camera[:3, 3], (0.03825, 0.012, 0.015355 - 0.1577), atol=1e-6)


def test_camera_controls_are_checked_before_the_robot_is_asked():
    """Exposure 0-100 and gain 0-79 (baxter_interface's ranges) as CameraControl (id, value); automatic (-1) sends
    none, so the robot keeps its own; anything else is a ValueError."""
    assert camera_controls(80, 0) == [(100, 80), (101, 0)]
    assert camera_controls() == camera_controls(-1, -1) == []
    for exposure, gain in ((101, -1), (-1, 80), (-2, -1), (True, -1), (50.0, -1)):
        with pytest.raises(ValueError, match='exposure|gain'):
            camera_controls(exposure, gain)
    with pytest.raises(ValueError, match='gain'):
        HandCamera('left', gain=100)


def test_camera_frames_are_validated(ros_node):
    """Without /cameras/list the camera is assumed to stream; bad frames are logged and dropped, never cached."""
    camera = HandCamera('right', service_timeout=0.3)
    assert not camera.opened
    image_pub = rospy.Publisher(camera.image_topic, Image, queue_size=10)
    info_pub = rospy.Publisher(camera.info_topic, CameraInfo, queue_size=10, latch=True)
    wait_for_connection(image_pub)
    model = load_default_camera().scaled(640, 400)
    image = np.random.default_rng(1).integers(0, 255, (400, 640, 3), dtype=np.uint8)
    stamp = rospy.Time.from_sec(1.0)

    def publish(encoding, seconds, size=(400, 640)):
        message = bgr_to_msg(np.ascontiguousarray(image[:size[0], :size[1]]), 'bgr8')
        message.encoding = encoding if encoding != 'bgr8' else message.encoding
        message.header.stamp = rospy.Time.from_sec(seconds)
        image_pub.publish(message)

    publish('bgr8', 1.0)                                  # no camera_info yet: dropped
    time.sleep(0.3)
    assert camera.latest() is None
    info_pub.publish(model.to_camera_info())
    wait_for_connection(info_pub)
    time.sleep(0.3)
    publish('16UC1', 2.0)                                 # unsupported encoding: dropped
    publish('bgr8', 3.0, size=(300, 480))                 # size differs from camera_info: dropped
    time.sleep(0.3)
    assert camera.latest() is None
    for encoding in ('rgb8', 'bgr8'):
        message = bgr_to_msg(image, encoding)
        message.header.stamp = stamp = rospy.Time.from_sec(stamp.to_sec() + 1.0)
        image_pub.publish(message)
        frame = camera.wait_for_frame(after_stamp=stamp.to_sec() - 0.5, timeout=2.0)
        np.testing.assert_array_equal(frame.image_bgr, image)
        assert frame.stamp == pytest.approx(stamp.to_sec())
        assert frame.camera.width == 640 and frame.camera.fx == pytest.approx(model.fx)
    with pytest.raises(RobotTimeout, match='no new valid frame'):
        camera.wait_for_frame(after_stamp=stamp.to_sec(), timeout=0.3)
    camera.close()
    image_pub.unregister()
    info_pub.unregister()


# ============================================================================ with the fake Baxter
@pytest.fixture(scope='module')
def fake(fake_baxter):
    return fake_baxter()


@pytest.fixture(scope='module')
def robot(ros_node, fake):
    return RobotEnable()


@pytest.fixture(scope='module')
def limb(robot, kinematics):
    robot.enable()
    return Limb('left', ArmSafety.for_arm(kinematics, table_top_z=TABLE_Z))


@pytest.fixture(scope='module')
def gripper(robot):
    return Gripper('left')


@pytest.fixture(scope='module')
def camera(robot):
    hand_camera = HandCamera('left', resolution=(640, 400), fps=20)
    yield hand_camera
    hand_camera.close()


def test_enable_disable_stop_reset(robot):
    robot.enable()
    assert robot.state().enabled
    robot.disable()
    assert not robot.state().enabled
    robot.stop()
    assert robot.state().stopped and not robot.state().enabled
    robot.enable()                                        # resets the stopped robot first
    state = robot.state()
    assert state.enabled and not state.stopped


def test_joint_states_and_endpoint(limb, kinematics):
    q = limb.joint_positions()
    assert q.shape == (7,) and np.all(np.isfinite(q))
    assert list(limb.joint_angles()) == kinematics.joint_names
    # The endpoint the robot reports is the URDF's left_gripper at the reported angles.
    np.testing.assert_allclose(limb.endpoint_pose(), kinematics.fk(q), atol=2e-3)


def test_ik_and_move_to_joint_positions(limb, kinematics):
    limb.set_speed_ratio(0.6)
    T_start = limb.endpoint_pose()
    T_target = make_transform(DOWN, T_start[:3, 3] + (0.0, 0.05, -0.15))
    solution = limb.solve_ik(T_target, seed=limb.joint_angles())
    q_target = np.array([solution[name] for name in limb.joint_names])
    np.testing.assert_allclose(kinematics.fk(q_target)[:3, 3], T_target[:3, 3], atol=1e-3)
    q_start, started = limb.joint_positions(), time.monotonic()
    assert limb.move_to_joint_positions(solution, timeout=20.0)
    print(f'move of {np.abs(q_target - q_start).max():.3f} rad took {time.monotonic() - started:.2f} s')
    assert np.all(np.abs(limb.joint_positions() - q_target) < 0.0088)
    assert np.linalg.norm(limb.endpoint_pose()[:3, 3] - T_target[:3, 3]) < 0.01


def test_unreachable_pose_raises_ik_failure(limb):
    with pytest.raises(IKFailure, match='no joint solution'):
        limb.solve_ik(make_transform(DOWN, (2.0, 0.3, 0.0)))


def test_move_below_the_table_is_refused_before_anything_is_sent(limb, kinematics):
    commands = []
    listener = rospy.Subscriber('/robot/limb/left/joint_command', msg.JointCommand, commands.append)
    wait_for_connection(limb._command_pub)
    time.sleep(0.2)
    q_before = limb.joint_positions()
    T_tip = limb.endpoint_pose()
    q_below = kinematics.ik(make_transform(DOWN, (T_tip[0, 3], T_tip[1, 3], TABLE_Z - 0.01)), seed=q_before)
    assert q_below is not None
    with pytest.raises(UnsafeCommand, match='below the table'):
        limb.move_to_joint_positions(q_below, timeout=5.0)
    time.sleep(0.5)
    listener.unregister()
    assert commands == []
    np.testing.assert_allclose(limb.joint_positions(), q_before, atol=1e-3)


def test_velocity_commands_and_exit_control_mode(limb):
    """set_joint_velocities streams VELOCITY_MODE commands the fake follows (its joint_states show that velocity,
    on the wrist only); exit_control_mode holds. Judged on the fake's clock, however this process was scheduled:
    the wrist turned at most the commanded speed times the simulated time the fake reported following it."""
    w2 = limb.joint_names.index('left_w2')
    qdot = np.zeros(7)
    qdot[w2] = 0.3                                          # rad/s, wrist roll: the tip stays in place
    with pytest.raises(UnsafeCommand, match='left_w2 velocity 5.000 rad/s exceeds'):
        limb.set_joint_velocities(np.where(np.arange(7) == w2, 5.0, 0.0))
    states = Recorder('/robot/joint_states', JointState)
    try:
        states.latest()
        q_start = limb.joint_positions()
        ros_start = rospy.get_time()
        while rospy.get_time() - ros_start < 0.5:
            limb.set_joint_velocities(qdot)
            time.sleep(0.02)
        limb.exit_control_mode()
        sim_sleep(0.5)                                          # the hold settles on the fake's clock, load or not
        q_held = limb.joint_positions()
        stamped = [(m.header.stamp.to_sec(), joint_velocity(m, 'left_w2')) for _, m in states.messages]
        moving = [m for _, m in states.messages if joint_velocity(m, 'left_w2') == pytest.approx(0.3, abs=0.01)]
    finally:
        states.close()
    # Simulated time between consecutive states received, when either shows 0.3 rad/s (states the fake dropped
    # while this process was slow only lengthen it: an upper bound of the time spent following).
    following = sum(t1 - t0 for (t0, v0), (t1, v1) in zip(stamped, stamped[1:])
                    if pytest.approx(0.3, abs=0.01) in (v0, v1))
    others = [np.delete(np.array(m.velocity)[[m.name.index(n) for n in limb.joint_names]], w2) for m in moving]
    moved = q_held[w2] - q_start[w2]
    print(f'\nthe wrist turned {moved:.4f} rad while the fake followed 0.3 rad/s for {following:.3f} s')
    assert following > 0.1 and stamped[-1][1] == pytest.approx(0.0, abs=0.01)      # holding
    assert np.max(np.abs(others)) < 0.01                       # only the wrist was commanded
    # The hold goes back to the angle exit_control_mode last read, which the wrist had passed by the time the hold
    # arrived (by 0.3 rad/s x this process's delivery lag): less than followed, never more.
    assert 0.0 < moved <= 0.3 * following
    np.testing.assert_allclose(np.delete(q_held, w2), np.delete(q_start, w2), atol=0.01)
    sim_sleep(0.3)
    np.testing.assert_allclose(limb.joint_positions(), q_held, atol=0.005)   # held, not drifting


def test_gripper_calibrate_close_open(gripper):
    assert gripper.calibrated() and gripper.ready()
    assert gripper.close(block=True)
    assert gripper.position() < gripper.parameters['dead_zone']
    # close() returns once within the dead zone; 'missed' is reported when the fingers stop, closed on nothing.
    deadline = time.monotonic() + 2.0
    while gripper.moving() and time.monotonic() < deadline:
        time.sleep(0.02)
    assert gripper.missed() and not gripper.gripping()
    assert gripper.open(block=True)
    assert gripper.position() > 100.0 - gripper.parameters['dead_zone']
    assert not gripper.missed()


def test_camera_opens_and_delivers_frames(camera):
    assert camera.opened
    frame = camera.wait_for_frame(timeout=5.0)
    second = camera.wait_for_frame(after_stamp=frame.stamp, timeout=5.0)
    assert second.stamp > frame.stamp
    assert second.image_bgr.shape == (400, 640, 3) and second.image_bgr.dtype == np.uint8
    assert second.image_bgr.std() > 5.0                   # a rendered scene, not a blank image
    assert (second.camera.width, second.camera.height) == (640, 400)
    assert second.camera.frame_id == 'left_hand_camera' and second.camera.fx > 0


def test_hand_eye_from_tf_matches_the_urdf(fake, ros_node, kinematics):
    hand_eye = hand_eye_transform('left', timeout=5.0)
    assert hand_eye.source == 'tf'
    np.testing.assert_allclose(hand_eye.T_hand_camera, T_HAND_CAMERA_URDF, atol=1e-6)
    q = np.array([0.1, -0.5, 0.2, 1.0, 0.3, 0.9, -0.2])
    T_gripper_camera = np.linalg.inv(kinematics.fk(q, 'left_gripper')) @ kinematics.fk(q, 'left_hand_camera')
    np.testing.assert_allclose(hand_eye.T_gripper_camera, T_gripper_camera, atol=1e-6)


def test_streams_are_lost_when_the_robot_dies(fake, limb, gripper, camera, robot):
    limb.require_fresh(0.5)
    camera.require_fresh(0.5)
    fake.stop()
    time.sleep(0.8)
    with pytest.raises(StreamLost, match='/robot/joint_states'):
        limb.require_fresh(0.5)
    with pytest.raises(StreamLost, match='/robot/joint_states'):
        limb.move_to_joint_positions({}, timeout=1.0)
    with pytest.raises(StreamLost, match='/robot/end_effector/left_gripper/state'):
        gripper.position()
    with pytest.raises(StreamLost, match='/cameras/left_hand_camera/image'):
        camera.require_fresh(0.5)
    with pytest.raises(StreamLost, match='/robot/state'):
        robot.require_fresh(0.5)
    with pytest.raises(ServiceUnavailable, match='IKService'):
        limb.solve_ik(make_transform(DOWN, (0.7, 0.3, 0.0)), timeout=0.5)
