"""Chessboard calibration: recover the thesis camera from synthetic images through the script."""
import os
import subprocess
import sys

import cv2
import numpy as np
import pytest
import yaml
from scipy.spatial.transform import Rotation

from baxter_pnp.camera import CameraModel, load_default_camera
from baxter_pnp.runtime import PACKAGE_ROOT
from baxter_pnp.synthetic import render_chessboard
from baxter_pnp.transforms import make_transform, transform_points

SCRIPT = os.path.join(PACKAGE_ROOT, 'scripts', 'calibrate_camera.py')
PATTERN, SQUARE = (9, 6), 0.030


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


def test_calibration_recovers_the_thesis_camera(tmp_path):
    camera = load_default_camera()
    rng = np.random.default_rng(2024)
    images = tmp_path / 'images'
    images.mkdir()
    for index in range(14):
        image, _ = render_chessboard(camera, random_board_pose(rng, camera), rng, pattern=PATTERN, square=SQUARE)
        cv2.imwrite(str(images / f'board_{index:02d}.png'), image)
    cv2.imwrite(str(images / 'blank.png'), np.full((480, 640, 3), 200, np.uint8))
    out = tmp_path / 'calib.yaml'
    result = run_script(images, '--pattern', '9x6', '--square', SQUARE, '-o', out)
    assert result.returncode == 0, result.stderr
    assert 'no board found in: blank.png' in result.stdout
    assert 'board_13.png:' in result.stdout
    calibrated = CameraModel.from_yaml(out)
    for name in ('fx', 'fy', 'cx', 'cy'):
        assert getattr(calibrated, name) == pytest.approx(getattr(camera, name), rel=0.01), name
    rms = yaml.safe_load(out.read_text())['rms_reprojection_error']
    assert 0 < rms < 0.5


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
