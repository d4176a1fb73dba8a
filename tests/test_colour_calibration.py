"""scripts/calibrate_colour.py: a colour class learnt from one view of a block detects that block (and not the
table); a region without colour is a clear error."""
import cv2
import numpy as np
import pytest
import yaml
from scipy.spatial.transform import Rotation

from baxter_pnp import vision
from baxter_pnp.camera import load_default_camera
from baxter_pnp.colour_calibration import main
from baxter_pnp.synthetic import BlockSpec, render_block_scene
from baxter_pnp.transforms import make_transform

TEAL_BGR = (150, 140, 30)      # a colour no default class holds (CIELAB hue about 220 deg)


@pytest.fixture
def teal_view(tmp_path):
    camera = load_default_camera()
    T_camera_block = make_transform(Rotation.from_rotvec([np.pi, 0, 0]) * Rotation.from_rotvec([0, 0, 0.3]),
                                    [0.01, 0.0, 0.25])
    image, _ = render_block_scene(camera, [(BlockSpec('square', 0.04, 0.02, TEAL_BGR), T_camera_block)],
                                  np.random.default_rng(3))
    path = tmp_path / 'teal.png'
    cv2.imwrite(str(path), image)
    return path, image


def test_a_learnt_class_detects_the_block_it_was_learnt_from(teal_view, tmp_path, capsys):
    path, image = teal_view
    assert not vision.detect(image, vision.VisionConfig.from_yaml()), 'no default class may hold teal'
    output = tmp_path / 'vision.yaml'
    assert main([str(path), '--name', 'teal', '--roi', '250,170,140,140', '-o', str(output)]) == 0
    learnt = yaml.safe_load(output.read_text())['chroma']['classes']['teal']
    assert 200 < learnt['hue_deg'] < 240 and learnt['min_chroma'] >= 15
    config = vision.VisionConfig.from_yaml(output)
    detections = vision.detect(image, config, colours=['teal'])
    assert [(d.colour, d.shape) for d in detections] == [('teal', 'square')]
    assert 'covers' in capsys.readouterr().out


def test_a_region_without_colour_is_refused(teal_view, tmp_path, capsys):
    path, _ = teal_view
    assert main([str(path), '--name', 'teal', '--roi', '0,0,60,60', '-o', str(tmp_path / 'out.yaml')]) == 2
    assert 'coloured pixels' in capsys.readouterr().err and not (tmp_path / 'out.yaml').exists()
    assert main([str(path), '--name', 'teal', '--roi', '600,400,100,100']) == 2
    assert 'not inside' in capsys.readouterr().err
