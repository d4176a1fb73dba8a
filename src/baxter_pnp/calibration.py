"""Chessboard camera calibration with OpenCV (the thesis's section 3.2 procedure, scriptable).

Corners: ``cv2.findChessboardCorners`` refined by ``cv2.cornerSubPix``; intrinsics: ``cv2.calibrateCamera``
with the 5-coefficient plumb-bob model (k1, k2, p1, p2, k3). A pattern is given as (columns, rows)
of **inner** corners (a 10 x 7-square board is ``9x6``), the square size in metres. Reprojection
errors are RMS distances in pixels. A board whose RMS error is an outlier (over ``OUTLIER_FACTOR`` times the
median of the others and over ``OUTLIER_FLOOR_PX``: typically one corner the detector put on the wrong spot,
which ``cornerSubPix`` cannot pull back from several pixels away) is left out and the calibration redone, one
board at a time, as long as ``MIN_BOARDS`` remain. ``main`` is the ``scripts/calibrate_camera.py`` entry point.
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


def calibrate(images, pattern, square, camera_name='left_hand_camera'):
    """Calibrate from ``images``: a list of ``(name, BGR or grey image)``, all of one size.

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
    object_points = board_object_points(pattern, square)
    outliers = {}
    while True:
        rms, K, D, per_image = _calibrate_boards(found, object_points, (width, height))
        worst = max(per_image, key=per_image.get)
        others = np.median([error for name, error in per_image.items() if name != worst])
        if len(found) <= MIN_BOARDS or per_image[worst] <= max(OUTLIER_FACTOR * others, OUTLIER_FLOOR_PX):
            break
        outliers[worst] = per_image[worst]
        found = [(name, corners) for name, corners in found if name != worst]
    camera = CameraModel(width, height, K, D.ravel()[:5], name=camera_name)
    return CalibrationResult(camera, float(rms), per_image, missing, outliers)


def _calibrate_boards(found, object_points, size):
    """OpenCV calibration of ``found`` = [(name, corners)]: (RMS px, K, D, {name: RMS px})."""
    rms, K, D, rvecs, tvecs = cv2.calibrateCamera([object_points] * len(found), [c for _, c in found], size,
                                                  None, None)
    per_image = {}
    for (name, corners), rvec, tvec in zip(found, rvecs, tvecs):
        projected, _ = cv2.projectPoints(object_points, rvec, tvec, K, D)
        per_image[name] = float(np.sqrt(np.mean(np.sum((projected - corners) ** 2, axis=2))))
    return rms, K, D, per_image


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
                                     description='Calibrate a camera from chessboard images (OpenCV, plumb-bob model).')
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
        print(f'{name}: {error_px:.3f} px')
    if result.boards_not_found:
        print('no board found in: ' + ', '.join(result.boards_not_found))
    if result.outliers_px:
        print('left out as outliers (a misplaced corner? check the image): '
              + ', '.join(f'{name} ({error_px:.3f} px)' for name, error_px in result.outliers_px.items()))
    camera = result.camera
    print(f'{len(result.per_image_rms_px)} boards, RMS reprojection error {result.rms_px:.3f} px')
    print(f'fx {camera.fx:.5f}  fy {camera.fy:.5f}  cx {camera.cx:.5f}  cy {camera.cy:.5f}')
    print('D (k1, k2, p1, p2, k3) = ' + ', '.join(f'{v:.5f}' for v in camera.D))
    camera.to_yaml(args.output, rms=result.rms_px)
    print(f'wrote {args.output}')
    return 0
