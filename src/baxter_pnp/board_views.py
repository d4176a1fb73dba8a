"""Where the hand camera looks from to calibrate on a chessboard lying on the table, pure: diverse viewpoints
around the board, whether the board is in view (and clear of the fingers), and a short path through them.

Frames: ``T_base_board`` is the board's pose in ``base`` as ``calibration.board_object_points`` defines it
(origin at the first inner corner, x along the columns, y along the rows, z normal to the board; a board on the
table may have its z up or down, both are handled); ``T_base_camera`` is the camera optical frame's pose (x right,
y down, z forward); 4x4, metres.

A viewpoint is set by four numbers around the board centre's *up* normal ``n`` (the board normal on the side
facing up, where the camera must be):

- ``tilt``: angle (deg) between the line of sight (camera -> board centre) and ``n``; 0 looks straight down;
- ``azimuth``: where the camera stands around ``n``, 0 toward the projection of ``base`` +x on the board,
  counter-clockwise about ``n``;
- ``distance``: from the camera to the board centre (m);
- ``roll``: rotation (deg) about the line of sight. **Roll 0**: the image x axis is ``base`` -y as seen across the
  line of sight (its component perpendicular to it). Looking straight down with roll 0 the image x points to
  ``base`` -y and the image y to ``base`` -x (toward the robot): the hand camera of the ``down`` start pose
  (``config/start_poses.yaml``; the left gripper pointing down, hand y = ``base`` y).

The line of sight passes through ``aim_px`` (default: the principal point, i.e. the optical axis through the board
centre; with the hand's clearance map, the centre of the largest image disk clear of the fingers, so the board sits
in the part of the image the fingers do not hide).

Viewpoints come from a scrambled Halton sequence over (tilt, azimuth, roll, distance): every prefix of it is spread
over the four ranges, so the viewpoints are listed in decreasing priority of diversity and the task can skip the
unreachable ones and still get well-spread views. Azimuths all around the board tilt the camera about every
horizontal axis, rolls turn it about the optical axis: the relative motions rotate about well-separated axes, as
hand-eye calibration needs.
"""
import numpy as np
from scipy.stats import qmc
from scipy.spatial.transform import Rotation

from baxter_pnp import view
from baxter_pnp.calibration import CalibrationError, board_object_points
from baxter_pnp.transforms import make_transform, transform_points

MAX_BOARD_SLOPE_DEG = 20.0     # a board "lying on the table": its normal within this of vertical
MAX_TILT_LIMIT_DEG = 60.0      # with the slope, the line of sight stays >= 10 deg below horizontal: roll 0 defined
DEFAULT_BORDER_SQUARES = 1.0   # the detector needs the outer row of squares around the inner corners in view
DISTANCE_BISECTIONS = 12       # finding the nearest distance at which the board fits: (0.2 m) / 2^12 = 0.05 mm
MAX_SAMPLES_PER_VIEW = 20      # Halton samples tried per view asked for (with a camera) before giving up
# Path cost of a rotation, metres per radian: a rough time equivalence. Moves are joint-space at one speed ratio;
# turning the camera 1 rad takes the wrist (4 rad/s limit) about as long as carrying it 0.4 m takes the shoulder
# (1.5 rad/s limit, the camera ~1 m out).
ROTATION_COST_M_PER_RAD = 0.4


def board_centre(pattern, square):
    """(3,) centre of the inner-corner grid in the board frame (m): ``pattern`` = (columns, rows)."""
    cols, rows = pattern
    return np.array([(cols - 1) * square / 2.0, (rows - 1) * square / 2.0, 0.0])


def board_outline(pattern, square, border_squares=DEFAULT_BORDER_SQUARES):
    """(4, 3) corners (board frame, m) of the inner-corner grid grown by ``border_squares`` squares each side."""
    cols, rows = pattern
    low = -border_squares * square
    high_x, high_y = (cols - 1 + border_squares) * square, (rows - 1 + border_squares) * square
    return np.array([[low, low, 0.0], [high_x, low, 0.0], [high_x, high_y, 0.0], [low, high_y, 0.0]])


def board_in_view(T_base_camera, T_base_board, camera, pattern, square, clearance_px=None, margin_px=15,
                  border_squares=DEFAULT_BORDER_SQUARES):
    """True if the board can be detected from ``T_base_camera``: every inner corner in front of ``camera`` (a
    ``CameraModel``) and projecting at least ``margin_px`` inside the image, and the board grown by
    ``border_squares`` squares around them (the squares the detector needs) inside the image. Given the hand's
    ``clearance_px`` map (``view.hand_clearance_px``: (H, W), each pixel's distance to the fingers, 0 where they
    hide it), the inner corners' polygon is also more than ``margin_px`` from the fingers and the grown board
    not behind them."""
    corners_base = transform_points(T_base_board, board_object_points(pattern, square))
    outline_base = transform_points(T_base_board, board_outline(pattern, square, border_squares))
    return (view.points_in_view(T_base_camera, corners_base, camera, margin_px, clearance_px)
            and view.points_in_view(T_base_camera, outline_base, camera, 0.0, clearance_px))


def clear_aim_px(camera, clearance_px=None):
    """(2,) pixel (u, v) on the principal point's column (so the image's width is there on both sides) where the
    largest disk clear of the fingers and inside the image is centred (ties: the row nearest the principal point);
    without ``clearance_px``, the principal point. Baxter's fingers hide the top of the image: this aims lower."""
    principal_point = np.array([camera.cx, camera.cy])
    if clearance_px is None:
        return principal_point
    height, width = clearance_px.shape
    column = int(np.clip(np.rint(camera.cx), 0, width - 1))
    rows = np.arange(height, dtype=float)
    room = np.minimum.reduce([clearance_px[:, column], rows, height - 1 - rows,
                              np.full(height, min(column, width - 1 - column), dtype=float)])
    best = np.nonzero(room >= room.max() - 1.0)[0]
    return np.array([column, best[np.argmin(np.abs(best - camera.cy))]], dtype=float)


def up_normal(T_base_board):
    """(3,) unit normal of the board on the side facing up (``base`` +z side); CalibrationError if the board is
    not lying flat (its normal more than ``MAX_BOARD_SLOPE_DEG`` from vertical)."""
    normal = T_base_board[:3, 2] / np.linalg.norm(T_base_board[:3, 2])
    normal = normal if normal[2] >= 0.0 else -normal
    slope_deg = np.degrees(np.arccos(np.clip(normal[2], -1.0, 1.0)))
    if slope_deg > MAX_BOARD_SLOPE_DEG:
        raise CalibrationError(f'the board is tilted {slope_deg:.0f} deg from horizontal: lay it flat on the table '
                               f'(at most {MAX_BOARD_SLOPE_DEG:.0f} deg)')
    return normal


def viewpoint(T_base_board, pattern, square, tilt_deg, azimuth_deg, distance, roll_deg, aim_normalised=(0.0, 0.0)):
    """T_base_camera looking at the board centre from (``tilt_deg``, ``azimuth_deg``, ``distance`` (m),
    ``roll_deg``) as the module's docstring defines them, the line of sight through the normalised image point
    ``aim_normalised`` (X/Z, Y/Z; (0, 0) = the optical axis)."""
    normal = up_normal(T_base_board)
    centre_base = transform_points(T_base_board, board_centre(pattern, square)[None])[0]
    east = np.array([1.0, 0.0, 0.0]) - normal[0] * normal       # base +x across the board: azimuth 0
    east /= np.linalg.norm(east)
    tilt, azimuth = np.radians(tilt_deg), np.radians(azimuth_deg)
    towards_camera = Rotation.from_rotvec(azimuth * normal).apply(np.cos(tilt) * normal + np.sin(tilt) * east)
    sight = -towards_camera                                      # camera -> board centre, unit
    minus_y = np.array([0.0, -1.0, 0.0])
    image_x = minus_y - (minus_y @ sight) * sight                 # base -y across the line of sight: roll 0
    image_x /= np.linalg.norm(image_x)
    image_x = Rotation.from_rotvec(np.radians(roll_deg) * sight).apply(image_x)
    R_base_sight = np.column_stack([image_x, np.cross(sight, image_x), sight])
    aim_ray = np.array([*aim_normalised, 1.0])
    aim_ray /= np.linalg.norm(aim_ray)
    R_sight_camera, _ = Rotation.align_vectors([[0.0, 0.0, 1.0]], [aim_ray])   # camera's aim ray -> sight's z
    return make_transform(R_base_sight @ R_sight_camera.as_matrix(), centre_base - distance * sight)


def candidate_views(T_base_board, pattern, square, count=20, distances=(0.25, 0.45), max_tilt_deg=30.0,
                    max_roll_deg=45.0, seed=0, oversample=3, camera=None, clearance_px=None, margin_px=15,
                    aim_px=None):
    """``oversample * count`` viewpoints [T_base_camera 4x4] around the board, in decreasing priority of diversity
    (a scrambled Halton sequence over tilt, azimuth, roll and distance; ``seed`` picks the scrambling).

    Tilts are spread evenly over the spherical cap up to ``max_tilt_deg`` (so more of them well tilted), azimuths
    over 0..360 deg, rolls over +-``max_roll_deg``, distances over ``distances`` (m). Given ``camera`` (a
    ``CameraModel``, and optionally the hand's ``clearance_px`` map), only viewpoints with the board in view
    (:func:`board_in_view` with ``margin_px``) are kept: the distance is drawn between the nearest one at which
    the board fits and ``distances[1]``, and a viewpoint where it does not fit even there is skipped.
    ``aim_px``: the pixel the line of sight passes through (default :func:`clear_aim_px`; without ``camera``,
    the optical axis). CalibrationError if the arguments are out of range or (with ``camera``) no viewpoint fits.
    """
    near, far = distances
    if not (0.0 < near <= far):
        raise CalibrationError(f'distances must be 0 < near <= far (m), got {distances}')
    if not (0.0 <= max_tilt_deg <= MAX_TILT_LIMIT_DEG and 0.0 <= max_roll_deg <= 180.0):
        raise CalibrationError(f'max_tilt_deg must be in [0, {MAX_TILT_LIMIT_DEG:.0f}] and max_roll_deg in '
                               f'[0, 180], got {max_tilt_deg} and {max_roll_deg}')
    if count < 1 or oversample < 1:
        raise CalibrationError(f'count and oversample must be >= 1, got {count} and {oversample}')
    wanted = oversample * count
    aim_normalised = np.zeros(2)
    if camera is not None:
        aim = clear_aim_px(camera, clearance_px) if aim_px is None else np.asarray(aim_px, dtype=float)
        aim_normalised = camera.undistort_points(aim[None])[0]
    cos_max_tilt = np.cos(np.radians(max_tilt_deg))
    samples = qmc.Halton(d=4, scramble=True, seed=seed).random(wanted if camera is None
                                                                 else MAX_SAMPLES_PER_VIEW * wanted)
    views = []
    for u_tilt, u_azimuth, u_roll, u_distance in samples:
        angles = dict(tilt_deg=np.degrees(np.arccos(1.0 - u_tilt * (1.0 - cos_max_tilt))),
                      azimuth_deg=360.0 * u_azimuth, roll_deg=max_roll_deg * (2.0 * u_roll - 1.0))

        def at(distance):
            return viewpoint(T_base_board, pattern, square, distance=distance, aim_normalised=aim_normalised,
                             **angles)

        def fits(distance):
            return board_in_view(at(distance), T_base_board, camera, pattern, square, clearance_px, margin_px)

        nearest = near
        if camera is not None:
            if not fits(far):
                continue
            if not fits(near):
                nearest = _nearest_fitting(fits, near, far)
        views.append(at(nearest + u_distance * (far - nearest)))
        if len(views) == wanted:
            break
    if not views:
        raise CalibrationError(f'no viewpoint within {far:.2f} m shows the whole {pattern[0]}x{pattern[1]} board '
                               f'({square * 1000:.0f} mm squares) in the image and clear of the fingers: use a '
                               f'smaller board or allow farther views')
    return views


def _nearest_fitting(fits, near, far):
    """Smallest distance in (near, far] with ``fits(distance)``, given fits(far) and not fits(near) (bisection)."""
    for _ in range(DISTANCE_BISECTIONS):
        middle = 0.5 * (near + far)
        near, far = (near, middle) if fits(middle) else (middle, far)
    return far


def plan_board_views(T_base_board, pattern, square, count=20, distances=(0.25, 0.45), max_tilt_deg=30.0,
                     max_roll_deg=45.0, seed=0, camera=None, clearance_px=None, margin_px=15, aim_px=None):
    """``count`` diverse viewpoints [T_base_camera 4x4] looking at the board centre: the first ``count`` of
    :func:`candidate_views` (same arguments). CalibrationError if fewer fit (with ``camera``)."""
    views = candidate_views(T_base_board, pattern, square, count, distances, max_tilt_deg, max_roll_deg, seed,
                            oversample=1, camera=camera, clearance_px=clearance_px, margin_px=margin_px,
                            aim_px=aim_px)
    if len(views) < count:
        raise CalibrationError(f'only {len(views)} of {count} viewpoints show the whole board: use a smaller '
                               f'board, fewer views or allow farther or less rolled views')
    return views


def view_step_cost(T_base_camera_a, T_base_camera_b):
    """Cost (m) of moving the camera between two poses: the translation plus ``ROTATION_COST_M_PER_RAD`` times
    the rotation angle."""
    translation = np.linalg.norm(T_base_camera_b[:3, 3] - T_base_camera_a[:3, 3])
    angle = Rotation.from_matrix(T_base_camera_a[:3, :3].T @ T_base_camera_b[:3, :3]).magnitude()
    return float(translation + ROTATION_COST_M_PER_RAD * angle)


def order_views(T_base_cameras, T_base_camera_start):
    """The viewpoints reordered into a short path from ``T_base_camera_start``: each next one the nearest (by
    :func:`view_step_cost`) of those not yet visited."""
    remaining = list(T_base_cameras)
    path, current = [], T_base_camera_start
    while remaining:
        index = min(range(len(remaining)), key=lambda i: view_step_cost(current, remaining[i]))
        current = remaining.pop(index)
        path.append(current)
    return path
