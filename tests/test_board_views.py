"""Viewpoints for calibrating on a chessboard lying on the table (baxter_pnp.board_views), pure.

The camera is the fake's 640x400 mode of the thesis lens (``sim/cameras.py``: the thesis calibration as the centred
640x480 window of the 1280x800 sensor, cropped to 640x400: cy - 40 px); the fingers' map is ray-cast from the
URDF's gripper solids through its hand-eye transform, as the eye does (``task/eye.py``).
"""
import cv2
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from baxter_pnp import view
from baxter_pnp.board_views import (ROTATION_COST_M_PER_RAD, board_centre, board_in_view, candidate_views,
                                    clear_aim_px, order_views, plan_board_views, view_step_cost, viewpoint)
from baxter_pnp.calibration import CalibrationError, board_object_points, find_board_corners
from baxter_pnp.camera import CameraModel, load_default_camera
from baxter_pnp.kinematics import ArmKinematics, load_start_poses
from baxter_pnp.synthetic import render_chessboard
from baxter_pnp.transforms import invert, make_transform, transform_points

PATTERN, SQUARE = (9, 6), 0.025                 # the board: 9x6 inner corners, 25 mm squares
BOARD_CENTRE_BASE = np.array([0.62, 0.26, -0.15])   # on the table, where the `down` start pose's camera looks
COUNT, MAX_TILT_DEG, MAX_ROLL_DEG, DISTANCES = 20, 30.0, 45.0, (0.25, 0.45)


def board_pose(yaw_deg=90.0, z_up=True, centre=BOARD_CENTRE_BASE):
    """T_base_board of a board flat on the table, its centre at ``centre``, columns along ``yaw_deg`` from base x
    (90: along base y, the long side across the image at roll 0), its z up or down."""
    rotation = Rotation.from_euler('z', yaw_deg, degrees=True) * Rotation.from_euler('x', 0.0 if z_up else np.pi)
    return make_transform(rotation, centre - rotation.apply(board_centre(PATTERN, SQUARE)))


@pytest.fixture(scope='module')
def camera():
    thesis = load_default_camera()
    K = thesis.K.copy()
    K[1, 2] -= 40.0
    return CameraModel(640, 400, K, thesis.D)


@pytest.fixture(scope='module')
def kinematics():
    return ArmKinematics('left')


@pytest.fixture(scope='module')
def clearance_px(camera, kinematics):
    """The open fingers' clearance map in the 640x400 image (they hide the top ~140 rows, left and right)."""
    q = np.zeros(7)
    T_camera_gripper = invert(invert(kinematics.fk(q)) @ kinematics.fk(q, 'left_hand_camera'))
    return view.hand_clearance_px(camera, [solid.moved(T_camera_gripper) for solid in kinematics.hand_solids()])


def view_angles(T_base_camera, T_base_board):
    """(tilt deg, azimuth deg, distance m, roll deg, miss m) of a view as board_views defines them; ``miss``: how
    far the optical axis passes from the board centre."""
    centre = transform_points(T_base_board, board_centre(PATTERN, SQUARE)[None])[0]
    up = np.array([0.0, 0.0, 1.0])
    offset = T_base_camera[:3, 3] - centre
    distance = np.linalg.norm(offset)
    sight = -offset / distance
    tilt = np.degrees(np.arccos(np.clip(offset @ up / distance, -1, 1)))
    azimuth = np.degrees(np.arctan2(offset[1], offset[0])) % 360.0
    minus_y = np.array([0.0, -1.0, 0.0])
    roll_zero_x = minus_y - (minus_y @ sight) * sight               # base -y's component across the sight
    roll_zero_x /= np.linalg.norm(roll_zero_x)
    x = T_base_camera[:3, 0]
    roll = np.degrees(np.arctan2(np.cross(roll_zero_x, x) @ sight, roll_zero_x @ x))
    miss = np.linalg.norm(np.cross(T_base_camera[:3, 2], centre - T_base_camera[:3, 3]))
    return tilt, azimuth, distance, roll, miss


def largest_gap_deg(angles_deg):
    """Largest gap (deg) between consecutive angles around the circle."""
    ordered = np.sort(np.asarray(angles_deg) % 360.0)
    return float(np.max(np.diff(np.append(ordered, ordered[0] + 360.0))))


# ------------------------------------------------------------------------------------------------ geometry
def test_board_centre():
    assert board_centre(PATTERN, SQUARE) == pytest.approx([0.1, 0.0625, 0.0])


@pytest.mark.parametrize('z_up', [True, False])
def test_views_look_at_the_board_centre_from_above_within_the_ranges(z_up):
    """Every view's optical axis through the board centre, from above (the board's z up or down alike), tilt,
    distance and roll within their bounds and spread over them, azimuths all around."""
    T_base_board = board_pose(z_up=z_up)
    views = plan_board_views(T_base_board, PATTERN, SQUARE, COUNT, DISTANCES, MAX_TILT_DEG, MAX_ROLL_DEG)
    assert len(views) == COUNT
    for T in views:                                                  # rigid: a rotation, no scaling or shear
        assert T[:3, :3].T @ T[:3, :3] == pytest.approx(np.eye(3), abs=1e-12) and np.linalg.det(T[:3, :3]) > 0
    tilt, azimuth, distance, roll, miss = np.array([view_angles(T, T_base_board) for T in views]).T
    assert np.all(miss < 1e-9)
    assert all(T[2, 3] > BOARD_CENTRE_BASE[2] + 0.2 and T[2, 2] < -0.8 for T in views)   # above, looking down
    assert np.all(tilt <= MAX_TILT_DEG + 1e-9) and tilt.max() > 0.8 * MAX_TILT_DEG and tilt.min() < 0.4 * MAX_TILT_DEG
    assert np.all((DISTANCES[0] - 1e-9 <= distance) & (distance <= DISTANCES[1] + 1e-9))
    assert np.ptp(distance) > 0.7 * (DISTANCES[1] - DISTANCES[0])
    assert np.all(np.abs(roll) <= MAX_ROLL_DEG + 1e-9)
    assert roll.min() < -0.6 * MAX_ROLL_DEG and roll.max() > 0.6 * MAX_ROLL_DEG
    assert largest_gap_deg(azimuth) < 60.0


def test_a_board_upside_down_gives_the_same_views():
    up = plan_board_views(board_pose(z_up=True), PATTERN, SQUARE, COUNT)
    down = plan_board_views(board_pose(z_up=False), PATTERN, SQUARE, COUNT)
    assert np.allclose(up, down, atol=1e-12)


def test_roll_zero_looking_down_is_the_down_start_pose_camera(kinematics):
    """Straight down with roll 0: the hand camera of the `down` start pose (image x = base -y, y = base -x)."""
    q_down = [load_start_poses()['down'][name] for name in kinematics.joint_names]
    T_base_camera_down = kinematics.fk(q_down, 'left_hand_camera')
    T_base_view = viewpoint(board_pose(), PATTERN, SQUARE, tilt_deg=0.0, azimuth_deg=0.0, distance=0.43, roll_deg=0.0)
    angle = Rotation.from_matrix(T_base_camera_down[:3, :3].T @ T_base_view[:3, :3]).magnitude()
    assert np.degrees(angle) < 1.0
    assert T_base_view[:3, :3] == pytest.approx(np.array([[0, -1, 0], [-1, 0, 0], [0, 0, -1]]), abs=1e-9)


def test_views_rotate_about_three_well_separated_axes():
    """Hand-eye calibration needs rotations about well-separated axes: the views' orientations, as rotation
    vectors about their mean, spread at least 8 deg RMS along each of three orthogonal axes (tilts all about one
    axis, or no roll, would leave one near 0)."""
    views = plan_board_views(board_pose(), PATTERN, SQUARE, COUNT)
    rotations = Rotation.from_matrix([T[:3, :3] for T in views])
    spread = (rotations.mean().inv() * rotations).as_rotvec()
    rms_deg = np.degrees(np.linalg.svd(spread, compute_uv=False)) / np.sqrt(len(views))
    assert rms_deg.min() > 8.0, rms_deg


def test_candidates_come_in_decreasing_priority_of_diversity():
    """3x count candidates, the first count being the plan; the same for the same seed, others for another; the
    first 8 already spread over azimuth, tilt and roll."""
    T_base_board = board_pose()
    candidates = candidate_views(T_base_board, PATTERN, SQUARE, count=10)
    assert len(candidates) == 30
    assert np.allclose(candidates[:10], plan_board_views(T_base_board, PATTERN, SQUARE, count=10))
    assert np.allclose(candidates, candidate_views(T_base_board, PATTERN, SQUARE, count=10))
    assert not np.allclose(candidates[:10], candidate_views(T_base_board, PATTERN, SQUARE, count=10, seed=1)[:10])
    tilt, azimuth, _, roll, _ = np.array([view_angles(T, T_base_board) for T in candidates[:8]]).T
    assert largest_gap_deg(azimuth) < 120.0 and np.ptp(tilt) > 10.0 and roll.min() < 0 < roll.max()


# ---------------------------------------------------------------------------------------- in view, fingers
def test_planned_views_fit_the_image_and_clear_the_fingers(camera, clearance_px):
    """With the camera and the fingers' map, every planned view shows the whole 9x6 board clear of the fingers
    (the board centre on the aim pixel below them), within the ranges; planned blind, many would not."""
    T_base_board = board_pose()
    aim = clear_aim_px(camera, clearance_px)
    assert aim[0] == pytest.approx(camera.cx, abs=0.5) and aim[1] > 240.0        # below the fingers (rows < 140)
    views = plan_board_views(T_base_board, PATTERN, SQUARE, COUNT, camera=camera, clearance_px=clearance_px)
    assert all(board_in_view(T, T_base_board, camera, PATTERN, SQUARE, clearance_px) for T in views)
    centre_base = transform_points(T_base_board, board_centre(PATTERN, SQUARE)[None])
    for T in views:
        assert camera.project(transform_points(invert(T), centre_base))[0] == pytest.approx(aim, abs=1e-6)
    tilt, azimuth, distance, _, _ = np.array([view_angles(T, T_base_board) for T in views]).T
    assert np.all(tilt <= MAX_TILT_DEG + 12.0)       # the line of sight's tilt plus the aim's 11 deg off-axis
    assert np.all((DISTANCES[0] <= distance) & (distance <= DISTANCES[1] + 1e-9)) and largest_gap_deg(azimuth) < 90
    blind = plan_board_views(T_base_board, PATTERN, SQUARE, COUNT)
    assert sum(board_in_view(T, T_base_board, camera, PATTERN, SQUARE, clearance_px) for T in blind) < COUNT / 2


def test_planned_views_render_to_detected_boards(camera):
    """Each planned view rendered (the board with its white border, no fingers): the detector finds all 54 corners
    where board_in_view's projection puts them."""
    T_base_board = board_pose(yaw_deg=70.0)
    rng = np.random.default_rng(0)
    views = plan_board_views(T_base_board, PATTERN, SQUARE, 12, camera=camera, seed=3)
    for T_base_camera in views:
        T_camera_board = invert(T_base_camera) @ T_base_board
        image, corners_px = render_chessboard(camera, T_camera_board, rng, pattern=PATTERN, square=SQUARE)
        found = find_board_corners(image, PATTERN)
        assert found is not None
        nearest = np.linalg.norm(found.reshape(-1, 1, 2) - corners_px[None], axis=2).min(axis=1)
        assert nearest.max() < 0.5


def test_board_in_view_is_false_when_a_corner_leaves_or_hides(camera):
    """A corner out of the image, within the margin, behind a finger, the board's outer squares cut, or the
    board behind the camera: not in view."""
    T_base_board = board_pose()
    T_base_camera = viewpoint(T_base_board, PATTERN, SQUARE, tilt_deg=10.0, azimuth_deg=40.0, distance=0.42,
                              roll_deg=5.0)
    assert board_in_view(T_base_camera, T_base_board, camera, PATTERN, SQUARE)
    corners_camera = transform_points(invert(T_base_camera) @ T_base_board, board_object_points(PATTERN, SQUARE))
    corners_px = camera.project(corners_camera)
    leftmost = np.argmin(corners_px[:, 0])

    def moved_left(target_u):
        """The camera moved along its x so that the leftmost corner lands near column ``target_u``; and its
        actual column then."""
        T = T_base_camera.copy()
        T[:3, 3] += T[:3, 0] * (corners_px[leftmost, 0] - target_u) * corners_camera[leftmost, 2] / camera.fx
        return T, camera.project(transform_points(invert(T) @ T_base_board, board_object_points(PATTERN,
                                                                                                 SQUARE)))[:, 0].min()
    square_px = camera.fx * SQUARE / corners_camera[leftmost, 2]
    T_out, u = moved_left(-5.0)                                      # a corner out of the image
    assert u < 0 and not board_in_view(T_out, T_base_board, camera, PATTERN, SQUARE)
    T_margin, u = moved_left(10.0)                                   # within the 15 px margin
    assert 0 < u < 15 and not board_in_view(T_margin, T_base_board, camera, PATTERN, SQUARE, border_squares=0.0)
    T_cut, u = moved_left(0.75 * square_px)                          # the corners clear, the outer squares cut
    assert 15 < u < square_px
    assert board_in_view(T_cut, T_base_board, camera, PATTERN, SQUARE, border_squares=0.0)
    assert not board_in_view(T_cut, T_base_board, camera, PATTERN, SQUARE)
    free = np.ones((camera.height, camera.width), np.uint8)
    column, row = np.round(corners_px[0]).astype(int)
    free[row - 3:row + 4, column - 3:column + 4] = 0               # a "finger" over one corner
    finger_map = cv2.distanceTransform(free, cv2.DIST_L2, 5)
    assert not board_in_view(T_base_camera, T_base_board, camera, PATTERN, SQUARE, clearance_px=finger_map)
    open_map = np.full((camera.height, camera.width), 1e3, np.float32)
    assert board_in_view(T_base_camera, T_base_board, camera, PATTERN, SQUARE, clearance_px=open_map)
    flipped = T_base_camera @ make_transform(Rotation.from_euler('x', np.pi))     # looking up, away from it
    assert not board_in_view(flipped, T_base_board, camera, PATTERN, SQUARE)


# ------------------------------------------------------------------------------------------------- path
def test_order_views_takes_the_nearest_next():
    """Poses along a line, shuffled: the path runs along it from the start's end; each step costs translation
    plus ROTATION_COST_M_PER_RAD per radian."""
    rng = np.random.default_rng(0)
    along = [make_transform(Rotation.from_euler('z', 0.1 * k), [0.1 * k, 0.0, 0.0]) for k in range(8)]
    shuffled = [along[k] for k in rng.permutation(8)]
    path = order_views(shuffled, make_transform(None, [-0.2, 0.0, 0.0]))
    assert np.allclose(path, along)
    assert view_step_cost(along[0], along[1]) == pytest.approx(0.1 + ROTATION_COST_M_PER_RAD * 0.1)


def test_order_views_shortens_the_planned_path():
    T_base_board = board_pose()
    views = plan_board_views(T_base_board, PATTERN, SQUARE, COUNT)
    start = viewpoint(T_base_board, PATTERN, SQUARE, tilt_deg=0.0, azimuth_deg=0.0, distance=0.43, roll_deg=0.0)
    path = order_views(views, start)

    def length(poses):
        return sum(view_step_cost(a, b) for a, b in zip([start] + poses[:-1], poses))
    assert sorted(map(id, path)) == sorted(map(id, views))          # the same poses, each once
    assert length(path) < 0.6 * length(views)


# ------------------------------------------------------------------------------------------------ errors
def test_clear_errors(camera):
    standing = board_pose() @ make_transform(Rotation.from_euler('x', 60.0, degrees=True))
    with pytest.raises(CalibrationError, match='lay it flat'):
        plan_board_views(standing, PATTERN, SQUARE)
    with pytest.raises(CalibrationError, match='distances'):
        plan_board_views(board_pose(), PATTERN, SQUARE, distances=(0.45, 0.25))
    with pytest.raises(CalibrationError, match='max_tilt_deg'):
        plan_board_views(board_pose(), PATTERN, SQUARE, max_tilt_deg=75.0)
    with pytest.raises(CalibrationError, match='no viewpoint within 0.45 m shows the whole 9x6 board'):
        plan_board_views(board_pose(), PATTERN, 0.08, camera=camera)          # a 0.8 m board
