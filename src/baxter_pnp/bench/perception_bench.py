"""Perception benchmark (``make bench-perception``): renders its own ground-truth datasets, runs the
vision pipeline and every pose estimator on the same vertices, and prints the results side by side.

Two renderers draw the datasets. The project's own (``synthetic.py``; thesis camera, 640x480, lens distortion,
lighting gradient, noise, blur, JPEG; blocks 2 cm thick so side faces show at oblique views):

- ``mixed``: triangles to hexagons of every named colour, 30-60 mm sides, 0.10-0.40 m away, up to 35 deg tilt;
- ``green40``: 40 mm green squares in the same range of poses (the acceptance set);
- ``depth161``: a 40 mm green square seen straight on at 161 mm (the thesis's depth experiment), 56 renders.

A second, independent renderer (``render_independent.py``: rounded edges, rounded-over top rims, soft shading
and shadows, a dim textured table, vignetting, pips, letters, grain and glare, 8x supersampling), the ``_r2`` sets:

- ``green40_r2``: 40 mm green squares 0.13-0.40 m away, up to 35 deg tilt;
- ``mixed_r2``: as ``mixed``;
- ``dice_r2``: 16-25 mm dice (cubes) of the four colours, pips on every face, rounded edges, 15-60 px a side,
  up to 40 deg tilt (two side faces often in view);
- ``small_r2``: blocks of every shape and colour 15-25 px a side;
- ``sharp40_r2``: 40 mm green squares as ``green40_r2``, but sharp (no rounded edge or rim, no marks): the issue's
  independent renderer (antialiasing, soft shading, side-face slivers, blur, JPEG), which rounding does not hide.

Errors are against the renderer's ground truth (the top face's sharp corners, where its edge lines meet):
vertex error (px, mean distance of each detected vertex to the nearest true one), position of the top-face
centre (mm), depth (z, mm; signed mean = bias, positive = too far), orientation (deg, modulo the shape's
symmetry). Estimators (``ESTIMATORS``): ``sqp``, ``ippe``, ``sqpnp`` on the block's model; ``sqp+plane`` with the
true table's normal as prior (as the robot has it); ``sqp+edge`` with the model told the block's rounded top rim
(``models.seen_model``, the truth's bevel: a user gives a die's edge radius as its side). Times are per frame on one
core (OpenCV and BLAS limited to one thread): ``detect`` for the vision pipeline, then each estimator's own time.
"""
import argparse
import csv
import json
import os
import time

import numpy as np

from baxter_pnp import camera as camera_module
from baxter_pnp import models, pick, pose, synthetic, vision
from baxter_pnp.bench import as_picked, composite, photometric, render_independent
from baxter_pnp.bench.as_picked import true_table_plane
from baxter_pnp.runtime import PACKAGE_ROOT, command_summary
from baxter_pnp.transforms import make_transform

COLOURS_BGR = {'green': (40, 170, 40), 'red': (40, 40, 200), 'blue': (200, 90, 30), 'yellow': (30, 200, 220)}
ESTIMATORS = ('sqp', 'sqp+plane', 'sqp+edge', 'ippe', 'sqpnp')     # described in the module docstring
BLOCK_HEIGHT = 0.02
PROJECT_DATASETS = ('mixed', 'green40', 'depth161')
R2_DATASETS = ('green40_r2', 'mixed_r2', 'dice_r2', 'small_r2', 'sharp40_r2')
LABEL_CHARACTERS = 'ABCDEFGHKLMNPRSTUVXYZ2345789'
# the blocks of green40_r2, mixed_r2 and small_r2: this fraction has rounded vertical edges of a radius in this
# range (m), that fraction a rounded-over top rim (the silhouette then lies up to the bevel inside the sharp corners)
R2_ROUNDED_FRACTION, R2_CORNER_RADIUS_M = 0.7, (0.0, 0.0015)
R2_BEVELLED_FRACTION, R2_BEVEL_M = 0.6, (0.0003, 0.001)
SIDE_PX_RANGES = {'dice_r2': (15.0, 60.0), 'small_r2': (15.0, 25.0)}   # mean projected side (px) of these sets


def limit_to_one_core():
    """Make the timing honest: one OpenCV thread (BLAS threads are set by the entry point's env)."""
    import cv2
    cv2.setNumThreads(1)


def set_seed(kind, seed):
    """The seed dataset ``kind`` is drawn from for the run seed ``seed`` (``--seed``): each set's own, whatever else
    is run."""
    return seed + 100 * (PROJECT_DATASETS + R2_DATASETS).index(kind)


def make_dataset(kind, count, seed, camera):
    """List of (block, T_camera_block, colour name) for dataset ``kind``: a ``synthetic.BlockSpec`` for the
    project's renderer, a ``render_independent.Block`` for the ``_r2`` sets."""
    if kind not in PROJECT_DATASETS + R2_DATASETS:
        raise ValueError(f'unknown dataset {kind!r}; known: {", ".join(PROJECT_DATASETS + R2_DATASETS)}')
    rng = np.random.default_rng(seed)
    if kind in R2_DATASETS:
        return [_r2_sample(kind, rng, camera) for _ in range(count)]
    samples = []
    for _ in range(count):
        if kind == 'mixed':
            shape = str(rng.choice(sorted(models.SHAPES)))
            colour = str(rng.choice(sorted(COLOURS_BGR)))
            side = float(rng.uniform(0.030, 0.060))
        else:
            shape, colour, side = 'square', 'green', 0.040
        spec = synthetic.BlockSpec(shape, side, BLOCK_HEIGHT, COLOURS_BGR[colour])
        if kind == 'depth161':
            yaw = rng.uniform(-np.pi, np.pi)
            offset = rng.uniform(-0.002, 0.002, size=2)
            T = make_transform(_rotation_looking_down(yaw), (offset[0], offset[1], 0.161))
        else:
            T = synthetic.random_block_pose(rng, distance_range=(0.10, 0.40), max_tilt_deg=35.0, camera=camera,
                                            block=spec)
        samples.append((spec, T, colour))
    return samples


def _r2_sample(kind, rng, camera):
    """One (``render_independent.Block``, T_camera_block, colour) of the ``_r2`` dataset ``kind``."""
    colour = 'green' if kind in ('green40_r2', 'sharp40_r2') else str(rng.choice(sorted(COLOURS_BGR)))
    albedo = np.clip(np.asarray(COLOURS_BGR[colour], float) * rng.uniform(0.85, 1.15, size=3), 0, 255)
    albedo = tuple(albedo + rng.uniform(0.0, 0.2) * (albedo.mean() - albedo))          # a little less saturated
    focal_px = camera.fx
    if kind == 'dice_r2':
        side = float(rng.uniform(0.016, 0.025))
        white_pips = bool(rng.random() < 0.5)
        marks = render_independent.Marks(pips=int(rng.integers(1, 7)), side_pips=True,
                                         pip_bgr=(230, 230, 225) if white_pips else (25, 25, 25),
                                         glare=float(rng.uniform(15, 50)) if rng.random() < 0.3 else 0.0)
        block = render_independent.Block('square', side, side, albedo, corner_radius=side * rng.uniform(0.08, 0.15),
                                         bevel=side * rng.uniform(0.05, 0.12), marks=marks)
        distances, max_tilt = (focal_px * side / 60.0, focal_px * side / 15.0), 40.0
    elif kind == 'sharp40_r2':
        block, distances, max_tilt = render_independent.Block('square', 0.040, BLOCK_HEIGHT, albedo), (0.13, 0.40), 35.0
    else:
        if kind == 'green40_r2':
            shape, side, distances = 'square', 0.040, (0.13, 0.40)
        else:
            shape, side = str(rng.choice(sorted(models.SHAPES))), float(rng.uniform(0.030, 0.060))
            distances = (0.10, 0.40) if kind == 'mixed_r2' else (focal_px * side / 25.0, focal_px * side / 15.0)
        letter_bgr = (20, 20, 20) if rng.random() < 0.5 else (235, 235, 235)
        marks = render_independent.Marks(
            label=str(rng.choice(list(LABEL_CHARACTERS))) if rng.random() < 0.25 else '', label_bgr=letter_bgr,
            grain=float(rng.uniform(0.02, 0.08)) if rng.random() < 0.4 else 0.0,
            glare=float(rng.uniform(15, 50)) if rng.random() < 0.3 else 0.0)
        block = render_independent.Block(
            shape, side, BLOCK_HEIGHT, albedo, marks=marks,
            corner_radius=float(rng.uniform(*R2_CORNER_RADIUS_M)) if rng.random() < R2_ROUNDED_FRACTION else 0.0,
            bevel=float(rng.uniform(*R2_BEVEL_M)) if rng.random() < R2_BEVELLED_FRACTION else 0.0)
        max_tilt = 35.0
    bounds = synthetic.BlockSpec(block.shape, block.side, block.height)       # its corners keep it in the image
    for _ in range(100):
        T = synthetic.random_block_pose(rng, distance_range=distances, max_tilt_deg=max_tilt, camera=camera,
                                        block=bounds)
        if kind not in SIDE_PX_RANGES or _within(side_px(camera, block.model, T), SIDE_PX_RANGES[kind]):
            return block, T, colour
    raise ValueError(f'{kind}: no pose gives sides of {SIDE_PX_RANGES[kind]} px')


def side_px(camera, model, T_camera_block):
    """Mean length (px) of the projected top-face sides of ``model`` at ``T_camera_block``."""
    corners = camera.project(model.vertices @ T_camera_block[:3, :3].T + T_camera_block[:3, 3])
    return float(np.mean(np.linalg.norm(np.roll(corners, -1, axis=0) - corners, axis=1)))


def _within(value, bounds):
    return bounds[0] <= value <= bounds[1]


def _rotation_looking_down(yaw):
    """Block rotation in the camera frame with its top face squarely facing the camera, yawed by ``yaw`` (rad)."""
    from scipy.spatial.transform import Rotation
    return (Rotation.from_euler('x', np.pi) * Rotation.from_euler('z', yaw)).as_matrix()


def orientation_error_deg(R_true, R_est, symmetry_angle):
    """Smallest rotation angle (deg) between two block orientations, over the shape's symmetric yaws."""
    from scipy.spatial.transform import Rotation
    best = np.inf
    for k in range(int(round(2 * np.pi / symmetry_angle))):
        R_sym = Rotation.from_euler('z', k * symmetry_angle).as_matrix()
        angle = Rotation.from_matrix(R_est.T @ R_true @ R_sym).magnitude()
        best = min(best, angle)
    return float(np.degrees(best))


def run_dataset(kind, samples, camera, config, seed, crops=None, estimators=ESTIMATORS):
    """Render, detect and estimate every sample; returns one result dict per (sample, estimator).

    ``crops``: a dict to fill with ``(kind, index) ->`` what ``save_worst`` draws of the frame.
    """
    render = render_independent.render_scene if kind in R2_DATASETS else synthetic.render_block_scene
    rng = np.random.default_rng(seed + 1)
    rows = []
    for index, (spec, T_true, colour) in enumerate(samples):
        start = time.perf_counter()
        image, truths = render(camera, [(spec, T_true)], rng)
        render_ms = 1000.0 * (time.perf_counter() - start)
        start = time.perf_counter()
        detections = vision.detect(image, config)
        detect_ms = 1000.0 * (time.perf_counter() - start)
        target = vision.select_target(detections, spec.shape, colour, (camera.width, camera.height))
        base = {'dataset': kind, 'index': index, 'shape': spec.shape, 'colour': colour, 'side_m': spec.side,
                'distance_m': float(np.linalg.norm(T_true[:3, 3])), 'tilt_deg': _tilt_deg(T_true),
                'render_ms': render_ms, 'detect_ms': detect_ms, 'detected': target is not None}
        if kind in R2_DATASETS:
            marks = spec.marks
            base.update(corner_radius_mm=1000.0 * spec.corner_radius, bevel_mm=1000.0 * spec.bevel,
                        marks=' '.join(name for name, present in (
                            ('pips', marks.pips), ('letter', marks.label), ('grain', marks.grain),
                            ('glare', marks.glare)) if present))
        if target is not None:
            base['vertex_err_px'] = _vertex_error_px(target.vertices_px, truths[0]['vertices_px'])
        if crops is not None:
            crops[(kind, index)] = _crop(image, truths[0]['vertices_px'], target, detections)
        for estimator in estimators:
            row = dict(base, estimator=estimator)
            if target is not None:
                method, *options = estimator.split('+')
                plane = true_table_plane(T_true, spec.height) if 'plane' in options else None
                model = models.seen_model(spec.shape, spec.side, spec.height,
                                          getattr(spec, 'bevel', 0.0) if 'edge' in options else 0.0)
                start = time.perf_counter()
                try:
                    estimate = pose.estimate_pose(target.vertices_px, camera, model, method=method,
                                                  table_plane=plane)
                except pose.PoseEstimationError:
                    estimate = None
                row['estimate_ms'] = 1000.0 * (time.perf_counter() - start)
                if estimate is not None:
                    T_est = estimate.T_camera_object
                    row['position_err_mm'] = 1000.0 * float(np.linalg.norm(T_est[:3, 3] - T_true[:3, 3]))
                    row['depth_err_mm'] = 1000.0 * float(T_est[2, 3] - T_true[2, 3])
                    row['orientation_err_deg'] = orientation_error_deg(T_true[:3, :3], T_est[:3, :3],
                                                                       model.symmetry_angle)
            rows.append(row)
    return rows


def measure_seed_spread(kinds, seeds, counts, camera, config):
    """The ``sqp`` summary (``summarise``) of each dataset of ``kinds`` rendered from each of ``seeds`` (``counts``:
    frames per dataset; each set's seed offset as in ``main``), a ``seed`` key added: how far a rate or an error
    moves between two draws of the same set, against which a change's effect is judged."""
    results = []
    for kind in kinds:
        for seed in seeds:
            samples = make_dataset(kind, counts[kind], set_seed(kind, seed), camera)
            rows = run_dataset(kind, samples, camera, config, set_seed(kind, seed), estimators=('sqp',))
            results.append(dict(summarise(rows, kind, 'sqp'), seed=seed))
    return results


def format_seed_spread(results):
    """Markdown table of ``measure_seed_spread``'s results, one row per dataset and seed."""
    lines = ['| dataset | seed | frames | detected | vertex mean px | pos med mm | pos p90 mm |',
             '|---|---|---|---|---|---|---|']
    lines += ['| %s | %d | %d | %.1f%% | %.3f | %.2f | %.2f |' % (
        r['dataset'], r['seed'], r['frames'], 100.0 * r['detection_rate'], r['vertex_err_px_mean'],
        r['position_err_mm_median'], r['position_err_mm_p90']) for r in results]
    return '\n'.join(lines)


HAND_CAMERA_MODE = (640, 400)    # px: the mode a real Baxter hand camera publishes (README, "On a real Baxter")
LATENCY_SEED_OFFSET = 50          # the latency frames' seeds: their own, not the accuracy sets'


def hand_camera(camera):
    """``camera``'s centred 640x400 window (``HAND_CAMERA_MODE``): what a Baxter hand camera delivers in that mode
    when ``camera`` is its 640x480 calibration (``image_geometry``'s arithmetic, ``CameraModel.windowed``)."""
    return camera.windowed(camera_module.SensorWindow.centred(camera.width, camera.height, *HAND_CAMERA_MODE))


def measure_latency(kinds, counts, seed, camera, config):
    """Per dataset of ``kinds`` (``counts``: frames of each), rendered for ``camera``: one dict with the
    detection rate and vision + ``sqp`` time per frame (ms: median, p90, as the tables' ``ms/frame``: each frame
    detected then estimated right after its rendering, one OpenCV thread)."""
    results = []
    for kind in kinds:
        frame_seed = set_seed(kind, seed) + LATENCY_SEED_OFFSET
        samples = make_dataset(kind, counts[kind], frame_seed, camera)
        rows = run_dataset(kind, samples, camera, config, frame_seed, estimators=('sqp',))
        frame_ms = [r['detect_ms'] + r.get('estimate_ms', 0.0) for r in rows]
        results.append({'dataset': kind, 'width': camera.width, 'height': camera.height, 'frames': len(rows),
                        'detection_rate': sum(r['detected'] for r in rows) / max(1, len(rows)),
                        'frame_ms_median': float(np.median(frame_ms)),
                        'frame_ms_p90': float(np.percentile(frame_ms, 90))})
    return results


def format_latency(results):
    """Markdown table of ``measure_latency``'s results."""
    lines = ['| dataset | image | frames | detected | ms/frame median | ms/frame p90 |', '|---|---|---|---|---|---|']
    lines += ['| %s | %dx%d | %d | %.1f%% | %.2f | %.2f |' % (
        r['dataset'], r['width'], r['height'], r['frames'], 100.0 * r['detection_rate'], r['frame_ms_median'],
        r['frame_ms_p90']) for r in results]
    return '\n'.join(lines)


def measure_as_picked(kinds, counts, seed, camera, config):
    """Per independent-renderer dataset of ``kinds`` (``counts``: frames of each; the accuracy tables' frames, same
    seeds): ``as_picked.summarise_looks`` of each frame's look as a pick makes it (``as_picked.look_at``, the table
    plane the truth's off by an error drawn from the pick's ``table_height_sigma``)."""
    sigma = pick.PickConfig().table_height_sigma
    results = []
    for kind in [k for k in kinds if k in R2_DATASETS]:
        rng, errors = np.random.default_rng(set_seed(kind, seed) + 1), np.random.default_rng(set_seed(kind, seed) + 2)
        looks = []
        for spec, T, colour in make_dataset(kind, counts[kind], set_seed(kind, seed), camera):
            image, _ = render_independent.render_scene(camera, [(spec, T)], rng)
            true = true_table_plane(T, spec.height)
            known = models.Plane(true.normal, true.offset + errors.normal(0.0, sigma))
            looks.append(as_picked.look_at(image, spec, colour, T, known, camera, config))
        results.append(as_picked.summarise_looks(kind, looks))
    return results


REAL_DEFAULT = os.environ.get('BAXTER_PNP_REAL_DATA', os.path.join(PACKAGE_ROOT, '..', 'shared', 'real'))
REAL_LABELS = os.path.join(PACKAGE_ROOT, 'tests', 'data', 'real_labels.yaml')   # the real cubes' labels
PHOTOMETRIC_SEED_OFFSET = 90                  # measure_photometric's frames' seeds: their own


def measure_photometric(kinds, count, seed, camera, config, real_dir):
    """``photometric``'s measures: the false detections on the real frames of ``real_dir`` that show no block, the
    labelled real cubes found (``REAL_LABELS``) and the blocks of ``count`` frames of each independent-renderer set
    of ``kinds`` found, under every photometric change. Returns ``(false_found, frame_count, blocks)`` as
    ``photometric.format_tables`` takes them."""
    frames = photometric.real_negative_frames(real_dir)
    cubes = photometric.real_cubes_found(real_dir, REAL_LABELS, config)
    blocks = {'real cubes': cubes} if cubes else {}
    for kind in [k for k in kinds if k in R2_DATASETS]:
        frame_seed = set_seed(kind, seed) + PHOTOMETRIC_SEED_OFFSET
        blocks[kind] = photometric.blocks_found(make_dataset(kind, count, frame_seed, camera), camera, config,
                                                np.random.default_rng(frame_seed + 1))
    return photometric.false_detections(frames, config), len(frames), blocks


COMPOSITE_SEED_OFFSET = 110                  # measure_composites' frames' seeds: their own


def measure_composites(kinds, count, seed, config, real_dir):
    """Per independent-renderer dataset of ``kinds``: ``count`` of its blocks put into the real hand-camera frames of
    ``real_dir`` (``composite.measure``'s rows; [] without the frames). Poses drawn for the real camera (640x400)."""
    backgrounds = composite.real_backgrounds(real_dir)
    rows = []
    for kind in [k for k in kinds if k in R2_DATASETS] if backgrounds else []:
        frame_seed = set_seed(kind, seed) + COMPOSITE_SEED_OFFSET
        samples = make_dataset(kind, count, frame_seed, backgrounds[0][2])
        rows.append(composite.measure(kind, samples, backgrounds, config, np.random.default_rng(frame_seed + 1)))
    return rows


BORDER_CUT_FRACTIONS = (0.15, 0.30, 0.50)    # measure_border_cuts: share of the block's extent cut off
BORDER_CUT_SEED_OFFSET = 70                   # its frames' seeds: their own


def _cut_by_the_border(image, vertices_px, side, fraction):
    """``image`` cropped so that ``fraction`` of the extent of the polygon ``vertices_px`` (n, 2) lies beyond one
    border (``side`` 0..3: left, right, top, bottom)."""
    low, high = vertices_px.min(axis=0), vertices_px.max(axis=0)
    axis = side // 2                                        # 0: u (columns), 1: v (rows)
    cut = fraction * (high[axis] - low[axis])
    window = slice(int(low[axis] + cut), None) if side % 2 == 0 else slice(None, int(high[axis] - cut))
    return np.ascontiguousarray(image[:, window] if axis == 0 else image[window])


def measure_border_cuts(kinds, count, seed, camera, config):
    """Per dataset of ``kinds``: ``count`` frames, each cropped so its block is cut by the image border (one border
    per frame, in turn; ``BORDER_CUT_FRACTIONS`` of its extent). One dict with the cut blocks and how many gave a
    detection of their colour flagged ``touches_border`` (what the task layer re-centres on)."""
    results = []
    for kind in kinds:
        frame_seed = set_seed(kind, seed) + BORDER_CUT_SEED_OFFSET
        render = render_independent.render_scene if kind in R2_DATASETS else synthetic.render_block_scene
        rng = np.random.default_rng(frame_seed + 1)
        cut = found = 0
        for index, (spec, T_true, colour) in enumerate(make_dataset(kind, count, frame_seed, camera)):
            image, truths = render(camera, [(spec, T_true)], rng)
            for fraction in BORDER_CUT_FRACTIONS:
                crop = _cut_by_the_border(image, truths[0]['vertices_px'], index % 4, fraction)
                cut += 1
                found += any(d.colour == colour and d.touches_border for d in vision.detect(crop, config))
        results.append({'dataset': kind, 'cut': cut, 'found': found})
    return results


def format_border_cuts(results):
    """Markdown table of ``measure_border_cuts``'s results."""
    lines = ['| dataset | blocks cut by the border | found, flagged touches_border |', '|---|---|---|']
    lines += ['| %s | %d | %d (%.1f%%) |' % (r['dataset'], r['cut'], r['found'],
                                             100.0 * r['found'] / max(1, r['cut'])) for r in results]
    return '\n'.join(lines)


def _tilt_deg(T_camera_block):
    """Angle (deg) between the block's +z and the camera's -z (0 = top face squarely towards the camera)."""
    return float(np.degrees(np.arccos(np.clip(-T_camera_block[2, 2], -1.0, 1.0))))


def _vertex_error_px(detected, true):
    """Mean distance (px) between detected vertices and the true ones, matched by nearest neighbour."""
    distances = np.linalg.norm(detected[:, None, :] - true[None, :, :], axis=2)
    return float(np.mean(distances.min(axis=1)))


CROP_MARGIN_PX = 12


def _crop(image, true_px, target, detections):
    """What ``save_worst`` draws of a frame: the image around the true and target vertices (``image``, top-left
    pixel ``origin``), ``true_px``, the target's vertices (None if missed), the other detections'
    ``(label, vertices)``."""
    h, w = image.shape[:2]
    shown = true_px if target is None else np.vstack([true_px, target.vertices_px])
    x0, y0 = np.clip(np.floor(shown.min(axis=0)).astype(int) - CROP_MARGIN_PX, 0, [w - 1, h - 1])
    x1, y1 = np.clip(np.ceil(shown.max(axis=0)).astype(int) + CROP_MARGIN_PX + 1, [x0 + 1, y0 + 1], [w, h])
    others = [('%s %s' % (d.shape, d.colour), d.vertices_px) for d in detections if d is not target]
    return {'image': image[y0:y1, x0:x1].copy(), 'origin': np.array([x0, y0]), 'true_px': true_px,
            'target_px': None if target is None else target.vertices_px, 'others': others}


def save_worst(rows, crops, directory, count, zoom=4):
    """Write crops (enlarged ``zoom`` times) of the ``count`` found targets with the largest vertex error
    (``worst_*.png``) and of up to ``count`` missed ones (``missed_*.png``): truth in green, the target's vertices
    in red, other detections in yellow with their shape and colour; ``worst.tsv`` lists them. Returns the paths."""
    import cv2
    frames = [r for r in rows if r['estimator'] == 'sqp' and (r['dataset'], r['index']) in crops]
    found = sorted((r for r in frames if r['detected']), key=lambda r: -r['vertex_err_px'])[:count]
    missed = [r for r in frames if not r['detected']][:count]
    os.makedirs(directory, exist_ok=True)
    paths, lines = [], ['file\tdataset\tindex\tshape\tcolour\tside_mm\tdistance_m\tvertex_err_px\t'
                        'position_err_mm\tdepth_err_mm\tother detections']
    for group, ranked in (('worst', found), ('missed', missed)):
        for rank, row in enumerate(ranked):
            crop = crops[(row['dataset'], row['index'])]
            canvas = cv2.resize(crop['image'], None, fx=zoom, fy=zoom, interpolation=cv2.INTER_NEAREST)

            def at(points):   # pixel centres of the enlarged crop, 4 fractional bits
                return np.round(((points - crop['origin'] + 0.5) * zoom - 0.5) * 16).astype(np.int32)
            for label, vertices in crop['others']:
                cv2.polylines(canvas, [at(vertices)], True, (0, 255, 255), 1, cv2.LINE_AA, 4)
                corner = tuple(int(c) for c in at(vertices).min(axis=0) // 16)
                cv2.putText(canvas, label, corner, cv2.FONT_HERSHEY_SIMPLEX, 0.4, (0, 255, 255), 1, cv2.LINE_AA)
            if crop['target_px'] is not None:
                cv2.polylines(canvas, [at(crop['target_px'])], True, (0, 0, 255), 1, cv2.LINE_AA, 4)
                for point in at(crop['target_px']):
                    cv2.circle(canvas, tuple(int(c) for c in point), 3 * 16, (0, 0, 255), 1, cv2.LINE_AA, 4)
            cv2.polylines(canvas, [at(crop['true_px'])], True, (0, 255, 0), 1, cv2.LINE_AA, 4)
            for point in at(crop['true_px']):
                cv2.circle(canvas, tuple(int(c) for c in point), 2 * 16, (0, 255, 0), -1, cv2.LINE_AA, 4)
            name = '%s_%02d_%s_%03d.png' % (group, rank, row['dataset'], row['index'])
            cv2.imwrite(os.path.join(directory, name), canvas)
            paths.append(os.path.join(directory, name))
            lines.append('\t'.join(str(v) for v in (
                name, row['dataset'], row['index'], row['shape'], row['colour'], round(1000 * row['side_m'], 1),
                round(row['distance_m'], 3), round(row.get('vertex_err_px', np.nan), 3),
                round(row.get('position_err_mm', np.nan), 2), round(row.get('depth_err_mm', np.nan), 2),
                '; '.join(label for label, _ in crop['others']))))
    with open(os.path.join(directory, 'worst.tsv'), 'w') as f:
        f.write('\n'.join(lines) + '\n')
    return paths


def summarise(rows, kind, estimator):
    """Statistics of one (dataset, estimator) pair."""
    selected = [r for r in rows if r['dataset'] == kind and r['estimator'] == estimator]
    estimated = [r for r in selected if 'position_err_mm' in r]

    def stat(key, q, absolute=False):
        values = np.array([r[key] for r in estimated if key in r], dtype=float)
        if absolute:
            values = np.abs(values)
        return float(np.percentile(values, q)) if len(values) else float('nan')

    def mean(values):
        return float(np.mean(values)) if len(values) else float('nan')

    frame_ms = [r['detect_ms'] + r['estimate_ms'] for r in selected if 'estimate_ms' in r]
    vertex_errors = [r['vertex_err_px'] for r in selected if 'vertex_err_px' in r]
    return {
        'dataset': kind, 'estimator': estimator, 'frames': len(selected),
        'detection_rate': sum(r['detected'] for r in selected) / max(1, len(selected)),
        'pose_rate': len(estimated) / max(1, len(selected)),
        'position_err_mm_median': stat('position_err_mm', 50), 'position_err_mm_p90': stat('position_err_mm', 90),
        'depth_err_mm_mean': mean([r['depth_err_mm'] for r in estimated]),
        'abs_depth_err_mm_mean': mean([abs(r['depth_err_mm']) for r in estimated]),
        'abs_depth_err_mm_median': stat('depth_err_mm', 50, absolute=True),
        'abs_depth_err_mm_p90': stat('depth_err_mm', 90, absolute=True),
        'orientation_err_deg_median': stat('orientation_err_deg', 50),
        'orientation_err_deg_p90': stat('orientation_err_deg', 90),
        'vertex_err_px_mean': mean(vertex_errors),
        'vertex_err_px_median': float(np.median(vertex_errors)) if vertex_errors else float('nan'),
        'detect_ms_median': float(np.median([r['detect_ms'] for r in selected])),
        'frame_ms_median': float(np.median(frame_ms)) if frame_ms else float('nan'),
    }


COLUMNS = [('detection_rate', 'detected', '{:.1%}'), ('pose_rate', 'posed', '{:.1%}'),
           ('vertex_err_px_mean', 'vertex mean px', '{:.3f}'), ('vertex_err_px_median', 'vertex med px', '{:.3f}'),
           ('position_err_mm_median', 'pos med mm', '{:.2f}'), ('position_err_mm_p90', 'pos p90 mm', '{:.2f}'),
           ('depth_err_mm_mean', 'dZ mean mm', '{:+.2f}'),
           ('abs_depth_err_mm_mean', '|dZ| mean mm', '{:.2f}'), ('abs_depth_err_mm_p90', '|dZ| p90 mm', '{:.2f}'),
           ('orientation_err_deg_median', 'rot med deg', '{:.2f}'),
           ('orientation_err_deg_p90', 'rot p90 deg', '{:.2f}'), ('frame_ms_median', 'ms/frame', '{:.2f}')]


def format_table(summaries):
    """Markdown table of the summaries (one row per dataset and estimator)."""
    header = '| dataset | estimator | frames | ' + ' | '.join(title for _, title, _ in COLUMNS) + ' |'
    lines = [header, '|' + '---|' * (3 + len(COLUMNS))]
    for s in summaries:
        cells = [fmt.format(s[key]) for key, _, fmt in COLUMNS]
        lines.append('| %s | %s | %d | %s |' % (s['dataset'], s['estimator'], s['frames'], ' | '.join(cells)))
    return '\n'.join(lines)


def seed_list(text):
    """The integer seeds of a ``--seeds`` value (comma-separated); ArgumentTypeError otherwise."""
    try:
        seeds = [int(part) for part in text.split(',') if part.strip()]
    except ValueError:
        raise argparse.ArgumentTypeError(f'expected comma-separated integers, got {text!r}') from None
    if not seeds:
        raise argparse.ArgumentTypeError('no seed given')
    return seeds


def dataset_list(text):
    """The dataset names of a ``--datasets`` value: comma-separated names, ``project`` (the project renderer's
    sets), ``r2`` (the independent renderer's) or ``all``; ArgumentTypeError on an unknown name."""
    groups = {'project': PROJECT_DATASETS, 'r2': R2_DATASETS, 'all': PROJECT_DATASETS + R2_DATASETS}
    names = []
    for name in filter(None, (part.strip() for part in text.split(','))):
        for kind in groups.get(name, (name,)):
            if kind not in PROJECT_DATASETS + R2_DATASETS:
                raise argparse.ArgumentTypeError(f'unknown dataset {kind!r}; known: project, r2, all, '
                                                 + ', '.join(PROJECT_DATASETS + R2_DATASETS))
            if kind not in names:
                names.append(kind)
    if not names:
        raise argparse.ArgumentTypeError('no dataset named')
    return names


def main(argv=None):
    parser = argparse.ArgumentParser(prog='bench_perception.py', description=command_summary(__doc__))
    parser.add_argument('--datasets', type=dataset_list, default=list(PROJECT_DATASETS + R2_DATASETS),
                        help='comma-separated: %s, or the groups project, r2, all (default all)'
                             % ', '.join(PROJECT_DATASETS + R2_DATASETS))
    parser.add_argument('--frames', type=int, default=300, help='frames in the mixed and green40 datasets')
    parser.add_argument('--r2-frames', type=int, default=150, help='frames in each _r2 dataset')
    parser.add_argument('--seed', type=int, default=1)
    parser.add_argument('--out', default='out/bench_perception', help='directory for the CSV and JSON results')
    parser.add_argument('--vision-config', metavar='YAML', help='vision parameters (default config/vision.yaml)')
    parser.add_argument('--worst', type=int, default=0, metavar='N',
                        help='save crops of the N found targets with the largest vertex error and of N missed ones '
                             '(truth green, target red, other detections yellow)')
    parser.add_argument('--worst-dir', default=None, help='where the crops go (default OUT/worst)')
    parser.add_argument('--seeds', type=seed_list, default=[], metavar='S1,S2,...',
                        help='also draw each dataset from these seeds (sqp only) and print detection and accuracy per '
                             'seed: the spread between draws of one set, against which a change is judged')
    parser.add_argument('--latency-frames', type=int, default=150, metavar='N',
                        help='frames of each dataset rendered at 640x400 (a Baxter hand camera\'s mode) for the '
                             'latency table, vision + sqp (default 150; depth161 has 56; 0: no latency table)')
    parser.add_argument('--border-cut-frames', type=int, default=40, metavar='N',
                        help='frames of each dataset whose block is cut by the image border (at %s %%%% of its '
                             'extent; default 40; 0: no border-cut table)'
                             % ', '.join('%d' % (100 * f) for f in BORDER_CUT_FRACTIONS))
    parser.add_argument('--photometric-frames', type=int, default=40, metavar='N',
                        help='frames of each _r2 dataset, and the real frames with no block (--real), measured '
                             'under exposure, cast, gamma, vignetting, glow and saturation changes (default 40; 0: '
                             'no photometric tables)')
    parser.add_argument('--as-picked-frames', type=int, default=150, metavar='N',
                        help='frames of each _r2 set looked at as a pick looks (observe_blocks with the table plane '
                             'and the pick\'s belief rules; bench/as_picked.py; default 150, 0: no table)')
    parser.add_argument('--composite-frames', type=int, default=150, metavar='N',
                        help='blocks of each _r2 set put into the real hand-camera frames (--real) where these show '
                             'a bare table or floor (bench/composite.py; default 150, 0: no table)')
    parser.add_argument('--real', default=REAL_DEFAULT, metavar='DIR',
                        help='the real images (default ../shared/real beside the repository, or '
                             '$BAXTER_PNP_REAL_DATA); their blockless frames are counted when present')
    args = parser.parse_args(argv)
    limit_to_one_core()
    camera = camera_module.load_default_camera()
    config = vision.VisionConfig.from_yaml(args.vision_config)
    counts = {'mixed': args.frames, 'green40': args.frames, 'depth161': 56}
    rows, crops = [], {} if args.worst else None
    for kind in args.datasets:
        samples = make_dataset(kind, counts.get(kind, args.r2_frames), set_seed(kind, args.seed), camera)
        rows += run_dataset(kind, samples, camera, config, set_seed(kind, args.seed), crops)
    summaries = [summarise(rows, kind, estimator) for kind in args.datasets for estimator in ESTIMATORS]
    os.makedirs(args.out, exist_ok=True)
    with open(os.path.join(args.out, 'frames.csv'), 'w', newline='') as f:
        keys = sorted({k for r in rows for k in r})
        writer = csv.DictWriter(f, fieldnames=keys)
        writer.writeheader()
        writer.writerows(rows)
    with open(os.path.join(args.out, 'summary.json'), 'w') as f:
        json.dump(summaries, f, indent=1)
    for title, kinds in (('project renderer (synthetic.py)', PROJECT_DATASETS),
                         ('independent renderer (render_independent.py)', R2_DATASETS)):
        chosen = [s for s in summaries if s['dataset'] in kinds]
        if chosen:
            print('\n%s\n\n%s' % (title, format_table(chosen)))
    if args.seeds:
        spread = measure_seed_spread(args.datasets, args.seeds, {**{kind: args.r2_frames for kind in R2_DATASETS},
                                                                 **counts}, camera, config)
        with open(os.path.join(args.out, 'seed_spread.json'), 'w') as f:
            json.dump(spread, f, indent=1)
        print('\nthe same sets drawn from other seeds (sqp)\n\n%s' % format_seed_spread(spread))
    if args.latency_frames > 0:
        counts = {kind: 56 if kind == 'depth161' else args.latency_frames for kind in args.datasets}
        latency = measure_latency(args.datasets, counts, args.seed, hand_camera(camera), config)
        with open(os.path.join(args.out, 'latency.json'), 'w') as f:
            json.dump(latency, f, indent=1)
        print('\nlatency at %dx%d (vision + sqp, one core)\n\n%s' % (*HAND_CAMERA_MODE, format_latency(latency)))
    if args.border_cut_frames > 0:
        cuts = measure_border_cuts(args.datasets, args.border_cut_frames, args.seed, camera, config)
        with open(os.path.join(args.out, 'border_cuts.json'), 'w') as f:
            json.dump(cuts, f, indent=1)
        print('\nblocks cut by the image border\n\n%s' % format_border_cuts(cuts))
    if args.photometric_frames > 0:
        false_found, frame_count, blocks = measure_photometric(args.datasets, args.photometric_frames, args.seed,
                                                               camera, config, args.real)
        found_json = {kind: {variant: list(count) for variant, count in found.items()}
                      for kind, found in blocks.items()}
        with open(os.path.join(args.out, 'photometric.json'), 'w') as f:
            json.dump({'false_detections': false_found, 'real_frames': frame_count, 'blocks_found': found_json}, f,
                      indent=1)
        print('\nphotometric changes (real frames with no block%s; real cubes; independent renderer\'s blocks)\n\n%s'
              % ('' if frame_count else ': none at %s' % args.real,
                 photometric.format_tables(false_found, frame_count, blocks)))
    if args.as_picked_frames > 0 and any(kind in R2_DATASETS for kind in args.datasets):
        picked = measure_as_picked(args.datasets, {kind: args.as_picked_frames for kind in R2_DATASETS}, args.seed,
                                   camera, config)
        with open(os.path.join(args.out, 'as_picked.json'), 'w') as f:
            json.dump(picked, f, indent=1)
        print('\nas a pick looks (observe_blocks with the true table plane and edge radius, the pick\'s belief rules)'
              '\n\n%s' % as_picked.format_as_picked(picked))
    if args.composite_frames > 0 and any(kind in R2_DATASETS for kind in args.datasets):
        composites = measure_composites(args.datasets, args.composite_frames, args.seed, config, args.real)
        with open(os.path.join(args.out, 'composites.json'), 'w') as f:
            json.dump(composites, f, indent=1)
        print('\nblocks put into real hand-camera frames%s\n\n%s' % (
            '' if composites else ': no frames at %s' % args.real, composite.format_table(composites)))
    if args.worst:
        directory = args.worst_dir or os.path.join(args.out, 'worst')
        save_worst(rows, crops, directory, args.worst)
        print('\n(the %d worst and missed frames: %s/, listed in worst.tsv)' % (args.worst, directory))
    print('\n(per-frame results: %s/frames.csv; summary: %s/summary.json, latency.json, border_cuts.json, '
          'photometric.json, seed_spread.json, as_picked.json, composites.json)' % (args.out, args.out))
    return 0
