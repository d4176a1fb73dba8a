"""Chessboard camera calibration with OpenCV (the thesis's section 3.2 procedure, scriptable).

Corners: ``cv2.findChessboardCorners`` refined by ``cv2.cornerSubPix``; intrinsics: ``cv2.calibrateCamera``
with the 5-coefficient plumb-bob model (k1, k2, p1, p2, k3). A pattern is given as (columns, rows)
of **inner** corners (a 10 x 7-square board is ``9x6``), the square size in metres. Reprojection
errors are RMS distances in pixels. A board whose RMS error is an outlier (over ``OUTLIER_FACTOR`` times the
median of the others and over ``OUTLIER_FLOOR_PX``: typically one corner the detector put on the wrong spot,
which ``cornerSubPix`` cannot pull back from several pixels away) is left out and the calibration redone, one
board at a time, as long as ``MIN_BOARDS`` remain. ``main`` is the ``scripts/calibrate_camera.py`` entry point.

How far to trust the result: ``cv2.calibrateCameraExtended``'s 1-sigma standard deviations of the intrinsics
(from the residuals and the Jacobian at the solution: right when the corners' errors are independent noise); the
leave-one-view-out jackknife's (the spread of the intrinsics over the calibrations without one view each: it also
sees what makes views disagree, a board that is not flat, a print scaled differently along x and y, blur);
``coverage`` of the image by the boards as ROS camera_calibration reports it (x, y, size, skew);
``conditioning_warnings`` when the views cannot pin the intrinsics down (boards nearly parallel to the image, poor
coverage, too few views, an uncertain focal length).
"""
import argparse
import os
import sys
from dataclasses import dataclass, field

import cv2
import numpy as np

from baxter_pnp.camera import CameraModel

IMAGE_EXTENSIONS = ('.png', '.jpg', '.jpeg', '.bmp', '.tif', '.tiff', '.pgm', '.ppm')
MIN_BOARDS = 3
OUTLIER_FACTOR = 3.0       # a board's RMS over this many times the median of the others' ...
OUTLIER_FLOOR_PX = 0.3     # ... and over this (px) is an outlier
_SUBPIX_CRITERIA = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 50, 1e-3)
INTRINSIC_NAMES = ('fx', 'fy', 'cx', 'cy', 'k1', 'k2', 'p1', 'p2', 'k3')   # calibrateCameraExtended's first 9 stds
# Coverage as ROS camera_calibration measures it (calibrator.py): each view's board as x, y, size, skew in [0, 1];
# a parameter is "good" when its range over the views spans at least these (ROS's param_ranges).
COVERAGE_NAMES = ('x', 'y', 'size', 'skew')
COVERAGE_GOOD_RANGE = {'x': 0.7, 'y': 0.7, 'size': 0.4, 'skew': 0.5}
# Conditioning warnings. Simulated (15 views of a 9x6 board of 25 mm squares 0.3-0.5 m away, the fake's 640x400
# camera, corner noise 0.2 px, 30 sets each):
# every board tilted under 15 deg from the image plane: fx off by 1.1 % RMS (3 % at worst; 2.2 % RMS under 10 deg);
# one view tilted 20-35 deg: 0.7 %; three: 0.36 %; all tilted 10-30 deg: 0.30 %; 20-40 deg: 0.17 %. Only a tilted
# board separates the focal length from the board's distance (a fronto-parallel board at twice the distance with
# twice the focal length gives the same image).
TILTED_BOARD_DEG = 15.0        # a board tilted at least this much from the image plane constrains the focal length
MIN_TILTED_BOARDS = 3          # ... and fewer than this many such boards leave it loose
MIN_WELL_CONDITIONED_BOARDS = 10   # OpenCV's tutorial's advice; fewer leave the 9 intrinsics barely overdetermined
MAX_FOCAL_STD_FRACTION = 0.005     # fx's 1-sigma over this: 1.5 mm of depth at 0.3 m (depth scales with f)
# The views disagree when the jackknife's sigma of fx exceeds the formal one this many times: with independent
# corner noise the two agree (simulated as above: jackknife / formal 0.9-1.3 on average); the two real Baxter
# hand-camera sets (../shared/real) give 4.6 and 5.2.
VIEWS_DISAGREE_FACTOR = 3.0


class CalibrationError(ValueError):
    """The images cannot give a calibration (unreadable, too few boards, mixed sizes)."""


@dataclass
class CalibrationResult:
    """A calibrated camera, its overall RMS reprojection error (px) and per-image details."""
    camera: CameraModel
    rms_px: float
    per_image_rms_px: dict = field(default_factory=dict)    # image name -> RMS error (px)
    boards_not_found: list = field(default_factory=list)    # image names without a detected board
    outliers_px: dict = field(default_factory=dict)         # left-out image name -> its RMS error (px) then
    std: dict = field(default_factory=dict)                 # intrinsic name (INTRINSIC_NAMES) -> 1-sigma (px or -)
    std_jackknife: dict = field(default_factory=dict)       # the same from the leave-one-view-out jackknife
    per_image_tilt_deg: dict = field(default_factory=dict)  # image name -> board's tilt from the image plane (deg)
    coverage: dict = field(default_factory=dict)            # see coverage()
    warnings: list = field(default_factory=list)            # see conditioning_warnings()


def board_object_points(pattern, square):
    """(columns * rows, 3) inner-corner positions (m) on the board, row by row, z = 0."""
    cols, rows = pattern
    grid = np.mgrid[0:cols, 0:rows].T.reshape(-1, 2)
    return np.column_stack([grid * square, np.zeros(len(grid))]).astype(np.float32)


def find_board_corners(image, pattern):
    """(N, 1, 2) float32 sub-pixel inner corners of a chessboard in a BGR or grey image, or None."""
    gray = cv2.cvtColor(image, cv2.COLOR_BGR2GRAY) if image.ndim == 3 else image
    found, corners = cv2.findChessboardCorners(gray, tuple(pattern))
    if not found:
        return None
    return cv2.cornerSubPix(gray, corners, (5, 5), (-1, -1), _SUBPIX_CRITERIA)


def calibrate(images, pattern, square, camera_name='left_hand_camera', jackknife=True):
    """Calibrate from ``images``: a list of ``(name, BGR or grey image)``, all of one size (``jackknife``: see
    :func:`calibrate_from_corners`).

    Raises CalibrationError when fewer than ``MIN_BOARDS`` boards are found or the sizes differ.
    """
    sizes = {image.shape[:2] for _, image in images}
    if len(sizes) > 1:
        raise CalibrationError(f'images of different sizes (height, width): {sorted(sizes)}')
    found, missing = [], []
    for name, image in images:
        corners = find_board_corners(image, pattern)
        if corners is None:
            missing.append(name)
        else:
            found.append((name, corners))
    if len(found) < MIN_BOARDS:
        raise CalibrationError(f'a {pattern[0]}x{pattern[1]} chessboard was found in {len(found)} of '
                               f'{len(images)} images; at least {MIN_BOARDS} are needed')
    height, width = sizes.pop()
    result = calibrate_from_corners(found, (width, height), pattern, square, camera_name, jackknife)
    result.boards_not_found = missing
    return result


def calibrate_from_corners(found, image_size, pattern, square, camera_name='left_hand_camera', jackknife=True):
    """Calibrate from detected boards ``found`` = [(name, (N, 1, 2) corners px)] in images of ``image_size`` =
    (width, height) px, leaving out outlier boards (module docstring); with the intrinsics' standard deviations
    (formal, and with ``jackknife`` the jackknife's: one more calibration per view), the coverage and the
    conditioning warnings. CalibrationError with fewer than ``MIN_BOARDS`` boards."""
    if len(found) < MIN_BOARDS:
        raise CalibrationError(f'{len(found)} chessboards given; at least {MIN_BOARDS} are needed')
    object_points = board_object_points(pattern, square)
    outliers = {}
    while True:
        fit = _calibrate_boards(found, object_points, image_size)
        worst = max(fit.per_image_rms_px, key=fit.per_image_rms_px.get)
        others = np.median([error for name, error in fit.per_image_rms_px.items() if name != worst])
        if (len(found) <= MIN_BOARDS
                or fit.per_image_rms_px[worst] <= max(OUTLIER_FACTOR * others, OUTLIER_FLOOR_PX)):
            break
        outliers[worst] = fit.per_image_rms_px[worst]
        found = [(name, corners) for name, corners in found if name != worst]
    camera = CameraModel(*image_size, fit.K, fit.D.ravel()[:5], name=camera_name)
    std_jackknife = _jackknife_std(found, object_points, image_size, fit) if jackknife else {}
    report = coverage([corners for _, corners in found], image_size, pattern)
    warnings = conditioning_warnings(list(fit.tilt_deg.values()), report, camera, fit.std, std_jackknife)
    return CalibrationResult(camera, fit.rms_px, fit.per_image_rms_px, [], outliers, fit.std, std_jackknife,
                             fit.tilt_deg, report, warnings)


@dataclass
class _Fit:
    rms_px: float
    K: np.ndarray
    D: np.ndarray
    per_image_rms_px: dict      # name -> RMS reprojection error (px)
    std: dict                   # INTRINSIC_NAMES -> 1-sigma
    tilt_deg: dict              # name -> board tilt from the image plane (deg)


def _calibrate_boards(found, object_points, size):
    """OpenCV calibration of ``found`` = [(name, corners)] in images of ``size`` = (width, height)."""
    rms, K, D, rvecs, _, std_intrinsics, _, per_view = cv2.calibrateCameraExtended(
        [object_points] * len(found), [c for _, c in found], size, None, None)
    names = [name for name, _ in found]
    tilts = [board_tilt_deg(rvec) for rvec in rvecs]
    return _Fit(float(rms), K, D, dict(zip(names, per_view.ravel().astype(float))),
                dict(zip(INTRINSIC_NAMES, std_intrinsics.ravel()[:len(INTRINSIC_NAMES)].astype(float))),
                dict(zip(names, tilts)))


def _jackknife_std(found, object_points, image_size, fit):
    """INTRINSIC_NAMES -> leave-one-view-out jackknife 1-sigma: sqrt((n - 1) / n * sum((p_i - mean p)^2)) over the
    n calibrations without one view each (started from ``fit``'s intrinsics)."""
    n = len(found)
    estimates = []
    for left_out in range(n):
        corners = [c for index, (_, c) in enumerate(found) if index != left_out]
        _, K, D, _, _ = cv2.calibrateCamera([object_points] * (n - 1), corners, image_size, fit.K.copy(),
                                            fit.D.copy(), flags=cv2.CALIB_USE_INTRINSIC_GUESS)
        estimates.append([K[0, 0], K[1, 1], K[0, 2], K[1, 2], *D.ravel()[:5]])
    estimates = np.array(estimates)
    spread = np.sqrt((n - 1) / n * np.sum((estimates - estimates.mean(axis=0)) ** 2, axis=0))
    return dict(zip(INTRINSIC_NAMES, spread.astype(float)))


def board_tilt_deg(rvec_camera_board):
    """Angle (deg) between a board's plane and the image plane, from its rotation vector in the camera frame."""
    normal_camera = cv2.Rodrigues(np.asarray(rvec_camera_board, dtype=float))[0][:, 2]
    return float(np.degrees(np.arccos(min(1.0, abs(normal_camera[2])))))


def board_view_parameters(corners, image_size, pattern):
    """ROS camera_calibration's description of one view (its ``get_parameters``): dict x, y, size, skew in [0, 1].

    ``corners`` (N, 1, 2) or (N, 2) px, row by row; ``image_size`` (width, height) px. x, y: the corners' mean
    position across the image shrunk by half the board's size each side; size: sqrt(board area / image area), the
    board's area being the outer corners' quadrilateral; skew: 2 |90 deg - the angle at a board corner| (rad),
    at most 1 (a board tilted from the image plane looks skewed).
    """
    cols = pattern[0]
    xy = np.asarray(corners, dtype=float).reshape(-1, 2)
    width, height = image_size
    up_left, up_right, down_right, down_left = xy[0], xy[cols - 1], xy[-1], xy[-cols]
    diagonal_a, diagonal_b = down_right - up_left, down_left - up_right
    area = abs(diagonal_a[0] * diagonal_b[1] - diagonal_a[1] * diagonal_b[0]) / 2.0
    border = np.sqrt(area)
    side_a, side_b = up_left - up_right, down_right - up_right
    angle = np.arccos(np.clip(side_a @ side_b / (np.linalg.norm(side_a) * np.linalg.norm(side_b)), -1.0, 1.0))
    return {'x': float(np.clip((xy[:, 0].mean() - border / 2) / (width - border), 0.0, 1.0)),
            'y': float(np.clip((xy[:, 1].mean() - border / 2) / (height - border), 0.0, 1.0)),
            'size': float(np.sqrt(area / (width * height))),
            'skew': float(min(1.0, 2.0 * abs(np.pi / 2 - angle)))}


def coverage(corners_list, image_size, pattern):
    """How the boards cover the image, as ROS camera_calibration reports it (its ``compute_goodenough``).

    ``corners_list``: each view's corners (N, 1, 2) px; ``image_size`` (width, height) px. Returns
    ``{'per_view': [{x, y, size, skew}], 'ranges': {name: {'min', 'max', 'progress', 'good'}}, 'good': bool}``:
    each parameter's range over the views; progress = (max - min) / COVERAGE_GOOD_RANGE[name], at most 1, with
    min taken as 0 for size and skew (small or straight boards earn nothing, as in ROS); good = progress 1.
    """
    per_view = [board_view_parameters(corners, image_size, pattern) for corners in corners_list]
    ranges = {}
    for name in COVERAGE_NAMES:
        values = [view[name] for view in per_view]
        low = 0.0 if name in ('size', 'skew') else min(values)
        progress = min(1.0, (max(values) - low) / COVERAGE_GOOD_RANGE[name])
        ranges[name] = {'min': min(values), 'max': max(values), 'progress': progress, 'good': progress >= 1.0}
    return {'per_view': per_view, 'ranges': ranges, 'good': all(r['good'] for r in ranges.values())}


def format_coverage(report):
    """The coverage report as text lines: a row per parameter (min, max, progress, good)."""
    lines = ['coverage  min    max    progress']
    for name, r in report['ranges'].items():
        lines.append(f'{name:<8}  {r["min"]:.3f}  {r["max"]:.3f}  {100 * r["progress"]:3.0f} %'
                     + ('' if r['good'] else '   (not enough)'))
    return lines


def conditioning_warnings(board_tilts_deg, coverage_report, camera=None, std=None, std_jackknife=None):
    """Warnings (str) when the views cannot pin the intrinsics down; empty when they are well conditioned.

    ``board_tilts_deg``: each view's board tilt from the image plane (deg, :func:`board_tilt_deg`);
    ``coverage_report``: :func:`coverage`'s; ``camera`` with ``std`` and/or ``std_jackknife`` (INTRINSIC_NAMES ->
    1-sigma) for the focal length's relative uncertainty (the larger of the two). Thresholds: the module's named
    constants.
    """
    warnings = []
    tilts = np.asarray(board_tilts_deg, dtype=float)
    tilted = int(np.sum(tilts >= TILTED_BOARD_DEG))
    if tilted < MIN_TILTED_BOARDS:
        warnings.append(f'the boards are nearly parallel to the image: {tilted} of {len(tilts)} views tilted '
                        f'{TILTED_BOARD_DEG:.0f} deg or more (largest {tilts.max():.0f} deg); the focal length and '
                        f'the board distance are then hardly separable and fx can be a few % off. Add at least '
                        f'{MIN_TILTED_BOARDS} views with the board tilted 20-40 deg from the image plane')
    if len(tilts) < MIN_WELL_CONDITIONED_BOARDS:
        warnings.append(f'only {len(tilts)} views: use at least {MIN_WELL_CONDITIONED_BOARDS}')
    ranges = coverage_report['ranges']
    for name, where in (('x', 'across the image width'), ('y', 'across the image height')):
        if not ranges[name]['good']:
            warnings.append(f'the boards cover {100 * ranges[name]["progress"]:.0f} % of the range needed '
                            f"{where} (ROS camera_calibration's {name}): the lens distortion near the edges is "
                            f'extrapolated; move the board toward the image borders')
    if not ranges['size']['good']:
        warnings.append(f'the boards look small (largest size {ranges["size"]["max"]:.2f} of the image, ROS asks '
                        f'{COVERAGE_GOOD_RANGE["size"]}): add closer views')
    if camera is None:
        return warnings
    fx_std = {label: sigmas['fx'] for label, sigmas in (('formal', std), ('jackknife', std_jackknife)) if sigmas}
    if fx_std and max(fx_std.values()) > MAX_FOCAL_STD_FRACTION * camera.fx:
        warnings.append('fx is uncertain: 1 sigma ' + ', '.join(f'{label} {value:.2f} px '
                                                                 f'({100 * value / camera.fx:.2f} %)'
                                                                 for label, value in fx_std.items())
                        + f' > {100 * MAX_FOCAL_STD_FRACTION:.1f} % of fx: add tilted views and views near the '
                          'image borders')
    if len(fx_std) == 2 and fx_std['jackknife'] > VIEWS_DISAGREE_FACTOR * fx_std['formal']:
        warnings.append(f'the views disagree {fx_std["jackknife"] / fx_std["formal"]:.1f} times more than the '
                        f"corners' noise explains, or a few views alone carry fx (its jackknife vs formal sigma): "
                        f'a board that is not flat, a print not to scale along x or y, blur, too few tilted views? '
                        f'Trust the jackknife sigma')
    return warnings


def load_images(images_dir):
    """Sorted ``[(file name, image)]`` of the image files in ``images_dir``; CalibrationError if none."""
    try:
        names = sorted(n for n in os.listdir(images_dir) if n.lower().endswith(IMAGE_EXTENSIONS))
    except OSError as error:
        raise CalibrationError(f'cannot read the image directory {images_dir}: {error.strerror}') from None
    images, unreadable = [], []
    for name in names:
        image = cv2.imread(os.path.join(images_dir, name), cv2.IMREAD_COLOR)
        if image is None:
            unreadable.append(name)
        else:
            images.append((name, image))
    if unreadable:
        print('could not decode: ' + ', '.join(unreadable), file=sys.stderr)
    if not images:
        raise CalibrationError(f'no readable image ({", ".join(IMAGE_EXTENSIONS)}) in {images_dir}')
    return images


def parse_pattern(text):
    """``'9x6'`` -> (9, 6) inner corners (columns, rows)."""
    try:
        cols, rows = (int(v) for v in text.lower().split('x'))
    except ValueError:
        raise argparse.ArgumentTypeError(f'pattern must look like 9x6 (inner corners), got {text!r}') from None
    if cols < 2 or rows < 2:
        raise argparse.ArgumentTypeError(f'pattern needs at least 2x2 inner corners, got {text!r}')
    return cols, rows


def main(argv=None):
    """``calibrate_camera.py IMAGES_DIR --pattern 9x6 --square 0.030 -o OUT.yaml``; returns the exit status."""
    parser = argparse.ArgumentParser(prog='calibrate_camera.py',
                                     description='Calibrate a camera from chessboard images (OpenCV, plumb-bob '
                                                 'model): intrinsics with their 1-sigma uncertainty, the coverage '
                                                 'of the image, warnings about poorly conditioned views.')
    parser.add_argument('images_dir', metavar='IMAGES_DIR', help='directory of chessboard images, one camera, one size')
    parser.add_argument('--pattern', type=parse_pattern, default=(9, 6),
                        help='inner corners as COLUMNSxROWS (default 9x6)')
    parser.add_argument('--square', type=float, default=0.030, help='square side (m), default 0.030')
    parser.add_argument('--camera-name', default='left_hand_camera', help='camera_name written in the YAML')
    parser.add_argument('-o', '--output', required=True, metavar='OUT.yaml',
                        help='calibration file to write (camera_calibration_parsers YAML)')
    args = parser.parse_args(argv)
    if not args.square > 0:
        parser.error('--square must be positive (metres)')
    try:
        result = calibrate(load_images(args.images_dir), args.pattern, args.square, args.camera_name)
    except CalibrationError as error:
        print(f'calibrate_camera: error: {error}', file=sys.stderr)
        return 1
    for name, error_px in result.per_image_rms_px.items():
        print(f'{name}: {error_px:.3f} px, board tilted {result.per_image_tilt_deg[name]:.1f} deg')
    if result.boards_not_found:
        print('no board found in: ' + ', '.join(result.boards_not_found))
    if result.outliers_px:
        print('left out as outliers (a misplaced corner? check the image): '
              + ', '.join(f'{name} ({error_px:.3f} px)' for name, error_px in result.outliers_px.items()))
    camera, std = result.camera, result.std
    print(f'{len(result.per_image_rms_px)} boards, RMS reprojection error {result.rms_px:.3f} px')
    jackknife = result.std_jackknife
    print('intrinsic    value   1 sigma: formal  jackknife')
    for name, value in zip(INTRINSIC_NAMES, [camera.fx, camera.fy, camera.cx, camera.cy, *camera.D]):
        print(f'{name:<4} {value:13.5f}  {std[name]:14.5f}  {jackknife[name]:9.5f}')
    print('\n'.join(format_coverage(result.coverage)))
    for warning in result.warnings:
        print(f'calibrate_camera: warning: {warning}', file=sys.stderr)
    camera.to_yaml(args.output, rms=result.rms_px)
    print(f'wrote {args.output}')
    return 0
