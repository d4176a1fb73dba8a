"""The fake Baxter node against a real rosmaster, through ROS only: start-up, time, robot state, arm, IK.

One node (``--enable``, real time) serves most tests; a first one boots with a camera open, as fast as the
CPU allows, to measure the image rate and the real-time factor with and without a camera. All times are
simulated seconds (header stamps, or this process's ``rospy.get_time()`` which follows ``/clock``) unless a
name says ``wall``; wall timeouts only bound the waiting. Timings are measured on the stamps of the fake's own
messages. The end effector and the sensors (gripper, cameras, range sensor): ``test_fake_baxter_devices.py``.
"""
import math
import os
import struct
import time

import numpy as np
import pytest
import rospy
from geometry_msgs.msg import PoseStamped
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import CameraInfo, Image, JointState
from std_msgs.msg import Bool, Empty, Float64
from tf2_msgs.msg import TFMessage

from baxter_pnp.camera import CameraModel, load_default_camera
from baxter_pnp.kinematics import load_start_poses
from baxter_pnp.msgs import msg, srv
from baxter_pnp.ros_image import msg_to_bgr
from baxter_pnp.sim.clock import RateSchedule, RealTimePacer
from baxter_pnp.sim.arm import ik_stages, parse_joint_command
from baxter_pnp.sim.launcher import harness_clock
from baxter_pnp.transforms import (from_xyz_quat, invert, matrix_to_pose_msg, pose_msg_to_matrix,
                                   rotation_angle_between)
import fake_baxter_client
from fake_baxter_client import (LEFT, STEP, Recorder, edge, joint_angles, joint_velocity, publish_until,
                                published_rate_hz, rate_hz, sim_sleep)
from ros_graph import FakeBaxterProcess

pytestmark = pytest.mark.timeout(300)
kin, scene, robot = fake_baxter_client.kin, fake_baxter_client.scene, fake_baxter_client.robot   # fixtures


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


# ============================================================================ start-up
def test_bad_scene_is_a_clear_error_with_exit_code_2(tmp_path):
    bad = tmp_path / 'bad.yaml'
    bad.write_text('objects:\n  - {shape: square, side: -0.04, color: [0, 1, 0], xy: [0.7, 0.2]}\n')
    process = FakeBaxterProcess(['--scene', str(bad)], log_path=tmp_path / 'bad.log')
    assert process.run_to_exit() == 2
    assert 'objects[0].side' in process.log()


# README "Fake Baxter" gives these. Measured on the 2-core machine (2026-11), in simulated seconds per CPU second of
# the fake (all its threads: the real-time factor it reaches with the CPU it gets; other processes' load takes
# cores away, which this does not count): 2.6-3.7 without a camera, 1.5-2.4 with one (angled start pose, OpenGL
# through EGL, the noise bank); per wall second 1.9-3.6 and 1.3-2.4. PyBullet's TinyRenderer gave 0.41-0.46 with a
# camera. Asserted per CPU second: above a third without a camera, above two thirds with one (a frame rendered
# twice, or by TinyRenderer), and a camera costs CPU (a frame skipped would not).
SIM_PER_CPU_SECOND_NO_CAMERA = 3.0
SIM_PER_CPU_SECOND_CAMERA = 1.1


def process_cpu_seconds(pid):
    """User + system CPU seconds used so far by process ``pid``, all its threads (Linux /proc)."""
    with open(f'/proc/{pid}/stat') as f:
        fields = f.read().rsplit(')', 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf('SC_CLK_TCK')


def measure_real_time_factor(clock, pid, simulated_seconds, wall_timeout=60.0):
    """(simulated s per wall s, simulated s per CPU s of process ``pid``) while /clock advances
    ``simulated_seconds``."""
    start_cpu, (start_wall, start) = process_cpu_seconds(pid), clock.messages[-1]
    clock.wait_for(lambda m: (m.clock - start.clock).to_sec() >= simulated_seconds, wall_timeout)
    end_cpu, (end_wall, end) = process_cpu_seconds(pid), clock.messages[-1]
    simulated = end.clock.to_sec() - start.clock.to_sec()
    return simulated / (end_wall - start_wall), simulated / (end_cpu - start_cpu)


@pytest.mark.skipif(harness_clock() == 'wall', reason='measures the unpaced fake on /clock: the sim clock only')
def test_camera_opened_at_boot_publishes_at_its_fps_and_the_fake_runs_at_its_measured_speed(ros_node, fake_baxter,
                                                                                            record_property):
    """The camera opened at boot streams 640x400 at 20 fps (stamps); the simulated seconds the fake computes per
    CPU second it uses, with that camera and without one (closed), are near the re-measured ones (bounds below).
    The wall-clock factors depend on the machine's load: recorded, not asserted."""
    process = fake_baxter('--open-camera', 'left_hand_camera:640x400@20', '--real-time-factor', '0',
                          '--image-encoding', 'rgb8', '--start-pose', 'angled')
    joints = rospy.wait_for_message('/robot/joint_states', JointState, timeout=5.0)
    angled = load_start_poses()['angled']
    np.testing.assert_allclose(joint_angles(joints), [angled[n] for n in LEFT], atol=0.01)
    images = Recorder('/cameras/left_hand_camera/image', Image, keep=200)
    infos = Recorder('/cameras/left_hand_camera/camera_info', CameraInfo, keep=200)
    clock = Recorder('/clock', Clock, keep=10)
    try:
        images.latest(timeout=10.0)
        clock.latest()
        with_camera, with_camera_cpu = measure_real_time_factor(clock, process.process.pid, 2.0)
        received = [m for _, m in images.messages]
        image = images.latest()
        info = infos.latest()
        assert rospy.ServiceProxy('/cameras/close', srv.CloseCamera)('left_hand_camera').err == 0
        time.sleep(0.2)
        without_camera, without_camera_cpu = measure_real_time_factor(clock, process.process.pid, 2.0)
    finally:
        for recorder in (images, infos, clock):
            recorder.close()
        process.stop()
    record_property('real_time_factor_640x400_20fps', with_camera)
    record_property('real_time_factor_no_camera', without_camera)
    print(f'\nreal-time factor: {with_camera:.2f} with left_hand_camera 640x400 @ 20 fps, {without_camera:.2f} '
          f'without a camera; per CPU second of the fake: {with_camera_cpu:.2f} and {without_camera_cpu:.2f}')
    assert SIM_PER_CPU_SECOND_CAMERA * 2 / 3 < with_camera_cpu < without_camera_cpu    # frames cost CPU
    assert SIM_PER_CPU_SECOND_NO_CAMERA / 3 < without_camera_cpu
    assert published_rate_hz(received) == pytest.approx(20.0, rel=0.10)
    assert rate_hz([m.header.stamp.to_sec() for m in received]) == pytest.approx(20.0, rel=0.10)
    assert len(received) >= 10
    # as a real Baxter's hand camera at 640x400: frame_id with a leading /, the full-sensor K (1280x800), the window
    # as roi, P for the delivered image; read as image_geometry reads it: the thesis calibration cropped
    assert (image.width, image.height, image.encoding, image.header.frame_id) == (640, 400, 'rgb8', '/left_hand_camera')
    assert msg_to_bgr(image).shape == (400, 640, 3)
    assert info.header.frame_id == '/left_hand_camera' and (info.width, info.height) == (640, 400)
    assert (info.roi.x_offset, info.roi.y_offset, info.roi.width, info.roi.height) == (320, 200, 640, 400)
    assert info.binning_x in (0, 1) and info.binning_y in (0, 1)
    expected = load_default_camera().scaled(640, 400)
    np.testing.assert_allclose([info.K[2], info.K[5]], [expected.cx + 320, expected.cy + 200])
    np.testing.assert_allclose([info.P[0], info.P[2], info.P[5], info.P[6]],
                               [expected.fx, expected.cx, expected.fy, expected.cy])
    published = CameraModel.from_camera_info(info)
    assert (published.width, published.height, published.frame_id) == (640, 400, 'left_hand_camera')
    np.testing.assert_allclose(published.K, expected.K)
    np.testing.assert_allclose(published.D, expected.D)


def test_boot_is_fast_and_announced(robot):
    assert robot.process.boot_seconds < 5.0
    assert 'fake_baxter ready' in robot.process.log()
    assert rospy.get_param('/rethink/software_version') == '1.2.0.57'     # a four-part build string, as a robot's
    assert rospy.get_param('/use_sim_time', False) is (harness_clock() == 'sim')   # the real robot does not set it
    assert ('clock sim (/clock)' if harness_clock() == 'sim' else 'clock wall (no /clock)') in robot.process.log()
    assert '<robot' in rospy.get_param('/robot_description')


# ============================================================================ state topics
def test_state_topics_rates_and_content(robot, kin, keeps_real_time):
    for recorder in (robot.joint_states, robot.endpoint, robot.state, robot.gripper_state):
        recorder.clear()
    sim_sleep(2.0)
    joint_states = robot.joint_states.messages
    rates = [published_rate_hz([m for _, m in joint_states]),
             published_rate_hz([m for _, m in robot.endpoint.messages]),
             rate_hz([m.timestamp.to_sec() for _, m in robot.gripper_state.messages])]
    assert rates == pytest.approx([100.0] * 3, rel=0.10)     # README: within 10 % in simulated time
    # AssemblyState has no stamp: count the ones that arrived between two joint_states messages. This process's
    # delivery of the two streams can drift apart by ~0.25 s over the 2 s window when the machine
    # is loaded (measured 88 Hz once with three other ROS test runs), hence 20 % for this estimate.
    (first_arrival, first), (last_arrival, last) = joint_states[0], joint_states[-1]
    states = [t for t, _ in robot.state.messages if first_arrival <= t <= last_arrival]
    assert len(states) / (last.header.stamp - first.header.stamp).to_sec() == pytest.approx(100.0, rel=0.2)

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


def test_velocity_mode_follows_and_times_out_to_holding(robot, keeps_real_time):
    """VELOCITY_MODE is followed, in order, and the arm holds ``joint_command_timeout`` simulated s after the last
    command took effect, within a step. On the fake's clock (joint_states stamps): every command of the stream
    asks for a slightly different velocity, so the states bracket when the last one took effect and when the arm
    stopped (``edge``)."""
    w2 = LEFT.index('left_w2')
    for timeout, velocity in ((None, 0.5), (0.6, -0.5)):     # None: the robot's default, 0.2 s
        if timeout is not None:
            robot.command_timeout.publish(Float64(timeout))
            sim_sleep(0.05)
        timeout = timeout or 0.2
        robot.joint_states.clear()
        end, last = rospy.get_time() + 0.4, 0
        while rospy.get_time() < end:
            last += 1
            robot.joint_command.publish(msg.JointCommand(mode=2, names=['left_w2'],
                                                         command=[velocity * (1 + 1e-4 * last)]))
            time.sleep(0.005)
        robot.joint_states.wait_for(lambda m: m.header.stamp.to_sec() > end + timeout + 0.1)
        states = [m for _, m in robot.joint_states.messages]

        def command_seen(message):
            """Which command of the stream (1..last) a state's velocity shows; 0 when still."""
            seen_velocity = joint_velocity(message, 'left_w2')
            return round((seen_velocity / velocity - 1) / 1e-4) if seen_velocity / velocity > 0.5 else 0
        seen = [command_seen(m) for m in states if command_seen(m)]
        print(f'\n{len(set(seen))} of {last} commands seen, {seen[:3]}...{seen[-3:]}')
        assert seen == sorted(seen) and seen[-1] == last                # in order, the last one too
        applied = edge(states, lambda m: command_seen(m) == last)
        stopped = edge(states, lambda m: command_seen(m) == 0, after=applied[1])
        print(f'the last command took effect in [{applied[0]:.4f}, {applied[1]:.4f}) s, the arm stopped in '
              f'[{stopped[0]:.4f}, {stopped[1]:.4f}) s (timeout {timeout} s)')
        # held in the first step more than the timeout after the command took effect
        assert stopped[1] - applied[0] > timeout and stopped[0] - applied[1] < timeout + STEP
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
