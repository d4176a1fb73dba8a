"""Hand-eye calibration from chessboard views: the camera's mount on the hand, the board (table) in ``base``.

Input: views of one chessboard lying still on the table, each with the hand's pose in ``base`` at the image's
stamp (``BoardView``). Per view ``cv2.solvePnP`` (IPPE, planar board) gives the board in the camera; OpenCV's
``cv2.calibrateHandEye`` (AX = XB) with each of its methods gives start values for the mount ``T_hand_camera``;
the one that reprojects best starts a joint least-squares refinement (``scipy.optimize.least_squares``) of the
reprojection error of every corner of every view over the mount, the board's pose in ``base`` and, on request,
the intrinsics (``REFINED_INTRINSICS``). Views that reproject far worse than the others are dropped one at a time
(a misdetected board, a bad stamp). Boards that look the same turned by 180 deg (an even number of inner corners
in all, e.g. 8x6) are refused: their corner order can flip between views. The uncertainty is the refinement's
covariance ``(J^T J)^-1 s^2`` (``s^2`` the residual variance per coordinate, degrees of freedom counted): it
assumes independent corner noise and exact hand poses.

Frames: ``<side>_hand`` (the hand, Baxter's endpoint parent), ``<side>_hand_camera`` (the camera optical frame:
x right, y down, z forward), ``base``, and the board frame of ``calibration.board_object_points`` (origin at the
first inner corner, x along the columns, y along the rows, z = 0 on the printed surface). Metres, radians inside;
files and reports in mm and degrees where named so.

The result file (``write_hand_eye``, ``load_hand_eye``) is a YAML mapping::

    {parent_frame: left_hand, child_frame: left_hand_camera, translation: [x, y, z] (m),
     rotation_xyzw: [x, y, z, w], rms_px, views, std_mm, std_deg, table_plane: {normal: [..], offset: ..}, stamp}
"""
import datetime
import os
import tempfile
from dataclasses import dataclass
from typing import Optional

import cv2
import numpy as np
import yaml
from scipy.optimize import least_squares
from scipy.spatial.transform import Rotation

from baxter_pnp.calibration import CalibrationError, board_object_points
from baxter_pnp.camera import CameraModel
from baxter_pnp.transforms import invert, make_transform, to_xyz_quat

MIN_VIEWS = 6                  # views with the board found, after outlier rejection
MAX_RMS_PX = 2.0               # a final RMS reprojection error over this: the views do not agree
MIN_PAIR_ROTATION_DEG = 5.0    # relative hand rotations smaller than this say nothing about their axis ...
MIN_AXIS_SPREAD_DEG = 20.0     # ... and the axes of the larger ones must spread over at least this angle
MAX_MOUNT_OFFSET_M = 0.5       # a hand camera further than this from the hand is a unit mistake (mm for m?)
UNIT_NORM_TOLERANCE = 1e-3     # a quaternion or normal this close to unit length is normalised, else refused
# The intrinsics refined with refine_intrinsics=True: focal lengths, principal point and radial distortion k1, k2;
# a real lens differs from its published calibration in all of them (the fake's only in focal length). With
# known hand motions the run pins the focal lengths well (20 views: 0.04 % 1-sigma). Freeing the principal point
# doubles the mount's rotation uncertainty (it is nearly interchangeable with a small camera rotation: 1 px ~
# 0.14 deg at 410 px), still far below 0.1 deg. Tangential p1, p2 (small, and nearly interchangeable with the
# principal point) and k3 (with k1, k2 over this lens's +-38 deg field) stay fixed. Pass a tuple of names (e.g.
# ('fx', 'fy') after a separate lens calibration) to refine fewer.
REFINED_INTRINSICS = ('fx', 'fy', 'cx', 'cy', 'k1', 'k2')
_INTRINSIC_ENTRIES = {'fx': ('K', (0, 0)), 'fy': ('K', (1, 1)), 'cx': ('K', (0, 2)), 'cy': ('K', (1, 2)),
                      'k1': ('D', 0), 'k2': ('D', 1)}
OPENCV_METHODS = {'TSAI': cv2.CALIB_HAND_EYE_TSAI, 'PARK': cv2.CALIB_HAND_EYE_PARK,
                  'HORAUD': cv2.CALIB_HAND_EYE_HORAUD, 'ANDREFF': cv2.CALIB_HAND_EYE_ANDREFF,
                  'DANIILIDIS': cv2.CALIB_HAND_EYE_DANIILIDIS}
FILE_KEYS = ('parent_frame', 'child_frame', 'translation', 'rotation_xyzw', 'rms_px', 'views', 'std_mm',
             'std_deg', 'table_plane', 'stamp')
REQUIRED_FILE_KEYS = ('parent_frame', 'child_frame', 'translation', 'rotation_xyzw')
SIDES = ('left', 'right')


class HandEyeError(CalibrationError):
    """The views cannot give a hand-eye calibration, or a calibration file is unusable; the message says why."""


@dataclass(frozen=True)
class BoardView:
    """One image's chessboard and the hand's pose when it was taken."""
    T_base_hand: np.ndarray    # 4x4: the <side>_hand frame in base at the image's stamp (m)
    corners_px: np.ndarray     # (N, 2) sub-pixel inner corners (image px), in board_object_points order
    name: str = ''             # e.g. 'view_07'


@dataclass
class HandEyeResult:
    """A solved hand-eye calibration; ``*_px`` are RMS reprojection errors (px), ``std_*`` 1-sigma values."""
    T_hand_camera: np.ndarray          # 4x4, the camera optical frame in <side>_hand (m)
    T_base_board: np.ndarray           # 4x4, the board frame (board_object_points' frame) in base
    camera: CameraModel                # refined intrinsics when asked, else the input camera
    rms_px: float                      # RMS reprojection error over the views kept
    per_view_rms_px: dict              # view name -> RMS px (kept views)
    outliers_px: dict                  # rejected view name -> its RMS px when rejected
    std_translation_mm: np.ndarray     # (3,) 1-sigma of T_hand_camera's translation, per axis of <side>_hand
    std_rotation_deg: np.ndarray       # (3,) 1-sigma of its rotation (small-angle vector, hand axes)
    std_mm: float                      # norm of std_translation_mm (the 1-sigma radius)
    std_deg: float                     # norm of std_rotation_deg
    focal_std_fraction: Optional[float]  # 1-sigma of the refined focal lengths / focal length (None: not refined)
    methods: dict                      # OpenCV method name -> (translation mm, rotation deg) from the final result
    table_plane: tuple                 # (normal (3,) unit up, offset m): the table top under the board in base,
                                       # normal . x = offset (the board's printed plane minus board_thickness)
    views_used: int
    start_method: str = ''             # the OpenCV method whose result started the refinement


@dataclass(frozen=True)
class HandEyeCalibration:
    """A hand-eye calibration file's content (``load_hand_eye``); statistics are None when the file has none."""
    parent_frame: str
    child_frame: str
    T_parent_child: np.ndarray         # 4x4 (m)
    table_plane: Optional[tuple]       # (normal (3,) unit, offset m) or None
    rms_px: Optional[float]
    std_mm: Optional[float]
    std_deg: Optional[float]
    views: Optional[int]
    stamp: Optional[str] = None


# ----------------------------------------------------------------------------------------------- solving
def solve_hand_eye(views, camera, pattern, square, refine_intrinsics=False, board_thickness=0.0,
                   outlier_factor=3.0, outlier_floor_px=0.5, min_views=MIN_VIEWS):
    """Solve the camera mount ``T_hand_camera`` and the board's pose in base from ``views`` (``BoardView``s).

    ``camera``: the intrinsics (``CameraModel``) the corners were measured with; ``pattern`` (columns, rows) of
    inner corners and ``square`` (m) as for ``board_object_points``; ``refine_intrinsics``: False, True (refine
    ``REFINED_INTRINSICS`` too) or a tuple of names among them; ``board_thickness`` (m): the printed surface's
    height above the table. A view whose RMS error is over ``outlier_factor`` times the median of the others and
    over ``outlier_floor_px`` is dropped and the solve redone, one at a time, while ``min_views`` remain.
    Raises HandEyeError (too few views, wrong corner count, degenerate motion, views that do not agree).
    """
    object_points = _checked_board(pattern, square)
    intrinsics = _checked_intrinsics(refine_intrinsics)
    if min_views < 3:
        raise HandEyeError(f'min_views must be at least 3, got {min_views}')
    views = _checked_views(views, len(object_points))
    if len(views) < min_views:
        raise HandEyeError(f'{len(views)} views with the board found; at least {min_views} are needed '
                           '(is the board in view of every pose? is the pattern right?)')
    outliers = {}
    while True:
        check_motion([view.T_base_hand for view in views])
        solution = _solve(views, camera, object_points, intrinsics)
        per_view = solution.per_view_rms_px
        worst = max(per_view, key=per_view.get)
        others = float(np.median([rms for name, rms in per_view.items() if name != worst]))
        if len(views) <= min_views or per_view[worst] <= max(outlier_factor * others, outlier_floor_px):
            break
        outliers[worst] = per_view[worst]
        views = [view for view in views if view.name != worst]
    if solution.rms_px > MAX_RMS_PX:
        raise HandEyeError(
            f'the views do not agree: RMS reprojection error {solution.rms_px:.2f} px over {len(views)} views '
            f'(at most {MAX_RMS_PX} px; worst {worst} at {per_view[worst]:.2f} px): the board moved during the '
            'run, or the hand poses are not those of the images (stamps, wrong arm)')
    return _result(solution, outliers, board_thickness)


def check_motion(T_base_hands):
    """HandEyeError unless the hand poses (4x4, in base) rotate enough, about at least two distinct axes.

    The relative rotations between pairs of poses larger than ``MIN_PAIR_ROTATION_DEG`` give axes (in hand
    coordinates, where AX = XB compares them); their largest angle to each other must reach
    ``MIN_AXIS_SPREAD_DEG``: rotations about one axis leave the mount's translation along it undetermined.
    """
    rotations = Rotation.from_matrix(np.array([np.asarray(T, dtype=float)[:3, :3] for T in T_base_hands]))
    first, second = np.triu_indices(len(rotations), k=1)
    if len(first) == 0:
        raise HandEyeError('the motion needs at least two hand poses')
    relative = (rotations[first].inv() * rotations[second]).as_rotvec()
    angles = np.linalg.norm(relative, axis=1)
    largest = np.degrees(angles.max())
    turning = angles > np.radians(MIN_PAIR_ROTATION_DEG)
    if not np.any(turning):
        raise HandEyeError(f'the hand barely rotates between views (largest rotation {largest:.1f} deg, not over '
                           f'{MIN_PAIR_ROTATION_DEG:.0f} deg): tilt it by 10-30 deg about different axes between '
                           'views; translations alone cannot determine the camera mount')
    axes = relative[turning] / angles[turning, None]
    cosines = np.clip(np.abs(axes @ axes.T), 0.0, 1.0)
    spread = np.degrees(np.arccos(cosines.min()))
    if spread < MIN_AXIS_SPREAD_DEG:
        axis = np.round(axes[0] * np.sign(axes[0][np.argmax(np.abs(axes[0]))]), 2).tolist()
        raise HandEyeError(f'all rotations about nearly parallel axes (within {spread:.1f} deg of each other, '
                           f'about hand axis {axis}; at least {MIN_AXIS_SPREAD_DEG:.0f} deg apart are needed): '
                           'the mount cannot be determined along that axis; tilt the hand about two different '
                           'axes between views')


def _checked_board(pattern, square):
    """The board's object points (N, 3) float64; HandEyeError for a bad or symmetric pattern."""
    cols, rows = (int(n) for n in pattern)
    if cols < 2 or rows < 2 or not square > 0:
        raise HandEyeError(f'a board needs at least 2x2 inner corners and a positive square size, got '
                           f'{cols}x{rows}, {square} m')
    if (cols + rows) % 2 == 0:
        raise HandEyeError(f'a {cols}x{rows} board looks the same turned by 180 deg, so its corner order can flip '
                           'between views; use one with an odd and an even number of inner corners (e.g. 9x6)')
    return board_object_points((cols, rows), square).astype(np.float64)


def _checked_intrinsics(refine_intrinsics):
    """The names of the intrinsics to refine (a tuple, maybe empty); HandEyeError for an unknown name."""
    if refine_intrinsics is True:
        return REFINED_INTRINSICS
    names = tuple(refine_intrinsics or ())
    unknown = [name for name in names if name not in REFINED_INTRINSICS]
    if unknown or len(set(names)) != len(names):
        raise HandEyeError(f'refine_intrinsics: {list(names)} must be distinct names among {REFINED_INTRINSICS}')
    return names


def _checked_views(views, corner_count):
    """The views with float arrays and unique names ('view_NN' when unnamed); HandEyeError naming a bad one."""
    checked, names = [], set()
    for index, view in enumerate(views):
        name = view.name or f'view_{index:02d}'
        T = np.asarray(view.T_base_hand, dtype=float)
        corners = np.asarray(view.corners_px, dtype=float).reshape(-1, 2)
        if T.shape != (4, 4) or not np.all(np.isfinite(T)) or not np.allclose(T[:3, :3] @ T[:3, :3].T, np.eye(3),
                                                                               atol=1e-6):
            raise HandEyeError(f'{name}: T_base_hand must be a finite 4x4 rigid transform')
        if len(corners) != corner_count or not np.all(np.isfinite(corners)):
            raise HandEyeError(f'{name}: {len(corners)} corners, the board has {corner_count} '
                               '(wrong pattern, or a partly seen board)')
        if name in names:
            raise HandEyeError(f'two views are named {name!r}')
        names.add(name)
        checked.append(BoardView(T, corners, name))
    return checked


@dataclass
class _Solution:
    """One solve's estimate (see HandEyeResult) with its parameters' covariance (``_JointModel`` order)."""
    T_hand_camera: np.ndarray
    T_base_board: np.ndarray
    camera: CameraModel
    intrinsics: tuple
    covariance: np.ndarray
    rms_px: float
    per_view_rms_px: dict
    methods: dict
    start_method: str


def _solve(views, camera, object_points, intrinsics):
    """One solve of ``views``: the OpenCV methods' starts, the best one refined jointly (``_Solution``)."""
    T_base_hands = np.array([view.T_base_hand for view in views])
    T_hand_bases = np.array([invert(T) for T in T_base_hands])
    corners = np.array([view.corners_px for view in views])
    T_camera_boards = [_board_in_camera(view.corners_px, camera, object_points) for view in views]
    starts = {}
    for method_name, method in OPENCV_METHODS.items():
        T_hand_camera = _opencv_hand_eye(T_base_hands, T_camera_boards, method)
        if T_hand_camera is not None:
            T_base_board = _mean_pose([T_hand @ T_hand_camera @ T for T_hand, T in zip(T_base_hands, T_camera_boards)])
            rms = _rms(_residuals_px(T_hand_camera, T_base_board, camera, T_hand_bases, object_points, corners))
            starts[method_name] = (T_hand_camera, T_base_board, rms)
    if not starts:
        raise HandEyeError('no OpenCV hand-eye method gave a solution: the motion is degenerate')
    start_method = min(starts, key=lambda name: starts[name][2])
    model = _JointModel(camera, starts[start_method][0], starts[start_method][1], intrinsics)
    fit = least_squares(model.residuals, np.zeros(model.size), args=(T_hand_bases, object_points, corners),
                        x_scale='jac', method='lm')
    if not fit.success:
        raise HandEyeError(f'the joint refinement did not converge ({fit.message})')
    T_hand_camera, T_base_board, refined_camera = model.unpack(fit.x)
    residuals = fit.fun.reshape(len(views), -1)
    per_view_rms_px = {view.name: _rms(r) for view, r in zip(views, residuals)}
    methods = {name: _pose_distance(start[0], T_hand_camera) for name, start in starts.items()}
    return _Solution(T_hand_camera, T_base_board, refined_camera, intrinsics,
                     _covariance(fit.jac, fit.fun, model.size), _rms(residuals), per_view_rms_px, methods, start_method)


def _covariance(jacobian, residuals, parameter_count):
    """Parameter covariance (J^T J)^-1 s^2, s^2 = residual variance (dof-corrected); HandEyeError if singular."""
    column_norms = np.linalg.norm(jacobian, axis=0)
    normalised = jacobian / column_norms
    if not np.all(column_norms > 0) or np.linalg.cond(normalised) > 1e6:
        raise HandEyeError('the views cannot determine the mount (singular refinement): tilt the hand more, about '
                           'different axes, and vary the distance to the board')
    variance = residuals @ residuals / (len(residuals) - parameter_count)
    return np.linalg.inv(normalised.T @ normalised) / np.outer(column_norms, column_norms) * variance


def board_pose_in_camera(corners_px, camera, pattern, square):
    """T_camera_board (4x4, m) of one board's (N, 2) or (N, 1, 2) corners (px, ``board_object_points`` order)
    seen by ``camera``: planar PnP (IPPE) with the camera's distortion. HandEyeError for a wrong corner count."""
    object_points = _checked_board(pattern, square)
    corners_px = np.asarray(corners_px, dtype=float).reshape(-1, 2)
    if len(corners_px) != len(object_points):
        raise HandEyeError(f'{len(corners_px)} corners, the board has {len(object_points)}')
    return _board_in_camera(corners_px, camera, object_points)


def _board_in_camera(corners_px, camera, object_points):
    """T_camera_board (4x4) of (N, 2) corners (px) by planar PnP (IPPE) with the camera's distortion."""
    found, rvec, tvec = cv2.solvePnP(object_points, corners_px.reshape(-1, 1, 2), camera.K, camera.D,
                                     flags=cv2.SOLVEPNP_IPPE)
    if not found:
        raise HandEyeError('the board pose could not be computed from its corners')
    return make_transform(Rotation.from_rotvec(rvec.ravel()), tvec.ravel())


def _opencv_hand_eye(T_base_hands, T_camera_boards, method):
    """T_hand_camera (4x4) from ``cv2.calibrateHandEye`` (gripper = hand), or None if the method fails."""
    try:
        R, t = cv2.calibrateHandEye([T[:3, :3] for T in T_base_hands], [T[:3, 3] for T in T_base_hands],
                                    [T[:3, :3] for T in T_camera_boards], [T[:3, 3] for T in T_camera_boards],
                                    method=method)
    except cv2.error:
        return None
    if not (np.all(np.isfinite(R)) and np.all(np.isfinite(t))) or abs(np.linalg.det(R) - 1.0) > 1e-3:
        return None
    return make_transform(Rotation.from_matrix(R), np.ravel(t))


def _mean_pose(transforms):
    """The mean (rotation mean, mean translation) of 4x4 transforms."""
    transforms = np.asarray(transforms)
    return make_transform(Rotation.from_matrix(transforms[:, :3, :3]).mean(), transforms[:, :3, 3].mean(axis=0))


class _JointModel:
    """Parameters of the joint refinement, as offsets from a start: the mount's rotation (small-angle vector in
    hand axes, rad) and translation (m, hand axes), the board's (base axes), then the refined intrinsics (px)."""

    def __init__(self, camera, T_hand_camera, T_base_board, intrinsics):
        self.camera, self.T_hand_camera, self.T_base_board = camera, T_hand_camera, T_base_board
        self.intrinsics = tuple(intrinsics)
        self.size = 12 + len(self.intrinsics)

    def unpack(self, x):
        """(T_hand_camera, T_base_board, CameraModel) for the parameter vector ``x``."""
        def moved(T, rotvec, translation):
            rotation = Rotation.from_rotvec(rotvec) * Rotation.from_matrix(T[:3, :3])
            return make_transform(rotation, T[:3, 3] + translation)
        camera = self.camera
        if self.intrinsics:
            K, D = camera.K.copy(), camera.D.copy()
            for name, delta in zip(self.intrinsics, x[12:]):
                matrix, index = _INTRINSIC_ENTRIES[name]
                (K if matrix == 'K' else D)[index] += delta
            camera = CameraModel(camera.width, camera.height, K, D, camera.name, camera.frame_id)
        return moved(self.T_hand_camera, x[0:3], x[3:6]), moved(self.T_base_board, x[6:9], x[9:12]), camera

    def residuals(self, x, T_hand_bases, object_points, corners):
        """(views * N * 2,) reprojection residuals (px) at ``x`` (see ``_residuals_px``)."""
        return _residuals_px(*self.unpack(x), T_hand_bases, object_points, corners).ravel()


def _residuals_px(T_hand_camera, T_base_board, camera, T_hand_bases, object_points, corners):
    """(views, N, 2) projected minus measured corners (px); ``T_hand_bases``: (views, 4, 4) inverse hand poses."""
    T_camera_boards = invert(T_hand_camera) @ T_hand_bases @ T_base_board
    points_camera = object_points @ T_camera_boards[:, :3, :3].transpose(0, 2, 1) + T_camera_boards[:, None, :3, 3]
    projected, _ = cv2.projectPoints(points_camera.reshape(-1, 1, 3), np.zeros(3), np.zeros(3), camera.K, camera.D)
    return projected.reshape(corners.shape) - corners


def _rms(residuals_px):
    """RMS distance (px) of residual vectors (..., 2)."""
    return float(np.sqrt(np.mean(np.sum(np.reshape(residuals_px, (-1, 2)) ** 2, axis=1))))


def _pose_distance(T_a, T_b):
    """(translation mm, rotation deg) between two poses."""
    return (float(np.linalg.norm(T_a[:3, 3] - T_b[:3, 3]) * 1000.0),
            float(np.degrees(Rotation.from_matrix(T_a[:3, :3].T @ T_b[:3, :3]).magnitude())))


def _result(solution, outliers, board_thickness):
    """HandEyeResult of the final ``_Solution``."""
    variances = np.diag(solution.covariance)
    std_rotation_deg = np.degrees(np.sqrt(variances[0:3]))
    std_translation_mm = np.sqrt(variances[3:6]) * 1000.0
    focal = {'fx': solution.camera.fx, 'fy': solution.camera.fy}
    focal_fractions = [np.sqrt(variances[12 + i]) / focal[name] for i, name in enumerate(solution.intrinsics)
                       if name in focal]
    T_base_board = solution.T_base_board
    normal = T_base_board[:3, 2] * np.sign(T_base_board[2, 2])
    offset = float(normal @ T_base_board[:3, 3]) - board_thickness
    return HandEyeResult(
        T_hand_camera=solution.T_hand_camera, T_base_board=T_base_board,
        camera=solution.camera, rms_px=solution.rms_px,
        per_view_rms_px=solution.per_view_rms_px, outliers_px=outliers,
        std_translation_mm=std_translation_mm, std_rotation_deg=std_rotation_deg,
        std_mm=float(np.linalg.norm(std_translation_mm)), std_deg=float(np.linalg.norm(std_rotation_deg)),
        focal_std_fraction=float(max(focal_fractions)) if focal_fractions else None, methods=solution.methods,
        table_plane=(normal, offset), views_used=len(solution.per_view_rms_px), start_method=solution.start_method)


# ----------------------------------------------------------------------------------------------- files
def write_hand_eye(path, result, side='left', stamp=None):
    """Write ``result`` (a HandEyeResult) as the hand-eye YAML for ``side``'s hand, atomically.

    The file is written to a temporary file beside ``path``, flushed to disk and renamed over ``path``: a failed
    write leaves no file (and an older ``path`` intact). ``stamp``: any string, default the current local time
    (ISO 8601). HandEyeError for a bad side, a non-finite result or an I/O error.
    """
    if stamp is None:
        stamp = datetime.datetime.now().astimezone().isoformat(timespec='seconds')
    if side not in SIDES:
        raise HandEyeError(f'side must be one of {SIDES}, got {side!r}')
    xyz, quat = to_xyz_quat(result.T_hand_camera)
    normal, offset = result.table_plane
    numbers = np.concatenate([xyz, quat, normal, [offset, result.rms_px, result.std_mm, result.std_deg]])
    if not np.all(np.isfinite(numbers)):
        raise HandEyeError(f'not writing {path}: the result has non-finite values')
    content = {
        'parent_frame': f'{side}_hand', 'child_frame': f'{side}_hand_camera',
        'translation': [round(float(v), 6) for v in xyz],
        'rotation_xyzw': [round(float(v), 8) for v in quat],
        'rms_px': round(float(result.rms_px), 4), 'views': int(result.views_used),
        'std_mm': round(float(result.std_mm), 4), 'std_deg': round(float(result.std_deg), 5),
        'table_plane': {'normal': [round(float(v), 8) for v in normal], 'offset': round(float(offset), 6)},
        'stamp': str(stamp),
    }
    text = yaml.safe_dump(content, default_flow_style=None, sort_keys=False)
    directory = os.path.dirname(os.path.abspath(path))
    temporary = None
    try:
        with tempfile.NamedTemporaryFile('w', dir=directory, prefix='.' + os.path.basename(path) + '.',
                                         suffix='.tmp', delete=False) as f:
            temporary = f.name
            f.write(text)
            f.flush()
            os.fsync(f.fileno())
        os.replace(temporary, path)
    except OSError as error:
        if temporary is not None and os.path.exists(temporary):
            os.remove(temporary)
        raise HandEyeError(f'cannot write {path}: {error.strerror or error}') from None


def load_hand_eye(path):
    """The HandEyeCalibration in a hand-eye YAML file; HandEyeError naming the key for anything wrong.

    Required keys: parent_frame and child_frame (``<side>_hand`` and ``<side>_hand_camera``, one side),
    translation (3 numbers, m), rotation_xyzw (a unit quaternion; normalised when within 1e-3 of unit);
    optional: rms_px, views, std_mm, std_deg, table_plane ({normal: unit 3-vector, offset: m}), stamp.
    """
    try:
        with open(path) as f:
            content = yaml.safe_load(f)
    except OSError as error:
        raise HandEyeError(f'cannot read the hand-eye file {path}: {error.strerror or error}') from None
    except yaml.YAMLError as error:
        raise HandEyeError(f'{path}: not valid YAML: {error}') from None

    def bad(key, why):
        return HandEyeError(f'hand-eye file {path}: {key}: {why}')
    if not isinstance(content, dict):
        raise HandEyeError(f'hand-eye file {path}: not a mapping of {", ".join(REQUIRED_FILE_KEYS)}, ...')
    unknown = sorted(set(content) - set(FILE_KEYS))
    if unknown:
        raise bad(unknown[0], f'unknown key (known: {", ".join(FILE_KEYS)})')
    for key in REQUIRED_FILE_KEYS:
        if key not in content:
            raise bad(key, 'missing')
    parents = {f'{side}_hand': side for side in SIDES}
    if content['parent_frame'] not in parents:
        raise bad('parent_frame', f'must be left_hand or right_hand, got {content["parent_frame"]!r}')
    side = parents[content['parent_frame']]
    if content['child_frame'] != f'{side}_hand_camera':
        raise bad('child_frame', f'must be {side}_hand_camera (the parent is {side}_hand), '
                                 f'got {content["child_frame"]!r}')
    translation = _vector(content, 'translation', 3, bad)
    if np.linalg.norm(translation) > MAX_MOUNT_OFFSET_M:
        raise bad('translation', f'{np.linalg.norm(translation):.3f} m from the hand is no hand camera mount '
                                 '(metres expected)')
    quat = _vector(content, 'rotation_xyzw', 4, bad)
    if abs(np.linalg.norm(quat) - 1.0) > UNIT_NORM_TOLERANCE:
        raise bad('rotation_xyzw', f'not a unit quaternion (norm {np.linalg.norm(quat):.6f}); order is x, y, z, w')
    table_plane = None
    if content.get('table_plane') is not None:
        plane = content['table_plane']
        if not isinstance(plane, dict) or set(plane) != {'normal', 'offset'}:
            raise bad('table_plane', 'must be a mapping {normal: [x, y, z], offset: m}')

        def bad_plane(key, why):
            return bad('table_plane.' + key, why)
        normal = _vector(plane, 'normal', 3, bad_plane)
        if abs(np.linalg.norm(normal) - 1.0) > UNIT_NORM_TOLERANCE:
            raise bad_plane('normal', f'not a unit vector (norm {np.linalg.norm(normal):.6f})')
        table_plane = (normal / np.linalg.norm(normal), _number(plane, 'offset', bad_plane))
    statistics = {key: _number(content, key, bad, minimum=0.0) if content.get(key) is not None else None
                  for key in ('rms_px', 'std_mm', 'std_deg', 'views')}
    if statistics['views'] is not None:
        if statistics['views'] != int(statistics['views']) or statistics['views'] < 1:
            raise bad('views', f'must be a positive whole number, got {content["views"]!r}')
        statistics['views'] = int(statistics['views'])
    stamp = content.get('stamp')
    return HandEyeCalibration(content['parent_frame'], content['child_frame'],
                              make_transform(Rotation.from_quat(quat / np.linalg.norm(quat)), translation),
                              table_plane, stamp=None if stamp is None else str(stamp), **statistics)


def _vector(mapping, key, length, bad):
    """(length,) float array of ``mapping[key]``, or ``bad(key, why)`` raised."""
    value = mapping[key]
    try:
        vector = np.array(value, dtype=float)
    except (TypeError, ValueError):
        raise bad(key, f'must be {length} finite numbers, got {value!r}') from None
    if vector.shape != (length,) or not np.all(np.isfinite(vector)):
        raise bad(key, f'must be {length} finite numbers, got {value!r}')
    return vector


def _number(mapping, key, bad, minimum=-np.inf):
    """``mapping[key]`` as a finite float >= ``minimum``, or ``bad(key, why)`` raised."""
    value = mapping[key]
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not np.isfinite(value) or value < minimum:
        raise bad(key, f'must be a finite number{" >= %g" % minimum if minimum > -np.inf else ""}, got {value!r}')
    return float(value)


def static_transform_publisher_line(calibration_or_result, side='left'):
    """A launch-file ``<node>`` line publishing the mount with tf2_ros' static_transform_publisher.

    Takes a HandEyeCalibration (its own frames) or a HandEyeResult (frames of ``side``). The URDF's
    robot_state_publisher publishes the same edge: launch it without that joint or let the application read the
    file instead (``--hand-eye``).
    """
    if isinstance(calibration_or_result, HandEyeCalibration):
        parent, child = calibration_or_result.parent_frame, calibration_or_result.child_frame
        T = calibration_or_result.T_parent_child
    else:
        if side not in SIDES:
            raise HandEyeError(f'side must be one of {SIDES}, got {side!r}')
        parent, child, T = f'{side}_hand', f'{side}_hand_camera', calibration_or_result.T_hand_camera
    xyz, quat = to_xyz_quat(T)
    args = ' '.join(f'{v:.6f}' for v in xyz) + ' ' + ' '.join(f'{v:.8f}' for v in quat)
    return (f'<node pkg="tf2_ros" type="static_transform_publisher" name="{child}_calibration" '
            f'args="{args} {parent} {child}"/>')
