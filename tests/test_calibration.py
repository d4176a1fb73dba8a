"""Chessboard calibration: recover the thesis camera from synthetic images through the script.

What the calibration must deliver (README, "On a real Baxter" step 4a, and the depth experiment: "the thesis's
6.2 mm is what a 2 % focal-length error produces: calibrate before blaming the estimator"): intrinsics good
enough for the 1 mm depth target, i.e. focal lengths within 0.33 % (depth scales with f; 1 mm at the
experiment's 0.303 m camera depth), and the ray through every pixel the boards covered within a pixel or so.
"""
import os
import re
import subprocess
import sys

import cv2
import numpy as np
import pytest
import yaml
from scipy.spatial.transform import Rotation

from baxter_pnp.calibration import (board_object_points, calibrate, calibrate_from_corners, conditioning_warnings,
                                    coverage, find_board_corners, load_images)
from baxter_pnp.camera import CameraModel, load_default_camera
from baxter_pnp.runtime import PACKAGE_ROOT
from baxter_pnp.synthetic import render_chessboard
from baxter_pnp.transforms import make_transform, transform_points

SCRIPT = os.path.join(PACKAGE_ROOT, 'scripts', 'calibrate_camera.py')
PATTERN, SQUARE = (9, 6), 0.030
# Image set 4 of 14 boards holds two boards on which findChessboardCorners misplaces one corner by 5-9 px (their
# RMS error 0.7-2 px against 0.05 px for the others): the set exercises the outlier rejection as well. Measured
# over 11 image sets (seeds 0-9 and 2024) with the rejection: focal lengths within 0.13 %, principal point within
# 0.8 px, rays within 1.14 px; without it, 3 of the 11 were 0.2-0.8 % off in focal length.
BOARD_SEED, BOARDS = 4, 14
FOCAL_TOLERANCE = 0.003              # the 0.33 % that costs 1 mm of depth at 0.303 m, rounded down
PRINCIPAL_POINT_TOLERANCE_PX = 1.0   # 0.73 mm sideways at 0.30 m
RAY_TOLERANCE_PX = 1.5               # 1.1 mm sideways at 0.30 m, a third of the 3 mm position target
MISPLACED_CORNER_PX = 1.0            # a detected corner this far from the rendered one is wrong (good: < 0.25 px)


def random_board_pose(rng, camera, max_tilt_deg=40.0, distance_range=(0.35, 0.6), margin_px=8, min_tilt_deg=0.0):
    """T_camera_board facing the camera, tilted (about the image's x and y, each up to ``max_tilt_deg``; in all
    at least ``min_tilt_deg`` from the image plane) and placed at random, the whole board (with margin) in view."""
    cols, rows = PATTERN
    centre = np.array([(cols - 1) / 2, (rows - 1) / 2, 0.0]) * SQUARE
    outline = np.array([[-2, -2, 0], [cols + 1, -2, 0], [cols + 1, rows + 1, 0], [-2, rows + 1, 0]]) * SQUARE
    while True:
        tilt = Rotation.from_rotvec(np.radians(rng.uniform(-max_tilt_deg, max_tilt_deg, 2)).tolist() + [0.0])
        if tilt.magnitude() < np.radians(min_tilt_deg):
            continue
        rotation = tilt * Rotation.from_rotvec([np.pi, 0, 0]) * Rotation.from_rotvec([0, 0, rng.uniform(-0.5, 0.5)])
        position = np.array([*rng.uniform(-0.2, 0.2, 2), 0.0]) + [0, 0, rng.uniform(*distance_range)]
        T = make_transform(rotation, position - rotation.apply(centre))
        pixels = camera.project(transform_points(T, outline))
        if np.all(pixels >= margin_px) and np.all(pixels <= [camera.width - margin_px, camera.height - margin_px]):
            return T


def noisy_corners(seed, count, noise_px=0.2, **pose_ranges):
    """[(name, (N, 1, 2) float32 px)]: the thesis camera's exact corners of ``count`` random board poses
    (``random_board_pose``'s ranges) plus Gaussian noise of ``noise_px`` per axis; and the camera."""
    camera = load_default_camera()
    rng = np.random.default_rng(seed)
    views = []
    for index in range(count):
        T_camera_board = random_board_pose(rng, camera, **pose_ranges)
        pixels = camera.project(transform_points(T_camera_board, board_object_points(PATTERN, SQUARE)))
        pixels += rng.normal(0.0, noise_px, pixels.shape)
        views.append((f'view_{index:02d}', pixels.astype(np.float32).reshape(-1, 1, 2)))
    return views, camera


def run_script(*args):
    return subprocess.run([sys.executable, SCRIPT, *map(str, args)], capture_output=True, text=True, timeout=120)


def misplaced_corner_px(corners_px, true_corners_px):
    """Largest distance (px) from a detected corner (N, 2) to the nearest rendered (true) corner."""
    distances = np.linalg.norm(corners_px[:, None] - true_corners_px[None], axis=2)
    return distances.min(axis=1).max()


def ray_error_px(true, estimated, pixels):
    """(N,) angle between the true and estimated rays through ``pixels`` (distorted, px), in true-camera px."""
    return np.linalg.norm((true.undistort_points(pixels) - estimated.undistort_points(pixels)) * [true.fx, true.fy],
                          axis=1)


def covered_pixels(camera, corner_sets):
    """(N, 2) pixel centres inside the convex hull of every detected board corner (the calibrated region)."""
    hull = cv2.convexHull(np.round(np.vstack(corner_sets)).astype(np.int32))
    mask = cv2.fillConvexPoly(np.zeros((camera.height, camera.width), np.uint8), hull, 1)
    rows, columns = np.nonzero(mask)
    return np.column_stack([columns, rows]).astype(float)


def test_calibration_recovers_the_thesis_camera(tmp_path):
    """The script on 14 rendered boards (two with a misplaced corner) and a blank image: focal lengths within
    0.3 %, principal point within 1 px, every calibrated pixel's ray within 1.5 px; the misplaced boards, and
    only they, left out and named; RMS and per-image errors printed."""
    camera = load_default_camera()
    rng = np.random.default_rng(BOARD_SEED)
    images = tmp_path / 'images'
    images.mkdir()
    misplaced, corner_sets = set(), []
    for index in range(BOARDS):
        image, true_corners_px = render_chessboard(camera, random_board_pose(rng, camera), rng, pattern=PATTERN,
                                                   square=SQUARE)
        name = f'board_{index:02d}.png'
        cv2.imwrite(str(images / name), image)
        corner_sets.append(find_board_corners(image, PATTERN).reshape(-1, 2))    # as the script finds them
        if misplaced_corner_px(corner_sets[-1], true_corners_px) > MISPLACED_CORNER_PX:
            misplaced.add(name)
    assert len(misplaced) == 2                  # premise: the set does exercise the rejection
    cv2.imwrite(str(images / 'blank.png'), np.full((480, 640, 3), 200, np.uint8))
    out = tmp_path / 'calib.yaml'
    result = run_script(images, '--pattern', '9x6', '--square', SQUARE, '-o', out)
    assert result.returncode == 0, result.stderr
    assert 'no board found in: blank.png' in result.stdout
    outlier_lines = [line for line in result.stdout.splitlines() if line.startswith('left out as outliers')]
    assert len(outlier_lines) == 1 and set(re.findall(r'board_\d+\.png', outlier_lines[0])) == misplaced
    assert sum(line.startswith('board_') for line in result.stdout.splitlines()) == BOARDS - len(misplaced)
    assert f'{BOARDS - len(misplaced)} boards, RMS reprojection error' in result.stdout

    calibrated = CameraModel.from_yaml(out)
    for name in ('fx', 'fy'):
        assert getattr(calibrated, name) == pytest.approx(getattr(camera, name), rel=FOCAL_TOLERANCE), name
    for name in ('cx', 'cy'):
        assert getattr(calibrated, name) == pytest.approx(getattr(camera, name), abs=PRINCIPAL_POINT_TOLERANCE_PX)
    region = covered_pixels(camera, corner_sets)
    assert len(region) > 0.25 * camera.width * camera.height           # premise: the boards covered a quarter
    assert ray_error_px(camera, calibrated, region).max() < RAY_TOLERANCE_PX
    rms = yaml.safe_load(out.read_text())['rms_reprojection_error']
    assert 0 < rms < 0.1             # rendered corners are found to ~0.05 px; a misplaced corner makes 0.2-0.6 px
    # The sigmas printed (value, formal, jackknife) cover the focal lengths' actual errors and are plausible: on
    # these renders 0.06 % (formal) and 0.10 % (jackknife) of f, the errors 0.01-0.02 %.
    printed = {line.split()[0]: [float(v) for v in line.split()[1:]] for line in result.stdout.splitlines()
               if re.match(r'(fx|fy|cx|cy|k1|k2|p1|p2|k3) ', line)}
    assert len(printed) == 9
    for name in ('fx', 'fy'):
        value, formal, jackknife = printed[name]
        assert value == pytest.approx(getattr(calibrated, name), abs=1e-5)
        for sigma in (formal, jackknife):
            assert 0.0001 * value < sigma < 0.002 * value, (name, sigma)
            assert abs(value - getattr(camera, name)) < 3 * sigma, (name, sigma)
    assert 'coverage' in result.stdout and 'calibrate_camera: warning' not in result.stdout


def test_empty_directory_fails_clearly(tmp_path):
    result = run_script(tmp_path, '-o', tmp_path / 'out.yaml')
    assert result.returncode != 0
    assert 'no readable image' in result.stderr
    assert not (tmp_path / 'out.yaml').exists()


def test_too_few_boards_and_missing_directory(tmp_path):
    camera = load_default_camera()
    rng = np.random.default_rng(1)
    for index in range(2):
        image, _ = render_chessboard(camera, random_board_pose(rng, camera), rng)
        cv2.imwrite(str(tmp_path / f'{index}.png'), image)
    result = run_script(tmp_path, '-o', tmp_path / 'out.yaml')
    assert result.returncode != 0 and 'found in 2 of 2 images; at least 3' in result.stderr
    result = run_script(tmp_path / 'nowhere', '-o', tmp_path / 'out.yaml')
    assert result.returncode != 0 and 'cannot read the image directory' in result.stderr


# ------------------------------------------------------------------------ uncertainty, coverage, conditioning
STD_SETS, STD_VIEWS = 5, 10          # 5 sets x 4 intrinsics = 20 normalised errors per kind of sigma


def test_reported_sigmas_match_the_actual_errors():
    """On exact corners plus 0.2 px Gaussian noise (known truth), the errors of fx, fy, cx, cy divided by the
    reported 1-sigma (formal and jackknife) have an RMS near 1 and stay within 3 sigma: the sigmas are neither
    over- nor under-confident (a sigma 3x too large gives an RMS of ~0.35, 3x too small ~3)."""
    normalised = {'formal': [], 'jackknife': []}
    for seed in range(STD_SETS):
        views, camera = noisy_corners(seed, STD_VIEWS)
        result = calibrate_from_corners(views, (camera.width, camera.height), PATTERN, SQUARE)
        for name in ('fx', 'fy', 'cx', 'cy'):
            error = getattr(result.camera, name) - getattr(camera, name)
            normalised['formal'].append(error / result.std[name])
            normalised['jackknife'].append(error / result.std_jackknife[name])
    for kind, values in normalised.items():
        rms = float(np.sqrt(np.mean(np.square(values))))
        assert 0.6 < rms < 1.6, (kind, rms)
        assert np.max(np.abs(values)) < 3.0, (kind, values)


def test_coverage_of_a_known_layout():
    """Two 9x6 views in a 640x480 image, numbers worked out by hand from ROS camera_calibration's definitions."""
    cols, rows = PATTERN
    grid = np.mgrid[0:cols, 0:rows].T.reshape(-1, 2).astype(float)          # row by row, as the detector
    straight = grid * 20.0 + [100.0, 50.0]                                   # 160 x 100 px at (100, 50)
    sheared = grid * 30.0 + [300.0, 200.0]                                   # 240 x 150 px ...
    sheared[:, 0] += (sheared[:, 1] - 200.0) * np.tan(np.radians(10.0))     # ... x shifted down the rows: 10 deg
    report = coverage([straight.reshape(-1, 1, 2), sheared], (640, 480), PATTERN)

    border = np.sqrt(160 * 100)
    assert report['per_view'][0] == pytest.approx({'x': (180 - border / 2) / (640 - border),
                                                   'y': (100 - border / 2) / (480 - border),
                                                   'size': np.sqrt(160 * 100 / (640 * 480)), 'skew': 0.0})
    assert report['per_view'][1]['size'] == pytest.approx(np.sqrt(240 * 150 / (640 * 480)))   # shear keeps area
    assert report['per_view'][1]['skew'] == pytest.approx(2 * np.radians(10.0))
    ranges = report['ranges']
    assert ranges['x']['min'] == pytest.approx(report['per_view'][0]['x'])
    assert ranges['x']['max'] == pytest.approx(report['per_view'][1]['x'])
    assert ranges['x']['progress'] == pytest.approx((ranges['x']['max'] - ranges['x']['min']) / 0.7)
    assert ranges['size']['progress'] == pytest.approx(ranges['size']['max'] / 0.4)    # min counted as 0, as ROS
    assert ranges['skew']['progress'] == pytest.approx(2 * np.radians(10.0) / 0.5)
    assert not any(r['good'] for r in ranges.values()) and not report['good']
    warnings = conditioning_warnings([30.0] * 12, report)       # well tilted, enough views: coverage only
    assert len(warnings) == 3
    assert "camera_calibration's x" in warnings[0] and "camera_calibration's y" in warnings[1]
    assert 'look small' in warnings[2]


def tilt_warnings(warnings):
    return [w for w in warnings if 'nearly parallel' in w]


def test_tilt_warning_fires_for_fronto_parallel_views_only():
    """12 views within 10 deg of the image plane: the tilt warning (and the fx-uncertainty one), and fx really is
    worse; 12 views tilted 20-40 deg: neither."""
    results = {}
    for label, ranges in (('parallel', dict(max_tilt_deg=7.0)), ('tilted', dict(min_tilt_deg=20.0, max_tilt_deg=30.0))):
        views, camera = noisy_corners(7, 12, **ranges)
        results[label] = calibrate_from_corners(views, (camera.width, camera.height), PATTERN, SQUARE)
    parallel, tilted = results['parallel'], results['tilted']
    assert max(parallel.per_image_tilt_deg.values()) < 10.0 and min(tilted.per_image_tilt_deg.values()) > 20.0
    assert len(tilt_warnings(parallel.warnings)) == 1 and any('fx is uncertain' in w for w in parallel.warnings)
    assert not tilt_warnings(tilted.warnings) and not any('fx is uncertain' in w for w in tilted.warnings)
    assert abs(parallel.camera.fx / camera.fx - 1) > 3 * abs(tilted.camera.fx / camera.fx - 1)
    assert parallel.std['fx'] > 3 * tilted.std['fx']


def test_tilt_warning_counts_tilted_views():
    """Two views tilted 15 deg or more are not enough; three are."""
    report = {'ranges': {name: {'good': True, 'progress': 1.0} for name in ('x', 'y', 'size', 'skew')}}
    assert tilt_warnings(conditioning_warnings([5.0] * 10 + [20.0] * 2, report))
    assert not tilt_warnings(conditioning_warnings([5.0] * 9 + [20.0] * 3, report))
    assert conditioning_warnings([5.0] * 9 + [20.0] * 3, report) == []


REAL_HAND_B = os.path.join(os.environ.get('BAXTER_PNP_REAL_DATA', os.path.join(PACKAGE_ROOT, '..', 'shared', 'real')),
                           'baxter_hand_b')


@pytest.mark.skipif(not os.path.isdir(REAL_HAND_B), reason=f'no real frames at {REAL_HAND_B}')
def test_real_hand_camera_set_with_nearly_parallel_boards_is_flagged():
    """12 real Baxter hand-camera frames of a 9x6 board, 11 of them tilted under 14 deg: the tilt warning, and the
    jackknife sees fx about 2 % uncertain where the formal sigma says 0.4 %."""
    result = calibrate(load_images(REAL_HAND_B), PATTERN, 0.025)
    assert len(result.per_image_rms_px) == 12
    assert len(tilt_warnings(result.warnings)) == 1
    assert result.std['fx'] < 0.005 * result.camera.fx < result.std_jackknife['fx']
    assert any('fx is uncertain' in w for w in result.warnings)        # from the jackknife's sigma
    assert any('views disagree' in w for w in result.warnings)


def test_fx_warnings_take_the_larger_sigma():
    """The fx-uncertainty warning fires on either sigma over 0.5 % of fx, the views-disagree one when the
    jackknife's is over 3 times the formal one."""
    camera = load_default_camera()
    report = {'ranges': {name: {'good': True, 'progress': 1.0} for name in ('x', 'y', 'size', 'skew')}}
    tilts = [30.0] * 12
    small, large = {'fx': 0.001 * camera.fx}, {'fx': 0.01 * camera.fx}
    assert conditioning_warnings(tilts, report, camera, small, small) == []
    for formal, jackknife in ((large, small), (small, large)):
        assert any('fx is uncertain' in w for w in conditioning_warnings(tilts, report, camera, formal, jackknife))
    assert any('views disagree' in w for w in conditioning_warnings(tilts, report, camera, small, large))
    assert not any('views disagree' in w for w in conditioning_warnings(tilts, report, camera, large, small))
