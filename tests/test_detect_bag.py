"""Replay of a recorded run: ``detect_image.py`` on rosbags (issue 10, item 5), bags written with ``rosbag.Bag``.

The bag holds what a real Baxter's left hand camera publishes (``recorded_runs``): bgra8 images and the
CameraInfo of the full sensor with the 640x400 window as ROI (K's principal point at (651, 406), the image's at
(331, 206)), frame_id ``/left_hand_camera``. The images are rendered with a green square at a known pose, so a
CameraInfo read wrongly (ROI, binning, the wrong message for the frame) gives a wrong pose.
"""
import glob
import os
from types import SimpleNamespace

import cv2
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

import recorded_runs as runs
from baxter_pnp import detect_cli, synthetic
from baxter_pnp.camera import load_default_camera
from baxter_pnp.sim.launcher import run_script

T0_NS = 1543526450 * 10**9                      # the real robot's clock (its CameraInfo's stamp)
SIDE = 0.04
POSITION_TOLERANCE_M = 0.003
NORMAL_TOLERANCE_DEG = 3.0


def stamp_ns(k):
    return T0_NS + k * 100_000_000             # frames every 0.1 s


@pytest.fixture(scope='module')
def recorded_run(tmp_path_factory):
    """A bag of four frames with a green square each: frame 0 before any CameraInfo, frames 1-2 of the 640x400
    window, frame 3 of the whole sensor binned 2x2 (also 640x400, half the focal length); each CameraInfo is
    recorded after its image, with the image's stamp. Plus an image file of the thesis camera."""
    folder = tmp_path_factory.mktemp('recorded_run')
    windows = [runs.WINDOW_640x400, runs.WINDOW_640x400, runs.WINDOW_640x400, runs.WINDOW_BINNED]
    rng = np.random.default_rng(3)
    block = synthetic.BlockSpec('square', SIDE, 0.02, (40, 170, 40))
    messages, truths = [], {}
    for seq, window in enumerate(windows):
        camera = runs.window_camera(window)
        T_camera_block = synthetic.random_block_pose(rng, (0.18, 0.30), 20.0, camera=camera, margin_px=40,
                                                     block=block)
        image, _ = synthetic.render_block_scene(camera, [(block, T_camera_block)], rng)
        info = runs.camera_info(stamp_ns(seq), seq, window) if seq else None
        messages += runs.frame_messages(stamp_ns(seq), seq, runs.image(image, stamp_ns(seq), seq), info)
        truths[seq] = T_camera_block
    window_yaml = str(folder / 'window.yaml')
    runs.window_camera(runs.WINDOW_640x400).to_yaml(window_yaml)
    thesis = load_default_camera()
    T_camera_file_block = synthetic.random_block_pose(rng, (0.2, 0.25), 20.0, camera=thesis, margin_px=40,
                                                      block=block)
    file_image, _ = synthetic.render_block_scene(thesis, [(block, T_camera_file_block)], rng)
    png = str(folder / 'thesis_view.png')
    cv2.imwrite(png, file_image)
    return SimpleNamespace(bag=runs.write_bag(folder / 'run.bag', messages), truths=truths, png=png,
                           file_truth=T_camera_file_block, window_yaml=window_yaml, folder=folder)


def assert_one_posed_square(detections, T_camera_block, where):
    """One green square whose pose matches the rendered truth (position, top-face normal)."""
    assert [(d['shape'], d['colour']) for d in detections] == [('square', 'green')], where
    found = detections[0]
    error_m = np.linalg.norm(np.subtract(found['position_m'], T_camera_block[:3, 3]))
    assert error_m < POSITION_TOLERANCE_M, f'{where}: position off by {1000 * error_m:.1f} mm'
    normal = Rotation.from_quat(found['orientation_xyzw']).as_matrix()[:, 2]
    angle = np.degrees(np.arccos(np.clip(normal @ T_camera_block[:3, 2], -1.0, 1.0)))
    assert angle < NORMAL_TOLERANCE_DEG, f'{where}: top face tilted {angle:.1f} deg from the truth'


def test_a_recorded_run_replays_frame_by_frame_with_the_camera_info_of_its_stamp(recorded_run, tmp_path):
    """``detect_image.py run.bag image.png`` (no topic given: the bag's only image topic and its camera_info):
    one JSON line per frame with bag, topic, stamp, seq and frame_id (leading '/' dropped), each frame posed with
    the CameraInfo stamped at or before it although recorded after it (frame 3: the binned one), the frame before
    any CameraInfo skipped with one warning, the image file posed with the thesis camera, an annotated PNG per
    frame named by stamp, exit 0."""
    out = tmp_path / 'annotated'
    run = run_script(None, 'detect_image.py', [recorded_run.bag, recorded_run.png, '--side', SIDE, '--json',
                                               '--annotate', out], timeout=120, log_path=tmp_path / 'log')
    log = run.log()
    assert run.returncode == 0, log
    reports = runs.json_lines(log)
    frames, files = reports[:-1], reports[-1:]
    assert [(f['bag'], f['topic'], f['seq'], f['frame_id']) for f in frames] == [
        (recorded_run.bag, runs.IMAGE_TOPIC, seq, 'left_hand_camera') for seq in (1, 2, 3)]
    assert [f['stamp'] for f in frames] == pytest.approx([stamp_ns(seq) * 1e-9 for seq in (1, 2, 3)], abs=1e-6)
    for frame in frames:
        assert_one_posed_square(frame['detections'], recorded_run.truths[frame['seq']], f'frame {frame["seq"]}')
    assert files[0]['image'] == recorded_run.png
    assert_one_posed_square(files[0]['detections'], recorded_run.file_truth, 'image file')
    assert log.count('before the first CameraInfo') == 1 and ': 1 frame(s) of' in log, log
    annotated = sorted(os.listdir(out))
    assert annotated == sorted([f'run_1543526450.{k}00000000.png' for k in (1, 2, 3)] + ['thesis_view.png'])
    assert all(cv2.imread(str(out / name)).shape == (400, 640, 3) for name in annotated[:3])


def test_every_max_frames_a_fallback_calibration_and_the_summary(recorded_run, capsys):
    """``--every 2``: frames 0 (skipped: no CameraInfo yet) and 2. ``--camera-info`` YAML: used for frame 0 only
    (frame 1 has its CameraInfo), ``--max-frames 2`` stops there. Without ``--json``: one summary line per frame
    naming bag, topic, seq and stamp."""
    assert detect_cli.main([recorded_run.bag, '--side', str(SIDE), '--json', '--every', '2']) == 0
    output = capsys.readouterr()
    assert [f['seq'] for f in runs.json_lines(output.out)] == [2]
    assert ': 1 frame(s) of' in output.err

    assert detect_cli.main([recorded_run.bag, '--side', str(SIDE), '--json', '--max-frames', '2',
                            '--camera-info', recorded_run.window_yaml]) == 0
    output = capsys.readouterr()
    frames = runs.json_lines(output.out)
    assert [f['seq'] for f in frames] == [0, 1] and 'before the first CameraInfo' not in output.err
    for frame in frames:
        assert_one_posed_square(frame['detections'], recorded_run.truths[frame['seq']], f'frame {frame["seq"]}')

    assert detect_cli.main([recorded_run.bag, '--side', str(SIDE), '--every', '3', '--max-frames', '2']) == 0
    lines = capsys.readouterr().out.splitlines()
    assert lines[0] == f'{recorded_run.bag} {runs.IMAGE_TOPIC} frame seq 3 at 1543526450.300000000: 1 detection(s)'
    assert lines[1].startswith('  green square at') and 'mm, residual' in lines[1]


@pytest.mark.skipif(not os.path.exists(runs.REAL_CAMERA_INFO), reason=f'real data absent ({runs.REAL})')
def test_the_real_hand_camera_frames_replayed_from_a_bag_hold_no_square(tmp_path, capsys):
    """The 23 real frames of ``baxter_hand_a`` (chessboard, table, cables, an e-stop box) as bgra8 with the
    robot's own CameraInfo as published: every frame replayed and read, no square in any."""
    paths = sorted(glob.glob(os.path.join(runs.REAL, 'baxter_hand_a', '*.jpg')))
    messages = []
    for seq, path in enumerate(paths):
        messages += runs.frame_messages(stamp_ns(seq), seq, runs.image(cv2.imread(path), stamp_ns(seq), seq),
                                        runs.published_camera_info(stamp_ns(seq), seq))
    bag = runs.write_bag(tmp_path / 'hand_a.bag', messages)
    assert detect_cli.main([bag, '--side', '0.016', '--height', '0.016', '--shape', 'square', '--json']) == 0
    frames = runs.json_lines(capsys.readouterr().out)
    assert len(paths) == 23 and [f['seq'] for f in frames] == list(range(23))
    assert {f['frame_id'] for f in frames} == {'left_hand_camera'}
    assert [f['detections'] for f in frames] == [[]] * 23
