"""A whole Baxter (issue 13): both arms, the head, the I/O, the cameras' topics and the identity, used the way Rethink's
own programs (baxter_tools and baxter_examples 1.2.0) use them.

The SDK is not installable here, so the clients of ``sdk_clients.py`` (``Sdk*``) touch exactly the topics, services,
parameters and waits of ``baxter_interface`` 1.2.0 (``baxter_dataflow.wait_for`` in ROS time, its timeouts and
rates); each test names the program it mirrors and does what that program does, in order. One fake Baxter (booted
disabled, as a robot) serves the whole module at a real-time factor of 1: those programs' timeouts (2 s for an output's
state to follow) assume a robot at real time, and an unpaced fake at 5x left a loaded CI machine 0.4 wall s for a
publisher's connection. The tests run in file order and each leaves the robot enabled or disabled as the next one's
program expects to find it.
"""
import errno
import math
import time

import numpy as np
import pytest
import rosgraph
import rospy
from geometry_msgs.msg import Point, Pose, PoseStamped, Quaternion
from sensor_msgs.msg import Image, JointState, Range
from std_msgs.msg import Bool, Empty, Header
from std_srvs.srv import Empty as EmptyService

from baxter_pnp.kinematics import ArmKinematics, arm_joint_names
from baxter_pnp.msgs import msg, srv
from baxter_pnp.robot import Gripper
from baxter_pnp.ros_image import msg_to_bgr
from baxter_pnp.transforms import pose_msg_to_matrix
from sdk_clients import (HEAD_PAN_ANGLE_TOLERANCE, JOINT_ANGLE_TOLERANCE, SMOKE_TESTS, SdkAnalogIO, SdkDigitalIO,
                         SdkHead, SdkLimb, SdkNavigator, SdkRobotEnable, wait_for)


# ============================================================================ helpers
_HAND = []      # the publisher of press(), connected once: a press lands at once, however fast the fake runs


def press(name, value=True):
    """A person's hand on the robot: set digital input ``name`` through the fake's own test topic."""
    if not _HAND or not _HAND[0].get_num_connections():
        _HAND[:] = [rospy.Publisher('/fake_baxter/set_digital_input', msg.DigitalOutputCommand, queue_size=10)]
        wait_for(lambda: _HAND[0].get_num_connections() > 0, timeout=5.0)
    _HAND[0].publish(msg.DigitalOutputCommand(name=name, value=value))


def ik_request(side):
    """ik_service_client.py's request for ``side`` (its poses, in base, stamped now)."""
    header = Header(stamp=rospy.Time.now(), frame_id='base')
    poses = {
        'left': Pose(position=Point(x=0.657579481614, y=0.851981417433, z=0.0388352386502),
                     orientation=Quaternion(x=-0.366894936773, y=0.885980397775, z=0.108155782462, w=0.262162481772)),
        'right': Pose(position=Point(x=0.656982770038, y=-0.852598021641, z=0.0388609422173),
                      orientation=Quaternion(x=0.367048116303, y=0.885911751787, z=-0.108908281936,
                                             w=0.261868353356)),
    }
    return srv.SolvePositionIKRequest(pose_stamp=[PoseStamped(header=header, pose=poses[side])])


def camera_listed_open(name):
    """camera_control.py -l: a camera is listed '(open)' when the master has a publisher of /cameras/<name>/image."""
    topics = rosgraph.Master('/rostopic').getPublishedTopics('')
    return any(topic == f'/cameras/{name}/image' for topic, _ in topics)


def wait_wall(condition, timeout=10.0):
    deadline = time.monotonic() + timeout
    while not condition():
        assert time.monotonic() < deadline, 'condition not met in time'
        time.sleep(0.02)


@pytest.fixture(scope='module')
def fake(ros_node, fake_baxter):
    return fake_baxter('--real-time-factor', '1')


# ============================================================================ identity, enable, messages
def test_identity_enable_and_messages_as_enable_robot_and_the_smoke_tests(fake):
    """enable_robot.py -e / -d (RobotEnable(CHECK_VERSION)); smoke_test.py's version and serial; the Enable, Messages
    and Services smoke tests."""
    version = rospy.get_param('/rethink/software_version')
    assert len(version.split('.')) == 4                                       # a robot's build string
    assert version.split('_')[0].rsplit('.', 1)[0] in SMOKE_TESTS             # smoke_test.py drops the build
    assert rospy.get_param('manifest/robot_serial')
    robot = SdkRobotEnable(versioned=True)                                      # CHECK_VERSION passes
    assert not robot.state().enabled                                            # a robot boots disabled
    robot.enable()
    assert robot.state().enabled
    robot.disable()
    rospy.wait_for_message('robot/joint_states', JointState, 5.0)              # Messages
    states = rospy.wait_for_message('robot/analog_io_states', msg.AnalogIOStates, 5.0)
    assert 'torso_fan' in states.names and len(states.names) == len(states.states)
    service = '/ExternalTools/left/PositionKinematicsNode/IKService'            # Services
    rospy.wait_for_service(service, 5.0)
    rospy.ServiceProxy(service, srv.SolvePositionIK)(ik_request('left'))


def test_ik_service_client_left_and_right(fake):
    """ik_service_client.py -l left / -l right: the example's pose for each arm is solved by that arm's service; the
    two answers mirror each other (s0, e0, w0, w2 negated), and each puts its gripper at the pose."""
    solutions = {}
    for side in ('left', 'right'):
        name = f'ExternalTools/{side}/PositionKinematicsNode/IKService'
        rospy.wait_for_service(name, 5.0)
        request = ik_request(side)
        response = rospy.ServiceProxy(name, srv.SolvePositionIK)(request)
        assert response.isValid[0] and response.result_type[0] != response.RESULT_INVALID
        assert response.joints[0].name == arm_joint_names(side)
        solutions[side] = np.array(response.joints[0].position)
        T_fk = ArmKinematics(side).fk(solutions[side])
        np.testing.assert_allclose(T_fk[:3, 3], pose_msg_to_matrix(request.pose_stamp[0].pose)[:3, 3], atol=2e-3)
    mirror = np.array([-1, 1, -1, 1, -1, 1, -1])
    mirrored = ArmKinematics('left').fk(mirror * solutions['right'])
    np.testing.assert_allclose(mirrored[:3, 3], [0.656982770038, 0.852598021641, 0.0388609422173], atol=2e-3)


# ============================================================================ both arms
def test_tuck_arms_tuck_then_untuck(fake):
    """tuck_arms.py -t then -u: both Limbs, the collision avoidance states, suppress_collision_avoidance, the Head to
    neutral while enabled, then the 20 Hz command loops until every arm reaches its goal (0.2 rad)."""
    moves = {'tuck': {'left': [-1.0, -2.07, 3.0, 2.55, 0.0, 0.01, 0.0], 'right': [1.0, -2.07, -3.0, 2.55, -0.0, 0.01, 0.0]},
             'untuck': {'left': [-0.08, -1.0, -1.19, 1.94, 0.67, 1.03, -0.50],
                        'right': [0.08, -1.0, 1.19, 1.94, -0.67, 1.03, 0.50]}}
    arms = {side: SdkLimb(side) for side in ('left', 'right')}
    collide = {}
    subs = [rospy.Subscriber(f'robot/limb/{side}/collision_avoidance_state', msg.CollisionAvoidanceState,
                             lambda m, side=side: collide.__setitem__(side, len(m.collision_object) > 0))
            for side in arms]
    suppress = {side: rospy.Publisher(f'robot/limb/{side}/suppress_collision_avoidance', Empty, queue_size=10)
                for side in arms}
    robot = SdkRobotEnable(versioned=True)
    enable_pub = rospy.Publisher('robot/set_super_enable', Bool, queue_size=10)
    head = SdkHead()
    rate = rospy.Rate(20.0)
    start = rospy.get_time()
    while abs(head.pan()) > HEAD_PAN_ANGLE_TOLERANCE or not robot.state().enabled:    # _prepare_to_tuck
        assert rospy.get_time() - start < 10.0, 'the head did not reach neutral'
        if not robot.state().enabled:
            enable_pub.publish(True)
        head.set_pan(0.0, 0.5, timeout=0)
        rate.sleep()

    def reached(side, goal):
        angles = [arms[side].joint_angle(j) for j in arms[side].joint_names()]
        count = 2 if goal == 'tuck' else 7                    # tuck: s0 and s1 only
        return all(abs(a - b) <= 0.2 for a, b in zip(angles[:count], moves[goal][side][:count]))

    for goal in ('untuck', 'tuck', 'untuck'):                 # -t: neutral start first, then tuck; then -u
        start = rospy.get_time()
        while not all(reached(side, goal) for side in arms):
            assert rospy.get_time() - start < 30.0, f'{goal} not reached: {[reached(s, goal) for s in arms]}'
            for side, arm in arms.items():
                suppress[side].publish(Empty())
                arm.set_joint_positions(dict(zip(arm.joint_names(), moves[goal][side])))
            rate.sleep()
        if goal == 'tuck':
            assert all(arm.joint_angle(f'{side}_s1') <= -1.6 for side, arm in arms.items())    # "flipped"
    assert collide == {'left': False, 'right': False}          # states arrived, no collision object
    for sub in subs:
        sub.unregister()


def test_joint_velocity_wobbler_and_smoke_move_arms(fake):
    """joint_velocity_wobbler.py (both arms to neutral, then sine velocities at 100 Hz on both, then
    exit_control_mode) and the MoveArms smoke test (both arms through its joint moves, 15 s each)."""
    robot = SdkRobotEnable(versioned=True)
    robot.enable()
    arms = {side: SdkLimb(side) for side in ('left', 'right')}
    for arm in arms.values():
        arm.move_to_neutral()
    rate = rospy.Rate(100)
    start = rospy.get_time()
    peak = {'left': 0.0, 'right': 0.0}
    while rospy.get_time() - start < 2.0:
        elapsed = rospy.get_time() - start
        for side, arm in arms.items():
            sign = 1.0 if side == 'left' else -1.0
            arm.set_joint_velocities({j: sign * 0.3 * math.sin(2 * math.pi / 2.0 * elapsed) for j in arm.joint_names()})
            peak[side] = max(peak[side], abs(arm.joint_velocities()[f'{side}_s0']))
        rate.sleep()
    assert min(peak.values()) > 0.2                              # both arms followed (rad/s)
    for arm in arms.values():
        arm.exit_control_mode()
    rospy.sleep(0.5)
    # holding: a joint state published after the 0.5 s (this client's cached one may lag by more, the fake running
    # several times faster than real time)
    joints = rospy.wait_for_message('/robot/joint_states', JointState, timeout=5.0)
    arm_joints = {j for arm in arms.values() for j in arm.joint_names()}
    assert max(abs(v) for name, v in zip(joints.name, joints.velocity) if name in arm_joints) < 0.05
    for index, move in enumerate(([0.0, -0.55, 0.0, 0.75, 0.0, 1.26, 0.0], [0.5, -0.8, 2.8, 0.15, 0.0, 1.9, 2.8],
                                  [-0.1, -0.8, -1.0, 2.5, 0.0, -1.4, -2.8], [0.0, -0.55, 0.0, 0.75, 0.0, 1.26, 0.0])):
        targets = {side: dict(zip(arm.joint_names(), move)) for side, arm in arms.items()}
        errors = lambda: {j: round(a - arm.joint_angle(j), 4) for side, arm in arms.items()
                          for j, a in targets[side].items() if abs(a - arm.joint_angle(j)) >= JOINT_ANGLE_TOLERANCE}
        try:
            wait_for(lambda: not errors(), timeout=15.0, rate=100,
                     timeout_msg='MoveArms: the arms failed to reach the joint positions',
                     body=lambda: [arm.set_joint_positions(targets[side]) for side, arm in arms.items()])
        except OSError as error:
            raise AssertionError(f'move {index}: {error}; joint errors (rad) {errors()}') from error
    robot.disable()


def test_grippers_smoke_test_on_both_grippers(fake):
    """The Grippers smoke test (and what gripper_action_server.py needs of each side): the type, the state within
    5 s, reboot, calibrate, close and open blocking, position moves, on the left and the right gripper."""
    for side in ('left', 'right'):
        properties = rospy.wait_for_message(f'robot/end_effector/{side}_gripper/properties',
                                            msg.EndEffectorProperties, 5.0)
        assert properties.ui_type == msg.EndEffectorProperties.ELECTRIC_GRIPPER
        rospy.wait_for_message(f'robot/end_effector/{side}_gripper/state', msg.EndEffectorState, 5.0)
        gripper = Gripper(side)
        assert gripper.command('reboot', block=True, timeout=5.0,
                               test=lambda: gripper.state().enabled == 1 and gripper.state().ready == 1)
        assert gripper.calibrate()
        assert gripper.close(block=True) and gripper.position() < 5.0
        assert gripper.open(block=True) and gripper.position() > 95.0
        assert gripper.command_position(50.0, block=True) and abs(gripper.position() - 50.0) < 5.0


def test_joint_recorder_then_joint_position_file_playback(fake, tmp_path, keeps_real_time):
    """joint_recorder.py (both Limbs, both Grippers calibrated, the four cuff buttons; a row a 1/20 s: time, left
    angles, left gripper, right angles, right gripper; the right lower / upper cuff buttons open / close the right gripper) while
    the right arm is moved, then joint_position_file_playback.py (to the first row, then each row's positions and
    gripper positions at its time)."""
    robot = SdkRobotEnable(versioned=True)
    robot.enable()
    limbs = {side: SdkLimb(side) for side in ('left', 'right')}
    grippers = {side: Gripper(side) for side in ('left', 'right')}
    buttons = {name: SdkDigitalIO(name) for name in
               ('left_lower_button', 'left_upper_button', 'right_lower_button', 'right_upper_button')}
    target = dict(zip(limbs['right'].joint_names(), [0.3, -0.4, 0.2, 1.0, -0.2, 0.9, 0.3]))
    path = tmp_path / 'recording.csv'
    # the lower button held 1.8 s: the gripper opens in ~0.5 s, and under load the state this client reads lags
    # (0.8 s once left it at 64 % open in the recording)
    press('right_upper_button', False)      # connects the hand before the clock starts (a no-op press)
    rate, start, presses = rospy.Rate(20), rospy.get_time(), [(0.2, 'right_lower_button', True),
                                                               (2.0, 'right_lower_button', False),
                                                               (2.0, 'right_upper_button', True)]
    with open(path, 'w') as f:
        f.write('time,' + ','.join(limbs['left'].joint_names()) + ',left_gripper,'
                + ','.join(limbs['right'].joint_names()) + ',right_gripper\n')
        while rospy.get_time() - start < 6.0:     # 4 s after the close: the gripper state this client reads lags
            while presses and rospy.get_time() - start > presses[0][0]:     # the person's hand on the cuff
                press(*presses.pop(0)[1:])
            if buttons['right_lower_button'].state:
                grippers['right'].open()
            elif buttons['right_upper_button'].state:
                grippers['right'].close()
            limbs['right'].set_joint_positions(target)           # the person guiding the arm
            row = [rospy.get_time() - start]
            for side in ('left', 'right'):
                row += [limbs[side].joint_angle(j) for j in limbs[side].joint_names()] + [grippers[side].position()]
            f.write(','.join(f'{v:f}' for v in row) + '\n')
            rate.sleep()
    press('right_upper_button', False)
    rows = np.loadtxt(path, delimiter=',', skiprows=1)
    # the upper button's release (just above) may or may not have arrived yet
    assert buttons['right_lower_button'].changes == [True, False] and buttons['right_upper_button'].changes[:1] == [True]
    assert rows[:, 16].max() > 90.0 and rows[-1, 16] < 10.0          # right gripper: opened, then closed (buttons)
    assert np.abs(rows[-1, 9:16] - rows[0, 9:16]).max() > 0.3       # the right arm moved
    for side, columns in (('left', slice(1, 8)), ('right', slice(9, 16))):   # playback: first row
        limbs[side].move_to_joint_positions(dict(zip(limbs[side].joint_names(), rows[0, columns])))
    grippers['right'].open(block=True)
    start = rospy.get_time()
    for row in rows:
        for side, columns, gripper_column in (('left', slice(1, 8), 8), ('right', slice(9, 16), 16)):
            limbs[side].set_joint_positions(dict(zip(limbs[side].joint_names(), row[columns])))
            grippers[side].command_position(row[gripper_column])
        while rospy.get_time() - start < row[0]:
            rospy.sleep(0.01)
    limbs['right'].move_to_joint_positions(dict(zip(limbs['right'].joint_names(), rows[-1, 9:16])), timeout=5.0)
    wait_for(lambda: grippers['right'].position() < 10.0, timeout=3.0)
    robot.disable()


def test_head_wobbler_and_the_head_camera_pans_with_the_head(fake, keeps_real_time):
    """head_wobbler.py (Head, RobotEnable, enable; set_pan(0.0); command_nod; pans to angles in [-1.5, 1.5] at speed
    0.3, timeout 0, 100 Hz until within HEAD_PAN_ANGLE_TOLERANCE) and the Head smoke test's set_pan waits; the pan
    speed follows the ratio, the head camera turns with the head, a disabled robot's head does not pan."""
    head = SdkHead()
    robot = SdkRobotEnable()
    robot.enable()
    head.set_pan(0.0)
    head.command_nod()
    open_camera('head_camera')
    frame_ahead = msg_to_bgr(rospy.wait_for_message('/cameras/head_camera/image', Image, 5.0)).astype(float)
    rate, turning_seen = rospy.Rate(100), False
    for angle in (1.5, -0.5):
        start, start_pan = rospy.get_time(), head.pan()
        while abs(head.pan() - angle) > HEAD_PAN_ANGLE_TOLERANCE:
            assert rospy.get_time() - start < 15.0, f'the head did not reach {angle}'
            head.set_pan(angle, speed=0.3, timeout=0)
            turning_seen = turning_seen or head.panning()
            rate.sleep()
        speed = abs(head.pan() - start_pan) / (rospy.get_time() - start)
        assert speed == pytest.approx(0.3 * 1.5, rel=0.25)              # speed ratio x 1.5 rad/s (rad/s)
    assert turning_seen
    head.set_pan(-0.5, 1.0)                                               # settle on the target
    frame_turned = msg_to_bgr(rospy.wait_for_message('/cameras/head_camera/image', Image, 5.0)).astype(float)
    assert np.abs(frame_turned - frame_ahead).mean() > 5.0               # grey levels: another view
    assert rospy.ServiceProxy('/cameras/close', srv.CloseCamera)('head_camera').err == 0
    robot.disable()
    pan = head.pan()
    for _ in range(50):
        head.set_pan(0.5, 1.0, timeout=0)
        rospy.sleep(0.01)
    assert head.pan() == pytest.approx(pan, abs=0.01)                     # disabled: the head holds


def open_camera(name, width=640, height=400):
    """baxter_interface.CameraController(name).open() after close(), as camera_control.py -o."""
    rospy.ServiceProxy('/cameras/close', srv.CloseCamera)(name)
    settings = msg.CameraSettings(width=width, height=height, fps=20)
    assert rospy.ServiceProxy('/cameras/open', srv.OpenCamera)(name, settings).err == 0


def test_camera_control_lists_only_open_cameras_and_the_right_camera_sees_from_the_right_hand(fake):
    """camera_control.py -o / -l / -c / -e: a camera's image topic is published only while it is open (-l after a
    close shows it closed; -e, /cameras/reset, closes every camera); the right hand camera renders its own view."""
    assert rospy.ServiceProxy('/cameras/list', srv.ListCameras)().cameras == ['left_hand_camera', 'right_hand_camera',
                                                                             'head_camera']
    assert not any(camera_listed_open(name) for name in ('left_hand_camera', 'right_hand_camera', 'head_camera'))
    for name in ('left_hand_camera', 'right_hand_camera'):
        open_camera(name)
        assert camera_listed_open(name)
    images = {name: msg_to_bgr(rospy.wait_for_message(f'/cameras/{name}/image', Image, 5.0)).astype(float)
              for name in ('left_hand_camera', 'right_hand_camera')}
    assert np.abs(images['left_hand_camera'] - images['right_hand_camera']).mean() > 5.0   # two views (grey levels)
    assert rospy.ServiceProxy('/cameras/close', srv.CloseCamera)('right_hand_camera').err == 0
    assert not camera_listed_open('right_hand_camera') and camera_listed_open('left_hand_camera')
    rospy.wait_for_service('cameras/reset', timeout=10)
    rospy.ServiceProxy('cameras/reset', EmptyService)()
    assert not camera_listed_open('left_hand_camera')
    assert rospy.ServiceProxy('/cameras/close', srv.CloseCamera)('left_hand_camera').err == errno.EINVAL


def test_io_cuffs_navigators_lights_and_analog_as_the_examples_and_smoke_tests(fake):
    """joint_trajectory_action_server.py (the cuffs' DigitalIO: a squeeze is seen), joint_position_waypoints.py (the
    Navigator: its state, lights, a press of the OK button), the BlinkLEDs smoke test (every navigator light toggled
    with set_output's wait), analog_io_rampup.py (torso_fan ramped with set_output's wait) and the hand range sensor's
    analog input (mm)."""
    cuffs = {side: SdkDigitalIO(f'{side}_lower_cuff') for side in ('left', 'right')}
    assert not any(cuff.state or cuff.is_output for cuff in cuffs.values())
    press('left_lower_cuff')
    wait_for(lambda: cuffs['left'].state, timeout=2.0)
    press('left_lower_cuff', False)
    wait_for(lambda: cuffs['left'].changes == [True, False], timeout=2.0)
    assert cuffs['right'].changes == []
    with pytest.raises(IOError):
        cuffs['right'].set_output(True)
    navigator = SdkNavigator('left')
    press('left_button_ok')
    wait_for(lambda: navigator.button0, timeout=2.0)
    press('left_button_ok', False)
    wait_for(lambda: not navigator.button0, timeout=2.0)
    assert navigator.button0_presses == 1
    wheel = rospy.Publisher('/fake_baxter/set_analog_input', msg.AnalogOutputCommand, queue_size=10)
    wait_for(lambda: wheel.get_num_connections() > 0, timeout=5.0)
    wheel.publish(msg.AnalogOutputCommand(name='left_wheel', value=42))
    wait_for(lambda: navigator.wheel == 42, timeout=2.0)
    for location in ('left', 'torso_left', 'right', 'torso_right'):       # BlinkLEDs
        for light in ('outer', 'inner'):
            io = SdkDigitalIO(f'{location}_{light}_light')
            assert io.is_output
            for i in range(9):
                io.set_output(i % 2)
                rospy.sleep(0.1)
    navigator.inner_light.set_output(True)
    wait_for(lambda: navigator.lights == {'inner': True, 'outer': False}, timeout=2.0)
    fan = SdkAnalogIO('torso_fan')                                        # analog_io_rampup.py (steps of 50)
    assert fan.state() == 0.0
    for value in (0, 50, 100, 50, 0):
        fan.set_output(value)
    hand_range = SdkAnalogIO('left_hand_range')
    distance_m = rospy.wait_for_message('/robot/range/left_hand_range/state', Range, 5.0).range
    expected_mm = distance_m * 1000.0 if math.isfinite(distance_m) else 65535.0
    wait_for(lambda: abs(hand_range.state() - expected_mm) < 5.0, timeout=2.0)

