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

from baxter_pnp.calibration import find_board_corners
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


def random_board_pose(rng, camera, max_tilt_deg=40.0, distance_range=(0.35, 0.6), margin_px=8):
    """T_camera_board facing the camera, tilted and placed at random, the whole board (with margin) in view."""
    cols, rows = PATTERN
    centre = np.array([(cols - 1) / 2, (rows - 1) / 2, 0.0]) * SQUARE
    outline = np.array([[-2, -2, 0], [cols + 1, -2, 0], [cols + 1, rows + 1, 0], [-2, rows + 1, 0]]) * SQUARE
    while True:
        tilt = Rotation.from_rotvec(np.radians(rng.uniform(-max_tilt_deg, max_tilt_deg, 2)).tolist() + [0.0])
        rotation = tilt * Rotation.from_rotvec([np.pi, 0, 0]) * Rotation.from_rotvec([0, 0, rng.uniform(-0.5, 0.5)])
        position = np.array([*rng.uniform(-0.2, 0.2, 2), 0.0]) + [0, 0, rng.uniform(*distance_range)]
        T = make_transform(rotation, position - rotation.apply(centre))
        pixels = camera.project(transform_points(T, outline))
        if np.all(pixels >= margin_px) and np.all(pixels <= [camera.width - margin_px, camera.height - margin_px]):
            return T


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
