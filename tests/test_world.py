"""SimWorld: arm motion, physical grasping, gripper state, camera rendering, range sensor, ground truth, chessboard."""
import dataclasses
import os

import cv2
import numpy as np
import pybullet as p
import pytest
from scipy.spatial.transform import Rotation

from baxter_pnp.calibration import board_object_points, find_board_corners
from baxter_pnp.camera import CameraModel, load_default_camera
from baxter_pnp.kinematics import ArmKinematics
from baxter_pnp.models import model_for
from baxter_pnp.kinematics import load_start_poses
from baxter_pnp.perception import observe_blocks
from baxter_pnp.runtime import PACKAGE_ROOT
from baxter_pnp.sim import appearance
from baxter_pnp.sim.appearance import AppearanceConfig
from baxter_pnp.sim.cameras import sensor_model, sensor_window
from baxter_pnp.sim.render import RendererUnavailable
from baxter_pnp.sim.scene import CameraError, Scene, load_scene
from baxter_pnp.sim.world import SimWorld
from baxter_pnp.transforms import invert, make_transform, transform_points
from baxter_pnp.vision import VisionConfig

SCENES = os.path.join(PACKAGE_ROOT, 'config', 'scenes')
LEFT = ['left_s0', 'left_s1', 'left_e0', 'left_e1', 'left_w0', 'left_w1', 'left_w2']
VELOCITY_LIMITS = np.array([1.5, 1.5, 1.5, 1.5, 4.0, 4.0, 4.0])


@pytest.fixture(scope='module')
def kinematics():
    k = ArmKinematics('left')
    yield k
    k.close()


@pytest.fixture
def world():
    w = SimWorld(load_scene())
    yield w
    w.close()


@pytest.fixture(scope='module')
def camera():
    return load_default_camera().scaled(640, 400)


def left_angles(world):
    positions, _, _ = world.joint_state()
    names = world.joint_names()
    return np.array([positions[names.index(n)] for n in LEFT])


def left_velocities(world):
    _, velocities, _ = world.joint_state()
    names = world.joint_names()
    return np.array([velocities[names.index(n)] for n in LEFT])


def gripper_down(xyz, yaw):
    """T_base_gripper pointing straight down (hand z = -base z), fingers closing along the yawed base y."""
    return make_transform(Rotation.from_euler('z', yaw) * Rotation.from_euler('y', np.pi), xyz)


def move_gripper(world, kinematics, T, speed_ratio=0.5, timeout=5.0):
    """Command the IK solution of T and step until the arm is there (within 1 mrad) or the timeout."""
    q = kinematics.ik(T, seed=left_angles(world))
    assert q is not None
    world.command_arm_positions('left', dict(zip(LEFT, q)), speed_ratio)
    for _ in range(int(timeout / world.time_step)):
        world.step()
        if np.max(np.abs(left_angles(world) - q)) < 1e-3:
            return
    raise AssertionError('arm did not reach the IK target')


CLEAN = appearance.preset_look('clean')      # block_mask's thresholds: a saturated block in full light


def block_mask(image):
    """Boolean mask of the lit green top face of a block (``appearance: clean``)."""
    hsv = cv2.cvtColor(image, cv2.COLOR_BGR2HSV)
    return (hsv[:, :, 0] > 45) & (hsv[:, :, 0] < 75) & (hsv[:, :, 1] > 100) & (hsv[:, :, 2] > 150)


# ------------------------------------------------------------------------------------------------ joints
def test_joint_names_and_start_pose(world):
    names = world.joint_names()
    assert len(names) == 19 and names[0] == 'head_pan'
    assert names[1:3] == ['l_gripper_l_finger_joint', 'l_gripper_r_finger_joint'] and names[3:10] == LEFT
    positions, velocities, efforts = world.joint_state()
    assert positions.shape == velocities.shape == efforts.shape == (19,)
    np.testing.assert_allclose(left_angles(world), list(load_start_poses()['down'].values()), atol=1e-9)
    world.step(240)   # the start pose holds under gravity
    np.testing.assert_allclose(left_angles(world), list(load_start_poses()['down'].values()), atol=1e-3)


def test_position_command_is_velocity_limited_and_arrives(world):
    start = left_angles(world)
    target = start + np.array([0.3, 0.2, -0.3, -0.25, 0.4, 0.3, -0.5])
    speed_ratio = 0.3
    world.command_arm_positions('left', dict(zip(LEFT, target)), speed_ratio)
    peak = np.zeros(7)
    arrived_at = None
    for _ in range(int(3.0 / world.time_step)):
        world.step()
        peak = np.maximum(peak, np.abs(left_velocities(world)))
        if arrived_at is None and np.max(np.abs(left_angles(world) - target)) < 0.01:
            arrived_at = world.time
    assert arrived_at is not None and arrived_at < 2.0
    assert np.max(np.abs(left_angles(world) - target)) < 0.01
    assert np.all(peak <= speed_ratio * VELOCITY_LIMITS * 1.01), peak / (speed_ratio * VELOCITY_LIMITS)
    assert peak[0] > 0.9 * speed_ratio * VELOCITY_LIMITS[0]   # the slowest-to-arrive joints cruise at the limit
    assert np.max(np.abs(left_velocities(world))) < 1e-3     # and the arm holds still


def test_targets_are_clipped_to_the_joint_limits(world):
    world.command_arm_positions('left', {'left_e1': -1.0}, 1.0)
    world.step(480)
    assert left_angles(world)[3] == pytest.approx(-0.05, abs=1e-3)


def test_velocity_mode_then_hold(world):
    velocities = np.array([0.2, -0.1, 0.0, 0.1, 0.3, -0.2, 0.5])
    start = left_angles(world)
    world.command_arm_velocities('left', dict(zip(LEFT, velocities)))
    world.step(240)
    np.testing.assert_allclose(left_velocities(world), velocities, atol=2e-3)
    np.testing.assert_allclose(left_angles(world) - start, velocities * 1.0, atol=0.01)
    world.command_arm_velocities('left', {'left_s0': 10.0})   # clipped to 1.5 rad/s
    world.step(24)
    assert left_velocities(world)[0] == pytest.approx(1.5, abs=0.01)
    world.hold_arm('left')
    world.step(12)
    held = left_angles(world)
    world.step(240)
    assert np.max(np.abs(left_angles(world) - held)) < 1e-3


def test_velocity_mode_stops_at_the_joint_limits(world):
    world.command_arm_velocities('left', {'left_e1': -1.5, 'left_w1': 4.0})
    lowest_e1, highest_w1 = np.inf, -np.inf
    for _ in range(int(1.5 / world.time_step)):
        world.step()
        angles = left_angles(world)
        lowest_e1, highest_w1 = min(lowest_e1, angles[3]), max(highest_w1, angles[5])
    assert lowest_e1 > -0.05 - 1e-3 and angles[3] == pytest.approx(-0.05, abs=1e-3)
    assert highest_w1 < 2.094 + 1e-3 and angles[5] == pytest.approx(2.094, abs=1e-3)


def test_link_twist_matches_jacobian(world, kinematics):
    velocities = np.array([0.1, 0.2, -0.1, 0.2, 0.3, -0.2, 0.4])
    world.command_arm_velocities('left', dict(zip(LEFT, velocities)))
    world.step(60)
    expected = kinematics.jacobian(left_angles(world)) @ left_velocities(world)
    np.testing.assert_allclose(world.link_twist('left_gripper'), expected, atol=2e-3)


# ------------------------------------------------------------------------------------------------ gripper
def test_block_is_lifted_by_friction(world, kinematics):
    (block,) = world.object_poses()
    yaw = Rotation.from_matrix(block[:3, :3]).as_euler('xyz')[2]
    x, y, top_z = block[0, 3], block[1, 3], world.scene.table.top_z
    for z in (top_z + 0.10, top_z + 0.05, top_z + 0.008):      # down around the block, fingers open
        move_gripper(world, kinematics, gripper_down([x, y, z], yaw))
    assert world.gripper_state('left')['position_percent'] > 95
    world.command_gripper('left', 0.0, force_percent=40.0, velocity_percent=50.0)
    world.step(2)
    assert world.gripper_state('left')['moving']
    world.step(int(1.5 / world.time_step))
    state = world.gripper_state('left')
    assert state['gripping'] and not state['moving'] and not state['missed']
    gap = 0.016 + 2 * 0.020833 * state['position_percent'] / 100    # between the paddles' inner faces (m)
    assert gap == pytest.approx(0.04, abs=0.002)                      # stopped on the 40 mm block
    assert state['force_percent'] == pytest.approx(40.0, abs=4.0)     # squeezing with the commanded force
    z_before = world.object_poses()[0][2, 3]
    for z in (top_z + 0.06, top_z + 0.108):
        move_gripper(world, kinematics, gripper_down([x, y, z], yaw), speed_ratio=0.3)
    world.step(120)
    assert world.object_poses()[0][2, 3] - z_before >= 0.09
    assert world.gripper_state('left')['gripping']
    world.command_gripper('left', 100.0)                               # let go: it falls back on the table
    world.step(480)
    assert world.object_poses()[0][2, 3] == pytest.approx(top_z + 0.02, abs=1e-3)
    assert not world.gripper_state('left')['gripping']


def test_closing_on_nothing_is_missed(world):
    world.command_gripper('left', 0.0, force_percent=40.0, velocity_percent=100.0)
    world.step(int(1.0 / world.time_step))
    state = world.gripper_state('left')
    assert state['missed'] and not state['gripping'] and not state['moving']
    assert state['position_percent'] < 2.0
    world.command_gripper('left', 50.0)
    world.step(int(1.0 / world.time_step))
    state = world.gripper_state('left')
    assert state['position_percent'] == pytest.approx(50.0, abs=1.0) and not state['missed']


# ------------------------------------------------------------------------------------------------ sensors
@pytest.mark.parametrize('start', ['down', 'angled'])
def test_block_appears_where_the_camera_model_projects_it(camera, start):
    world = SimWorld(dataclasses.replace(load_scene(), start=start, appearance=CLEAN))   # the default scene's block
    image = world.render_camera('left_hand_camera', camera, np.random.default_rng(0))
    assert image.shape == (400, 640, 3) and image.dtype == np.uint8
    T_camera_block = invert(world.link_pose('left_hand_camera')) @ world.object_poses()[0]
    expected = camera.project(T_camera_block[:3, 3][None])[0]
    corners = camera.project(transform_points(T_camera_block, model_for('square', 0.04).vertices))
    assert np.all((corners > 5) & (corners < [camera.width - 5, camera.height - 5]))   # fully in view
    mask = block_mask(image)
    rows, columns = np.nonzero(mask)
    moments = cv2.moments(corners.astype(np.float32))
    assert mask.sum() == pytest.approx(moments['m00'], rel=0.1)
    assert np.hypot(columns.mean() - expected[0], rows.mean() - expected[1]) < 2.0
    # sharper: the mask's centroid is the projected top face's area centroid (perspective moves it off the
    # projected centre by 0.5 px in the angled view); a half-pixel convention error would show here
    area_centroid = np.array([moments['m10'], moments['m01']]) / moments['m00']
    assert np.hypot(columns.mean() - area_centroid[0], rows.mean() - area_centroid[1]) < 0.4
    # shading: a light table; the sides seen from the angled pose are darker green than the lit top
    assert np.median(image[~mask]) > 180
    if start == 'angled':
        hsv = cv2.cvtColor(image, cv2.COLOR_BGR2HSV)
        sides = (hsv[:, :, 0] > 45) & (hsv[:, :, 0] < 75) & (hsv[:, :, 1] > 100) & ~mask
        assert sides.sum() > 50
        assert np.median(hsv[:, :, 2][sides]) < 0.8 * np.median(hsv[:, :, 2][mask])
    world.close()


def test_camera_error_moves_the_true_camera(camera):
    shift, focal_scale = 0.01, 1.05   # m along the published camera's x; true / published focal length
    masks = []
    for error in (CameraError(), CameraError(xyz=(shift, 0.0, 0.0)), CameraError(focal_scale=focal_scale)):
        world = SimWorld(dataclasses.replace(load_scene(), camera_error=error, appearance=CLEAN))
        masks.append(block_mask(world.render_camera('left_hand_camera', camera)))
        depth = (invert(world.link_pose('left_hand_camera')) @ world.object_poses()[0])[2, 3]
        world.close()
    centroids = [np.nonzero(mask)[1].mean() for mask in masks]
    # the camera moves right, so the block moves left in the image by fx * shift / depth
    assert centroids[1] - centroids[0] == pytest.approx(-camera.fx * shift / depth, abs=0.5)
    # a longer true focal length magnifies the block
    assert masks[2].sum() / masks[0].sum() == pytest.approx(focal_scale ** 2, abs=0.03)


def test_range_sensor_reads_the_table_distance(world, kinematics):
    def expected_distance():
        T = world.link_pose('left_hand_range')
        origin, direction = T[:3, 3], T[:3, 0]
        return (world.scene.table.top_z - origin[2]) / direction[2]

    # in the down start pose the table is ~0.42 m away: beyond the sensor's 0.4 m
    assert expected_distance() > 0.4 and world.range_at('left_hand_range') == np.inf
    assert world.range_at('left_hand_range', max_range=1.0) == pytest.approx(expected_distance(), abs=0.005)
    q = kinematics.ik(gripper_down([0.6, 0.3, -0.05], 0.2), seed=left_angles(world))
    world.set_arm_positions('left', dict(zip(LEFT, q)))
    assert 0.1 < expected_distance() < 0.4
    assert world.range_at('left_hand_range') == pytest.approx(expected_distance(), abs=0.005)


# ------------------------------------------------------------------------------------------------ ground truth
def test_object_poses_and_place_object(world):
    (T,) = world.object_poses()
    np.testing.assert_allclose(T[:3, 3], [0.70, 0.25, -0.15 + 0.02], atol=1e-6)
    assert Rotation.from_matrix(T[:3, :3]).as_euler('xyz') == pytest.approx([0, 0, 0.4], abs=1e-6)
    world.step(240)                                   # resting on the table: it stays put
    np.testing.assert_allclose(world.object_poses()[0][:3, 3], [0.70, 0.25, -0.13], atol=1e-4)
    world.place_object(0, [0.55, -0.1], -0.3)
    world.step(10)
    (T,) = world.object_poses()
    np.testing.assert_allclose(T[:3, 3], [0.55, -0.1, -0.13], atol=1e-4)
    assert Rotation.from_matrix(T[:3, :3]).as_euler('xyz')[2] == pytest.approx(-0.3, abs=1e-4)


# ------------------------------------------------------------------------------------------------ respawn
def step_for(world, seconds):
    """Step ``seconds`` of simulated time; the respawn count after each step."""
    counts = []
    for _ in range(int(round(seconds / world.time_step))):
        world.step()
        counts.append(world.respawns)
    return counts


def test_respawn_fires_only_once_the_lifted_block_is_down_let_go_and_the_gripper_clear(kinematics):
    poses = [[0.60, 0.10, 0.3], [0.66, -0.05, -0.2]]
    delay = 0.5
    scene = load_scene()
    scene = Scene.from_dict({'objects': [{'shape': 'square', 'side': 0.04, 'height': 0.02, 'color': [0.1, 0.7, 0.1],
                                          'xy': list(scene.objects[0].xy), 'yaw': scene.objects[0].yaw}],
                             'respawn': {'poses': poses, 'delay': delay}})
    world = SimWorld(scene)
    (block,) = world.object_poses()
    yaw = Rotation.from_matrix(block[:3, :3]).as_euler('xyz')[2]
    x, y, top_z = block[0, 3], block[1, 3], world.scene.table.top_z
    block_top = top_z + 0.02
    assert set(step_for(world, 2 * delay)) == {0}                  # never lifted: stays
    for z in (top_z + 0.10, top_z + 0.05, top_z + 0.008):         # grasp it
        move_gripper(world, kinematics, gripper_down([x, y, z], yaw))
    world.command_gripper('left', 0.0, force_percent=40.0, velocity_percent=50.0)
    step_for(world, 1.5)
    for z in (top_z + 0.06, top_z + 0.108):                         # lift it 10 cm
        move_gripper(world, kinematics, gripper_down([x, y, z], yaw), speed_ratio=0.3)
    assert world.object_poses()[0][2, 3] > block_top + 0.08 and world.gripper_state('left')['gripping']
    assert set(step_for(world, 2 * delay)) == {0}                  # held in the air
    move_gripper(world, kinematics, gripper_down([x, y, top_z + 0.009], yaw), speed_ratio=0.3)
    assert world.object_poses()[0][2, 3] == pytest.approx(block_top, abs=2e-3)
    assert set(step_for(world, 2 * delay)) == {0}                  # put down but still held
    world.command_gripper('left', 100.0)
    assert set(step_for(world, 2 * delay)) == {0}                  # let go, fingers still around it
    move_gripper(world, kinematics, gripper_down([x, y, block_top + 0.07], yaw))
    assert set(step_for(world, 2 * delay)) == {0}                  # tip 7 cm above its top: too close
    np.testing.assert_allclose(world.object_poses()[0][:2, 3], [x, y], atol=3e-3)
    q = kinematics.ik(gripper_down([x, y, block_top + 0.09], yaw), seed=left_angles(world))
    world.command_arm_positions('left', dict(zip(LEFT, q)), 0.3)
    clearance, counts = [], []                                     # tip above the block's top (m), respawns
    for _ in range(int(3.0 / world.time_step)):
        clearance.append(world.link_pose('left_gripper')[2, 3] - block_top)
        world.step()
        counts.append(world.respawns)
    assert counts[-1] == 1
    clear = np.nonzero(np.array(clearance) < 0.08)[0][-1] + 1       # first step of the tip 8 cm above for good
    fired_after = (counts.index(1) - clear + 1) * world.time_step   # s after the tip got clear
    assert delay <= fired_after < delay + 2 * world.time_step, fired_after
    T = world.object_poses()[0]                                    # at rest on the table at the first pose
    np.testing.assert_allclose(T[:3, 3], [0.60, 0.10, block_top], atol=1e-3)
    assert Rotation.from_matrix(T[:3, :3]).as_euler('xyz') == pytest.approx([0, 0, 0.3], abs=1e-3)
    assert set(step_for(world, 2 * delay)) == {1}                  # not lifted since: stays
    world.place_object(0, (0.60, 0.10), 0.3)                       # dropped from 5 cm (e.g. a failed place)
    body = world._blocks[0]
    position, orientation = p.getBasePositionAndOrientation(body, physicsClientId=world._client)
    p.resetBasePositionAndOrientation(body, [position[0], position[1], position[2] + 0.05], orientation,
                                      physicsClientId=world._client)
    counts = step_for(world, 2 * delay + 0.5)
    assert counts[-1] == 2 and counts.count(2) < len(counts) // 2   # lands, rests for `delay`, moves on
    np.testing.assert_allclose(world.object_poses()[0][:3, 3], [0.66, -0.05, block_top], atol=1e-3)
    world.close()


def test_without_respawn_key_the_count_stays_zero(world):
    assert world.scene.respawn is None and world.respawns == 0


def test_respawn_needs_the_block_on_the_table_not_on_another_block():
    square = {'shape': 'square', 'side': 0.03, 'height': 0.02, 'color': [0.1, 0.7, 0.1], 'xy': [0.60, 0.30]}
    base = {'shape': 'hexagon', 'side': 0.05, 'height': 0.02, 'color': [0.8, 0.1, 0.1], 'xy': [0.70, 0.10]}
    world = SimWorld(Scene.from_dict({'objects': [square, base],
                                      'respawn': {'poses': [[0.62, -0.05, 0.2]], 'delay': 0.5}}))
    top_z = world.scene.table.top_z

    def drop_target_at(xy, bottom_z):
        """Teleport the target block, upright and still, its underside at ``bottom_z`` (m) above ``xy``."""
        p.resetBasePositionAndOrientation(world._blocks[0], [xy[0], xy[1], bottom_z + 0.01], [0, 0, 0, 1],
                                          physicsClientId=world._client)
        p.resetBaseVelocity(world._blocks[0], [0, 0, 0], [0, 0, 0], physicsClientId=world._client)

    drop_target_at((0.60, 0.30), top_z + 0.025)                     # a 2.5 cm drop onto the table: not lifted
    assert set(step_for(world, 1.0)) == {0}
    drop_target_at((0.70, 0.10), top_z + 0.035)                     # lifted 3.5 cm, lands on the hexagon
    assert set(step_for(world, 2.0)) == {0}
    np.testing.assert_allclose(world.object_poses()[0][:3, 3], [0.70, 0.10, top_z + 0.04], atol=2e-3)
    drop_target_at((0.60, 0.30), top_z + 0.001)                     # then on the table
    counts = step_for(world, 1.0)
    assert counts[-1] == 1 and 0.5 < counts.index(1) * world.time_step < 0.8
    np.testing.assert_allclose(world.object_poses()[0][:3, 3], [0.62, -0.05, top_z + 0.02], atol=1e-3)
    world.close()


# ------------------------------------------------------------------------------------------------ chessboard
@pytest.fixture(scope='module')
def sensor_camera():
    """The fake's left hand camera at 640x400, as it publishes it (a window of the 1280x800 sensor, distorted)."""
    return sensor_model('left_hand_camera').windowed(sensor_window(640, 400))


def hand_eye_scene(name='hand_eye', **changes):
    """config/scenes/<name>.yaml (hand_eye: a 9x6 board, 25 mm squares, a block beyond it, a camera error;
    hand_eye_focal: the same and a 2 % longer focal length), with ``changes``."""
    return dataclasses.replace(load_scene(os.path.join(SCENES, f'{name}.yaml')), **changes)


def make_world(scene, renderer='auto'):
    """SimWorld of ``scene``; the test skips where the EGL renderer asked for cannot run."""
    try:
        return SimWorld(scene, renderer=renderer)
    except RendererUnavailable as error:
        pytest.skip(f'EGL unavailable here: {error}')


def view_board_tilted(world, kinematics, angle=np.radians(25), closer=0.04):
    """Teleport the left arm: its camera turned ``angle`` about base +x through the board's centre from the start
    pose (it swings toward base -y and looks back at the board), then ``closer`` (m) along its optical axis
    (0.40 m from the board's centre)."""
    board = world.scene.boards[0]
    centre = make_transform(None, [*board.xy, world.scene.table.top_z])
    T_base_camera = (centre @ make_transform(Rotation.from_euler('x', angle)) @ invert(centre)
                     @ world.link_pose('left_hand_camera') @ make_transform(None, [0.0, 0.0, closer]))
    q = kinematics.ik(T_base_camera, frame='left_hand_camera', seed=left_angles(world))
    assert q is not None
    world.set_arm_positions('left', dict(zip(LEFT, q)))


def true_corners_px(world, camera):
    """(N, 2) px of the board's inner corners, ``calibration.board_object_points`` order mapped by the scene's
    ``T_base_board``, projected by the camera that renders the image: ``camera`` moved and scaled by
    ``scene.camera_error``."""
    scene = world.scene
    (board,) = scene.boards
    error = scene.camera_error
    K = camera.K.copy()
    K[0, 0] *= error.focal_scale
    K[1, 1] *= error.focal_scale
    true_camera = CameraModel(camera.width, camera.height, K, camera.D)
    T_camera_board = invert(world.link_pose('left_hand_camera') @ error.T_published_true) @ \
        board.T_base_board(scene.table.top_z)
    return true_camera.project(transform_points(T_camera_board, board_object_points(board.pattern, board.square)))


def corner_errors_px(image, expected):
    """Distances (px) of the sub-pixel corners ``find_board_corners`` finds in ``image`` from ``expected``,
    matched in the order OpenCV returns them (asserted: the board's own, first inner corner first)."""
    found = find_board_corners(image, (9, 6))
    assert found is not None, 'no 9x6 chessboard found'
    errors = np.linalg.norm(found.reshape(-1, 2) - expected, axis=1)
    assert errors.max() < 2.0, 'corners in another order than the board frame\'s'
    return errors


@pytest.mark.parametrize('renderer', ['egl', 'tiny'])
@pytest.mark.parametrize('scene_name, view', [('hand_eye', 'down'), ('hand_eye', 'tilted'), ('hand_eye_focal', 'down')])
def test_board_corners_are_found_where_the_true_camera_projects_them(sensor_camera, kinematics, renderer,
                                                                     scene_name, view):
    """The hand camera sees the board as OpenCV sees a real one: ``find_board_corners`` on the fake's image lands
    on the board's true corners (``Chessboard.T_base_board``) projected by the true camera (the scene's camera
    error included: 11.2 mm and 2.5 deg off the published one, and a 2 % longer focal length in hand_eye_focal),
    in the board frame's order."""
    world = make_world(hand_eye_scene(scene_name), renderer)
    try:
        if view == 'tilted':
            view_board_tilted(world, kinematics)
        expected = true_corners_px(world, sensor_camera)
        assert np.all((expected > 20) & (expected < [620, 380]))              # the whole grid in view
        errors = corner_errors_px(world.render_camera('left_hand_camera', sensor_camera, np.random.default_rng(0)),
                                  expected)
        # measured mean 0.13 px (down, focal too) and 0.14 px (tilted), max 0.25-0.32 px, both renderers; without the
        # scene's supersampling (aliased edges) 0.36 px (test_supersampling_makes_the_corners_sub_pixel_exact)
        assert errors.mean() < 0.2 and errors.max() < 0.5
    finally:
        world.close()


def test_supersampling_makes_the_corners_sub_pixel_exact(sensor_camera):
    """One sample a pixel gives stair-stepped edges and corners only good to a third of a pixel; 2 x 2 samples
    average like a real sensor's pixel and bring them to a tenth."""
    means = {}
    for samples in (1, 2):
        world = make_world(hand_eye_scene(supersampling=samples))
        image = world.render_camera('left_hand_camera', sensor_camera)
        means[samples] = corner_errors_px(image, true_corners_px(world, sensor_camera)).mean()
        world.close()
    assert means[1] > 0.3 and means[2] < 0.15, means         # measured 0.36 and 0.13 px


@pytest.mark.parametrize('look', ['clean', 'baxter'])
def test_the_board_is_no_block_and_is_found_under_both_looks(sensor_camera, look):
    """Black and white, no colour key: the pick's perception finds no block on the board alone (nor in the grey
    'baxter' look's darker, noisier, vignetted image), and the corners are still found."""
    world = make_world(hand_eye_scene(objects=(), appearance=AppearanceConfig.from_dict(appearance.expand(look))))
    try:
        image = world.render_camera('left_hand_camera', sensor_camera, np.random.default_rng(1))
        assert observe_blocks(image, sensor_camera, VisionConfig(), side=0.04) == []
        gray = cv2.cvtColor(image, cv2.COLOR_BGR2GRAY)
        inside = cv2.fillConvexPoly(np.zeros_like(gray), cv2.convexHull(
            true_corners_px(world, sensor_camera).astype(np.int32)), 1).astype(bool)
        dark, light = np.percentile(gray[inside], [10, 90])
        assert dark < 20 and light > 150, (dark, light)       # matte black squares on white paper
        assert corner_errors_px(image, true_corners_px(world, sensor_camera)).mean() < 0.2    # measured 0.13
    finally:
        world.close()


def test_the_board_is_visual_only(sensor_camera):
    """Nothing but the table, the blocks and the robot has a collision shape: a block standing on the board
    rests on the table top (a 0.5 mm board under it would lift it), and the ground truth lists blocks only."""
    scene = hand_eye_scene()
    world = make_world(scene)
    try:
        (board,) = scene.boards
        world.place_object(0, board.xy, 0.2)                                   # onto the board's centre
        world.step(240)
        (T_base_block,) = world.object_poses()
        np.testing.assert_allclose(T_base_block[:3, 3], [*board.xy, scene.table.top_z + 0.02], atol=1e-4)
        colliding = {i for i in range(p.getNumBodies(physicsClientId=world._client))
                     if p.getCollisionShapeData(i, -1, physicsClientId=world._client)}
        assert colliding == {world._table, *world._blocks}                    # the robot's are on its links
        assert p.getNumBodies(physicsClientId=world._client) == 2 + len(world._blocks) + 2     # + paper, squares
    finally:
        world.close()
