"""The independent renderer (bench/render_independent.py): its ground truth against what it draws, its determinism,
and the perception benchmark's ``_r2`` datasets built, measured and dumped end to end."""
import argparse
import math
import os

import cv2
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from baxter_pnp import camera as camera_module
from baxter_pnp import vision
from baxter_pnp.bench import perception_bench
from baxter_pnp.bench import render_independent as r2
from baxter_pnp.transforms import make_transform

# white block on a black table, lit straight from above, no ambient light: the top face is 255, everything else 0
TOP_ONLY = r2.plain_look(table_grey=0.0, ambient=0.0, diffuse=1.0, exposure=1.0, light_elevation=math.pi / 2)


@pytest.fixture(scope='module')
def camera():
    return camera_module.load_default_camera()


def face_on(position, yaw):
    """T_camera_block of a block whose top face squarely faces the camera (block +z = camera -z)."""
    return make_transform((Rotation.from_euler('x', np.pi) * Rotation.from_euler('z', yaw)).as_matrix(), position)


def top_face_coverage(camera, block, T):
    image, truths = r2.render_scene(camera, [(block, T)], np.random.default_rng(0), look=TOP_ONLY)
    return image[..., 1].astype(float) / 255.0, truths[0]


def dense_outline_px(camera, T, corners_block, per_edge=200):
    """The projected outline of a planar polygon, each straight 3D edge sampled densely (distortion bends it)."""
    t = np.arange(per_edge)[:, None] / per_edge
    points = np.vstack([a + t * (b - a) for a, b in zip(corners_block, np.roll(corners_block, -1, axis=0))])
    return camera.project(points @ T[:3, :3].T + T[:3, 3])


def area_centroid(outline):
    x, y = outline[:, 0], outline[:, 1]
    cross = x * np.roll(y, -1) - np.roll(x, -1) * y
    area = cross.sum() / 2.0
    centroid = np.array([np.sum((x + np.roll(x, -1)) * cross), np.sum((y + np.roll(y, -1)) * cross)]) / (6 * area)
    return abs(area), centroid


def edge_line(coverage, a, b, reach=3.0, step=0.05):
    """Line (point, unit direction) through the sub-pixel edge of ``coverage`` between pixels ``a`` and ``b`` (the
    middle 60 % of the side, away from the corners): the edge's offset along the normal is the profile's integral."""
    direction = (b - a) / np.linalg.norm(b - a)
    normal = np.array([-direction[1], direction[0]])
    t = np.arange(-reach, reach + step / 2, step)
    points = []
    for f in np.linspace(0.2, 0.8, 25):
        samples = a + f * (b - a) + np.outer(t, normal)
        values = cv2.remap(coverage.astype(np.float32), samples[:, 0:1].astype(np.float32),
                           samples[:, 1:2].astype(np.float32), cv2.INTER_LINEAR).ravel()
        integral = np.trapz(values, t)                  # the face covers [offset, reach] or [-reach, offset]
        offset = reach - integral if values[-1] > values[0] else integral - reach
        points.append(a + f * (b - a) + offset * normal)
    return fit_line(points)


def fit_line(points):
    """Least-squares line (point, unit direction) through points (N, 2)."""
    vx, vy, x0, y0 = cv2.fitLine(np.array(points, np.float32), cv2.DIST_L2, 0, 0.01, 0.01).ravel()
    return np.array([x0, y0]), np.array([vx, vy])


def intersect(line1, line2):
    (p, d), (q, e) = line1, line2
    s = np.linalg.solve(np.column_stack([d, -e]), q - p)
    return p + s[0] * d


@pytest.mark.parametrize('position, yaw', [((0.0, 0.0, 0.20), 0.3), ((0.06, -0.04, 0.22), 1.0)])
def test_top_face_drawn_where_the_truth_says(camera, position, yaw):
    """Face-on square: the area and centroid of the drawn top face match the projected model within hundredths of
    a pixel (the lens bends the edges; side faces, if seen, are black like the table), and the corners are the
    projected model corners."""
    block, T = r2.Block('square', 0.04, 0.02, (255, 255, 255)), face_on(position, yaw)
    coverage, truth = top_face_coverage(camera, block, T)
    v, u = np.mgrid[0:camera.height, 0:camera.width]
    area, centroid = coverage.sum(), np.array([(coverage * u).sum(), (coverage * v).sum()]) / coverage.sum()
    outline = dense_outline_px(camera, T, block.model.vertices)
    true_area, true_centroid = area_centroid(outline)
    perimeter = np.sum(np.linalg.norm(np.roll(outline, -1, axis=0) - outline, axis=1))
    assert abs(area - true_area) / perimeter < 0.02          # the edges sit within 0.02 px of the truth on average
    assert np.linalg.norm(centroid - true_centroid) < 0.02
    assert np.allclose(truth['vertices_px'], camera.project(block.model.vertices @ T[:3, :3].T + T[:3, 3]))
    assert np.allclose(truth['centroid_px'], camera.project(T[:3, 3])[0])
    assert truth['visible']


def test_rounded_corners_keep_the_sharp_corners_as_truth(camera):
    """With 3 mm rounded vertical edges the drawn face is the rounded square, and the true vertices are where the
    drawn edges' lines meet, not on the rounding."""
    radius, depth = 0.003, 0.18
    block = r2.Block('square', 0.04, 0.02, (255, 255, 255), corner_radius=radius)
    T = face_on((0.07, -0.05, depth), 0.5)
    coverage, truth = top_face_coverage(camera, block, T)
    half = 0.02 - radius                         # the rounded square: corner arcs about (+-half, +-half)
    arcs = [np.array([cx, cy, 0.0]) + radius * np.array([np.cos(a), np.sin(a), 0.0])
            for cx, cy, start in ((half, half, 0.0), (-half, half, 0.5 * np.pi), (-half, -half, np.pi),
                                  (half, -half, 1.5 * np.pi)) for a in np.linspace(start, start + np.pi / 2, 60)]
    rounded_outline = dense_outline_px(camera, T, np.array(arcs), per_edge=4)
    rounded_area, rounded_centroid = area_centroid(rounded_outline)
    sharp_area, _ = area_centroid(dense_outline_px(camera, T, block.model.vertices))
    perimeter = np.sum(np.linalg.norm(np.roll(rounded_outline, -1, axis=0) - rounded_outline, axis=1))
    assert abs(coverage.sum() - rounded_area) / perimeter < 0.02 < (sharp_area - rounded_area) / perimeter
    corners = truth['vertices_px']
    lines = [edge_line(coverage, a, b) for a, b in zip(corners, np.roll(corners, -1, axis=0))]
    measured = np.array([intersect(lines[k - 1], lines[k]) for k in range(4)])
    # the same construction on the exactly projected sides (the lens bends them: lines through their middles meet
    # a few hundredths of a pixel off the corners); the measured edges are good to about 0.03 px
    vertices = block.model.vertices
    exact_lines = [fit_line(camera.project(np.array([a + f * (b - a) for f in np.linspace(0.2, 0.8, 25)])
                                           @ T[:3, :3].T + T[:3, 3]))
                   for a, b in zip(vertices, np.roll(vertices, -1, axis=0))]
    expected = np.array([intersect(exact_lines[k - 1], exact_lines[k]) for k in range(4)])
    assert np.max(np.linalg.norm(measured - expected, axis=1)) < 0.08     # (the rounding is 2.8 px deep)
    assert np.max(np.linalg.norm(measured - corners, axis=1)) < 0.12
    # the rounding is drawn: the drawn face does not reach its sharp corners
    assert all(cv2.getRectSubPix(coverage.astype(np.float32), (1, 1), tuple(c))[0, 0] < 0.3 for c in corners)


def test_a_rounded_top_rim_posed_with_its_edge_radius(camera):
    """A 40 mm square whose top rim is rounded over by 1.5 mm, 0.18-0.30 m away, tilted 5-20 deg: its seen top face
    is smaller than the sharp one, and the block's sharp model puts it 4-6 mm too far; told the edge radius
    (``models.seen_model``) the estimate comes within 2 mm."""
    from baxter_pnp import perception
    config = vision.VisionConfig.from_yaml()
    block = r2.Block('square', 0.04, 0.02, (40, 170, 40), bevel=0.0015)
    look = r2.plain_look(blur_sigma=0.7, light_elevation=math.radians(65), light_azimuth=0.7, table_grey=110.0)
    depth_errors = {0.0: [], 0.0015: []}
    for k, (x, y, z, tilt, yaw) in enumerate([(0.0, 0.0, 0.20, 10, 0.3), (0.05, -0.03, 0.25, 20, 1.0),
                                              (-0.04, 0.03, 0.30, 15, 2.0), (0.02, 0.05, 0.18, 5, 0.7)]):
        rotation = Rotation.from_euler('x', np.pi) * Rotation.from_euler('y', tilt, degrees=True) \
            * Rotation.from_euler('z', yaw)
        T = make_transform(rotation.as_matrix(), (x, y, z))
        image, _ = r2.render_scene(camera, [(block, T)], np.random.default_rng(k), look=look)
        for edge_radius, errors in depth_errors.items():
            observations = perception.observe_blocks(image, camera, config, 0.04, 0.02, shape='square',
                                                     colour='green', edge_radius=edge_radius)
            posed = [o for o in observations if o.pose is not None]
            assert len(posed) == 1, (k, edge_radius, observations)
            errors.append(posed[0].pose.T_camera_object[2, 3] - T[2, 3])
    assert min(depth_errors[0.0]) > 0.0035
    assert max(np.abs(depth_errors[0.0015])) < 0.002


def test_a_look_as_a_pick_makes_it(camera):
    """``as_picked.look_at``: a 40 mm square 0.25 m away is believed and right, within 3 mm; looked for with a 50 mm
    model it is estimated 25 % farther, below the table, and the pick's height rule refuses it."""
    import dataclasses
    from baxter_pnp.bench import as_picked
    config = vision.VisionConfig.from_yaml()
    block = r2.Block('square', 0.04, 0.02, (40, 170, 40))
    T = make_transform((Rotation.from_euler('x', np.pi) * Rotation.from_euler('y', 0.2)).as_matrix(),
                       (0.02, -0.01, 0.25))
    image, _ = r2.render_scene(camera, [(block, T)], np.random.default_rng(3), look=r2.plain_look(blur_sigma=0.7))
    plane = perception_bench.true_table_plane(T, block.height)
    believed, right, error_mm = as_picked.look_at(image, block, 'green', T, plane, camera, config)
    assert believed and right and error_mm < 3.0
    assert as_picked.look_at(image, dataclasses.replace(block, side=0.05), 'green', T, plane, camera, config) == \
        (False, False, None)
    T_base_camera, table = as_picked.base_of_table(plane)
    base_z = (T_base_camera @ T)[2, 3]
    assert base_z == pytest.approx(table.offset + block.height, abs=1e-9)     # the top face at its height


def test_same_seed_same_picture(camera):
    """Every random choice comes from the generator: a seed gives one picture, another seed another one."""
    die = r2.Block('square', 0.02, 0.02, (40, 40, 200), corner_radius=0.002, bevel=0.0015,
                   marks=r2.Marks(pips=5, pip_bgr=(230, 230, 230), side_pips=True, label='', glare=30.0))
    block = r2.Block('pentagon', 0.04, 0.02, (40, 170, 40), corner_radius=0.001, bevel=0.0008,
                     marks=r2.Marks(label='K', grain=0.05, glare=20.0))
    T_die = make_transform(Rotation.from_euler('xyz', [np.pi - 0.4, 0.3, 0.7]).as_matrix(), (0.04, 0.0, 0.2))
    T_block = face_on((-0.05, 0.02, 0.25), 0.2)
    scene = [(die, T_die), (block, T_block)]
    first, truths = r2.render_scene(camera, scene, np.random.default_rng(5))
    again, _ = r2.render_scene(camera, scene, np.random.default_rng(5))
    other, _ = r2.render_scene(camera, scene, np.random.default_rng(6))
    assert np.array_equal(first, again)
    assert np.mean(np.abs(first.astype(int) - other)) > 1.0
    assert all(t['visible'] for t in truths)
    with pytest.raises(ValueError, match='corner_radius'):
        r2.Block('square', 0.02, 0.02, corner_radius=0.011)


def test_r2_datasets_built_measured_and_dumped(camera, tmp_path):
    """Each _r2 set builds blocks of its kind, the benchmark runs the real pipeline on them and reports the new
    columns, and the worst frames are written as crops."""
    config = vision.VisionConfig.from_yaml(None)
    rows, crops = [], {}
    for kind in perception_bench.R2_DATASETS:
        samples = perception_bench.make_dataset(kind, 3, 3, camera)
        for block, T, colour in samples:
            corners = camera.project(block.model.vertices @ T[:3, :3].T + T[:3, 3])
            side_px = np.mean(np.linalg.norm(np.roll(corners, -1, axis=0) - corners, axis=1))
            low, high = {'dice_r2': (15, 60), 'small_r2': (15, 25)}.get(kind, (10, 400))
            assert low <= side_px <= high, (kind, side_px)
            if kind == 'dice_r2':
                assert block.height == block.side and block.marks.side_pips and block.corner_radius > 0
            if kind in ('green40_r2', 'sharp40_r2'):
                assert (block.shape, colour, block.side) == ('square', 'green', 0.040)
            if kind == 'sharp40_r2':
                assert block.corner_radius == block.bevel == 0.0 and block.marks == r2.Marks()
        rows += perception_bench.run_dataset(kind, samples, camera, config, 3, crops)
    assert len(rows) == 3 * len(perception_bench.R2_DATASETS) * len(perception_bench.ESTIMATORS)
    summaries = [perception_bench.summarise(rows, kind, 'sqp') for kind in perception_bench.R2_DATASETS]
    table = perception_bench.format_table(summaries)
    for title in ('vertex mean px', 'vertex med px', 'pos p90 mm', 'dZ mean mm', 'ms/frame'):
        assert title in table
    assert perception_bench.dataset_list('green40,r2') == ['green40'] + list(perception_bench.R2_DATASETS)
    paths = perception_bench.save_worst(rows, crops, str(tmp_path), 3)
    missed = sum(not r['detected'] for r in rows if r['estimator'] == 'sqp')
    assert len(paths) == 3 + min(3, missed) and all(os.path.getsize(p) > 0 for p in paths)
    assert len(open(tmp_path / 'worst.tsv').read().splitlines()) == 1 + len(paths)


def test_seed_spread_draws_each_set_again_from_each_seed(camera):
    """``--seeds``: each dataset drawn anew from each seed (other blocks, other poses), summarised per seed."""
    config = vision.VisionConfig.from_yaml(None)
    results = perception_bench.measure_seed_spread(['small_r2'], [5, 6], {'small_r2': 2}, camera, config)
    assert [(r['dataset'], r['seed'], r['frames']) for r in results] == [('small_r2', 5, 2), ('small_r2', 6, 2)]
    assert perception_bench.set_seed('small_r2', 5) != perception_bench.set_seed('dice_r2', 5)
    first, second = (perception_bench.make_dataset('small_r2', 2, perception_bench.set_seed('small_r2', seed), camera)
                     for seed in (5, 6))
    assert not np.allclose(first[0][1], second[0][1])
    table = perception_bench.format_seed_spread(results).splitlines()
    assert len(table) == 4 and table[2].startswith('| small_r2 | 5 | 2 |')
    assert perception_bench.seed_list('1, 7,13') == [1, 7, 13]
    for bad in ('', 'a,1'):
        with pytest.raises(argparse.ArgumentTypeError):
            perception_bench.seed_list(bad)


def test_latency_is_measured_on_the_hand_cameras_640x400_frames(camera):
    """The latency table renders new frames for the 640x400 window a real hand camera delivers (the thesis
    calibration's centred window: the principal point moves up by 40 px) and times vision + sqp on them."""
    hand = perception_bench.hand_camera(camera)
    assert (hand.width, hand.height) == (640, 400)
    assert hand.cx == pytest.approx(camera.cx) and hand.cy == pytest.approx(camera.cy - 40.0)
    config = vision.VisionConfig.from_yaml(None)
    results = perception_bench.measure_latency(['green40', 'small_r2'], {'green40': 4, 'small_r2': 3}, 1, hand,
                                               config)
    assert [(r['dataset'], r['frames'], r['width'], r['height']) for r in results] == [
        ('green40', 4, 640, 400), ('small_r2', 3, 640, 400)]
    assert results[0]['detection_rate'] == 1.0        # 40 mm green squares in the open: always found
    assert all(0.0 < r['frame_ms_median'] <= r['frame_ms_p90'] < 1000.0 for r in results)
    table = perception_bench.format_latency(results)
    assert '| green40 | 640x400 | 4 | 100.0% |' in table


def test_blocks_cut_by_the_border_are_measured(camera):
    """Each frame is cropped so its block reaches past one border by 15, 30 and 50 % of its extent; a found block
    is a detection of its colour flagged ``touches_border`` (what the pick re-centres on)."""
    image = np.zeros((100, 200, 3), np.uint8)
    square = np.array([[40.0, 20.0], [80.0, 20.0], [80.0, 60.0], [40.0, 60.0]])
    assert perception_bench._cut_by_the_border(image, square, 0, 0.5).shape == (100, 140, 3)     # cut at u = 60
    assert perception_bench._cut_by_the_border(image, square, 3, 0.25).shape == (50, 200, 3)     # cut at v = 50
    config = vision.VisionConfig.from_yaml(None)
    results = perception_bench.measure_border_cuts(['green40'], 4, 1, camera, config)
    assert results == [{'dataset': 'green40', 'cut': 12, 'found': results[0]['found']}]
    assert results[0]['found'] >= 10                 # 40 mm green squares in the open, 2/3 of them or more in view
    assert '| green40 | 12 |' in perception_bench.format_border_cuts(results)


def test_the_issues_sharp_blocks_are_found_and_their_corners_placed(camera):
    """``sharp40_r2`` (the issue's independent renderer: sharp 40 mm squares, side-face slivers, blur, JPEG), 40 frames
    of one draw: all but one found; vertex error and position median within the README's (0.30 px and 0.80 mm over
    150 frames, session 23) plus the spread of a 40-frame draw. Without the sub-pixel stage the vertex median is
    about 1 px."""
    config = vision.VisionConfig.from_yaml(None)
    samples = perception_bench.make_dataset('sharp40_r2', 40, 41, camera)
    rows = perception_bench.run_dataset('sharp40_r2', samples, camera, config, 41, estimators=('sqp',))
    summary = perception_bench.summarise(rows, 'sharp40_r2', 'sqp')
    assert summary['detection_rate'] >= 39 / 40
    assert summary['vertex_err_px_median'] <= 0.40
    assert summary['position_err_mm_median'] <= 1.0
