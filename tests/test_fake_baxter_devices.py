"""The fake Baxter's end effector and sensors against a real rosmaster, through ROS only: the electric gripper's
protocol, the hand cameras, the IR range sensor, and a block picked up through ROS.

One node (``--enable``, real time). Times are simulated seconds (the stamps of the fake's messages, or this
process's ``rospy.get_time()`` which follows ``/clock``); wall timeouts only bound the waiting. Ground truth
comes from ``/fake_baxter/object_poses`` and the forward kinematics of ``ArmKinematics`` on the published joint
angles. Start-up, time, robot state, arm and IK: ``test_fake_baxter.py``.
"""
import argparse
import errno
import math
import time

import cv2
import numpy as np
import pytest
import rospy
from sensor_msgs.msg import CameraInfo, Image, Range
from std_msgs.msg import Float64

from baxter_pnp.camera import CameraModel
from baxter_pnp.models import model_for
from baxter_pnp.msgs import msg, srv
from baxter_pnp.robot.sdk import GRIPPER_PARAMETERS
from baxter_pnp.ros_image import msg_to_bgr
from baxter_pnp.sim.cameras import (RESOLUTION_HALF_CONTROL, camera_settings_problem, control_brightness,
                                    parse_camera_option)
from baxter_pnp.sim.world import FINGER_TRAVEL, GRIPPER_MAX_SPEED
from baxter_pnp.transforms import invert, make_transform
import fake_baxter_client
from fake_baxter_client import GRIPPER, Recorder, gripper_down, sim_sleep

pytestmark = pytest.mark.timeout(300)
kin, scene, robot = fake_baxter_client.kin, fake_baxter_client.scene, fake_baxter_client.robot   # fixtures

MODES = [(1280, 800), (960, 600), (640, 400), (480, 300), (384, 240), (320, 200)]


def green_mask(image_bgr):
    """The green block's pixels, by hue and saturation (the default look is dim and vignetted)."""
    hsv = cv2.cvtColor(image_bgr, cv2.COLOR_BGR2HSV)
    return ((hsv[..., 0] > 45) & (hsv[..., 0] < 75) & (hsv[..., 1] > 120) & (hsv[..., 2] > 40)).astype(np.uint8)


# ============================================================================ pure parts (no ROS graph)
def test_camera_settings_and_option():
    assert camera_settings_problem('left_hand_camera', 1280, 800, 30.0) is None
    assert camera_settings_problem('left_hand_camera', 800, 800, 30.0)[0] == errno.EINVAL
    assert camera_settings_problem('left_hand_camera', 640, 400, 0.0)[0] == errno.EINVAL
    assert camera_settings_problem('torso_camera', 640, 400, 20.0)[0] == errno.ENODEV
    assert camera_settings_problem('left_hand_camera', 640, 400, 20.0, half_resolution=True) is None
    assert camera_settings_problem('left_hand_camera', 960, 600, 20.0, half_resolution=True)[0] == errno.EINVAL
    assert parse_camera_option('head_camera:320x200') == ('head_camera', 320, 200, 20.0)
    assert parse_camera_option('left_hand_camera:640x400@12.5') == ('left_hand_camera', 640, 400, 12.5)
    for bad in ('left_hand_camera', 'left_hand_camera:640x480@20', 'left_hand_camera:640x400@0'):
        with pytest.raises(argparse.ArgumentTypeError):
            parse_camera_option(bad)


def test_exposure_and_gain_controls_scale_the_brightness():
    """The fake's model of baxter_interface's exposure (0-100) and gain (0-79) controls: automatic (-1) or absent
    = 1; exposure / 50; x (1 + gain / 16); other controls ignored; out of range refused."""
    assert control_brightness([]) == control_brightness([(100, -1), (101, -1), (RESOLUTION_HALF_CONTROL, 1)]) == 1.0
    assert control_brightness([(100, 25)]) == pytest.approx(0.5)
    assert control_brightness([(100, 100), (101, 16)]) == pytest.approx(4.0)
    for bad in ([(100, 101)], [(101, 80)], [(100, -2)]):
        with pytest.raises(ValueError, match='exposure|gain'):
            control_brightness(bad)


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


def _frame_and_info(images, infos, width, binning, since, timeout):
    """The newest image of ``width`` px stamped at or after ``since`` (s) with the camera_info of the same stamp and
    ``binning``. A reopened camera advertises its topics anew and the two subscribers reconnect one after the other,
    so the first frames of a mode may come without their camera_info (or the reverse); and a frame of the previous
    mode, of the same width unbinned (320x200 before the binned 320x200), may still come after ``since``."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        stamps = {m.header.stamp: m for _, m in infos.messages if m.width == width and m.binning_x == binning}
        for _, image in reversed(images.messages):
            if image.width == width and image.header.stamp.to_sec() >= since and image.header.stamp in stamps:
                return image, stamps[image.header.stamp]
        time.sleep(0.005)
    raise AssertionError(f'no {width} px image with its camera_info (binning {binning}) within {timeout} s')


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
        for width, height, binning in [(w, h, 1) for w, h in MODES] + [(640, 400, 2), (320, 200, 2)]:
            opened_at = rospy.get_time()
            controls = [msg.CameraControl(id=RESOLUTION_HALF_CONTROL, value=1)] if binning == 2 else []
            settings = msg.CameraSettings(width=width, height=height, fps=10.0, controls=controls)
            assert open_camera('left_hand_camera', settings).err == 0
            image, info = _frame_and_info(images, infos, width, binning, opened_at, 20.0)
            assert (image.height, image.encoding, info.height) == (height, 'bgra8', height)
            # the mode's centred window of the 1280x800 sensor as roi, binned 2x2 at half resolution
            roi = (info.roi.x_offset, info.roi.y_offset, info.roi.width, info.roi.height)
            assert roi == ((1280 - binning * width) // 2, (800 - binning * height) // 2, binning * width,
                           binning * height) and info.binning_x == info.binning_y == binning, (width, roi)
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


def test_a_camera_opened_with_an_exposure_sends_darker_frames(robot):
    """Exposure 25 (the fake's automatic one amounts to 50) halves the frames' grey levels; exposure 101 or gain 80
    are refused (EINVAL) and leave the camera as it was."""
    open_camera = rospy.ServiceProxy('/cameras/open', srv.OpenCamera)
    close_camera = rospy.ServiceProxy('/cameras/close', srv.CloseCamera)
    images = Recorder('/cameras/left_hand_camera/image', Image, keep=20)
    infos = Recorder('/cameras/left_hand_camera/camera_info', CameraInfo, keep=20)

    def mean_grey(*controls):
        opened_at = rospy.get_time()
        settings = msg.CameraSettings(width=320, height=200, fps=10.0,
                                      controls=[msg.CameraControl(id=i, value=v) for i, v in controls])
        assert open_camera('left_hand_camera', settings).err == 0
        sim_sleep(0.3)          # past the frames rendered before the new settings
        image, _ = _frame_and_info(images, infos, 320, 1, opened_at + 0.25, 20.0)
        return float(msg_to_bgr(image).mean())
    try:
        automatic, darker = mean_grey(), mean_grey((100, 25))
        assert darker / automatic == pytest.approx(0.5, abs=0.05), (automatic, darker)
        for control in ((100, 101), (101, 80)):
            settings = msg.CameraSettings(width=320, height=200, fps=10.0, controls=[msg.CameraControl(*control)])
            assert open_camera('left_hand_camera', settings).err == errno.EINVAL
    finally:
        images.close()
        infos.close()
        close_camera('left_hand_camera')


# ============================================================================ range sensor
RANGE_TOPIC = '/robot/range/left_hand_range/state'


def test_range_sensor_reads_inf_beyond_its_range_and_the_table_within_it(robot, kin, scene):
    """REP 117 ``inf`` when the table lies beyond ``max_range`` (the 'down' start pose: about 0.42 m away), else
    the distance (m) along the sensor's +x axis to the table, against forward kinematics at the published angles
    (the arm holds still; the fake's ray test is exact, 1 mm covers the angles' noise over that lever arm)."""
    def reading_and_distance_to_table():
        sim_sleep(0.05)
        message = rospy.wait_for_message(RANGE_TOPIC, Range, timeout=5.0)
        T_base_range = kin.fk(robot.angles(), 'left_hand_range')
        origin, direction = T_base_range[:3, 3], T_base_range[:3, 0]
        assert direction[2] < -0.9                        # looking down at the table
        return message, (scene.table.top_z - origin[2]) / direction[2]

    message, to_table = reading_and_distance_to_table()
    assert (message.min_range, message.max_range) == pytest.approx((0.004, 0.4))
    assert message.header.frame_id == 'left_hand_range' and message.radiation_type == Range.INFRARED
    assert to_table > message.max_range and message.range == math.inf
    # The gripper tip 15 cm above an empty part of the table (the block is at (0.70, 0.25)), at full speed.
    robot.speed_ratio.publish(Float64(1.0))
    sim_sleep(0.05)
    robot.move_to(robot.solve_ik(gripper_down([0.60, -0.05, scene.table.top_z + 0.15], 0.0)))
    robot.speed_ratio.publish(Float64(0.3))
    message, to_table = reading_and_distance_to_table()
    print(f'\nrange {message.range:.4f} m, table at {to_table:.4f} m along the sensor axis')
    assert message.min_range < to_table < message.max_range
    assert message.range == pytest.approx(to_table, abs=0.001)


# ============================================================================ gripper
# Parameters unlike baxter_interface's defaults (GRIPPER_PARAMETERS), so that a configure that did nothing shows.
SLOW_GRIPPER = {'velocity': 25.0, 'moving_force': 60.0, 'holding_force': 20.0, 'dead_zone': 3.0}


def configure_args(parameters):
    return '{%s}' % ', '.join(f'"{key}": {value}' for key, value in parameters.items())


def test_gripper_protocol_over_ros(robot, keeps_real_time):
    """Properties, acknowledgements, calibration, and ``configure``: the fingers close at the configured velocity
    (percent of GRIPPER_MAX_SPEED per finger), measured on the gripper states' stamps."""
    assert all(SLOW_GRIPPER[key] != GRIPPER_PARAMETERS[key] for key in GRIPPER_PARAMETERS)
    properties = rospy.wait_for_message(f'{GRIPPER}/properties', msg.EndEffectorProperties, timeout=5.0)
    state = robot.gripper_state.latest()
    assert properties.ui_type == 2 and properties.id == state.id
    assert properties.firmware_date == '2014/7/24 18:30:00'
    acknowledged, _ = robot.gripper('configure', configure_args(SLOW_GRIPPER))
    assert acknowledged < 0.5
    assert robot.gripper_state.latest().calibrated == 0        # boots uncalibrated, like the real gripper
    acknowledged, done = robot.calibrate_gripper()
    assert acknowledged < 0.5 and done < 5.0
    for position in (100.0, 0.0):
        robot.gripper_state.clear()
        acknowledged, done = robot.gripper(
            'go', '{"position": %.1f}' % position,
            test=lambda s: abs(s.position - position) < 5.0 or s.gripping == 1)
        assert acknowledged < 0.5 and done < 5.0
    closed_at = rospy.get_time()
    final = robot.gripper_state.wait_for(lambda s: s.timestamp.to_sec() >= closed_at and s.moving == 0)
    assert final.missed == 1 and final.gripping == 0          # closed on nothing
    closing = [(s.timestamp.to_sec(), s.position) for _, s in robot.gripper_state.messages if 15 < s.position < 85]
    speed = -np.polyfit(*np.array(closing).T, 1)[0]            # percent of the travel per simulated second
    expected = SLOW_GRIPPER['velocity'] / 100 * GRIPPER_MAX_SPEED / FINGER_TRAVEL * 100
    print(f'\nthe fingers closed at {speed:.1f} %/s ({expected:.1f} %/s configured, {2 * expected:.1f} by default)')
    assert speed == pytest.approx(expected, rel=0.05)          # the motors reach their speed limit in a few steps
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
    """Down around the block, close with a configured force, lift 10 cm: the ground truth follows."""
    obj = scene.objects[0]
    T_block = robot.block_pose(0)
    T_grasp = gripper_down(T_block[:3, 3] + [0.0, 0.0, -0.012], math.atan2(T_block[1, 0], T_block[0, 0]))
    above = make_transform(None, [0.0, 0.0, 0.10])
    squeeze = dict(GRIPPER_PARAMETERS, moving_force=60.0)      # percent of GRIPPER_MAX_FORCE (default 40)

    robot.calibrate_gripper()
    robot.gripper('go', '{"position": 100.0}', test=lambda s: s.position > 95.0)
    robot.move_to(robot.solve_ik(above @ T_grasp))
    sim_sleep(0.05)
    reading = rospy.wait_for_message('/robot/range/left_hand_range/state', Range, timeout=5.0).range
    expected = _expected_ranges(kin.fk(robot.angles(), 'left_hand_range'), scene.table.top_z, T_block,
                                model_for(obj.shape, obj.side, obj.height))
    assert any(abs(reading - distance) < 0.005 for distance in expected), (reading, expected)
    robot.move_to(robot.solve_ik(T_grasp, seed_mode=2))
    robot.gripper('configure', configure_args(squeeze))
    robot.gripper('go', '{"position": 0.0}', test=lambda s: s.gripping == 1 or (s.moving == 0 and s.position < 5))
    closed_at = rospy.get_time()
    state = robot.gripper_state.wait_for(lambda s: s.timestamp.to_sec() >= closed_at and s.moving == 0)
    assert state.gripping == 1 and state.missed == 0
    assert state.position == pytest.approx(100.0 * (obj.side - 0.016) / 2 / FINGER_TRAVEL, abs=8.0)
    print(f'\nsqueezing the block with {state.force:.1f} % of the maximum force '
          f'({squeeze["moving_force"]:g} % configured)')
    assert state.force == pytest.approx(squeeze["moving_force"], rel=0.1)   # contact force jitters (test_world: 10 %)
    z_before = robot.block_pose(0)[2, 3]
    robot.move_to(robot.solve_ik(above @ T_grasp, seed_mode=2))
    sim_sleep(0.5)
    lifted = robot.block_pose(0)[2, 3] - z_before
    assert lifted == pytest.approx(0.10, abs=0.01)
    assert robot.gripper_state.latest().gripping == 1
    robot.gripper('go', '{"position": 100.0}', test=lambda s: s.position > 95.0)
