"""Perception benchmark (``make bench-perception``): renders its own ground-truth dataset, runs the
vision pipeline and every pose estimator on the same vertices, and prints the results side by side.

Datasets (thesis camera, 640x480, lens distortion, lighting gradient, noise, blur, JPEG; blocks 2 cm thick
so side faces show at oblique views):

- ``mixed``: triangles to hexagons of every named colour, 30-60 mm sides, 0.10-0.40 m away, up to 35 deg tilt;
- ``green40``: 40 mm green squares in the same range of poses (the acceptance set);
- ``depth161``: a 40 mm green square seen straight on at 161 mm (the thesis's depth experiment), 56 renders.

Errors are against the renderer's ground truth: position of the top-face centre (mm), depth (z, mm),
orientation (deg, modulo the shape's symmetry). Times are per frame on one core (OpenCV and BLAS limited
to one thread): ``detect`` for the vision pipeline, then each estimator's own time.
"""
import argparse
import csv
import json
import os
import time

import numpy as np

from baxter_pnp import camera as camera_module
from baxter_pnp import models, pose, synthetic, vision
from baxter_pnp.transforms import make_transform

COLOURS_BGR = {'green': (40, 170, 40), 'red': (40, 40, 200), 'blue': (200, 90, 30), 'yellow': (30, 200, 220)}
ESTIMATORS = ('sqp', 'sqp+plane', 'ippe', 'sqpnp')
BLOCK_HEIGHT = 0.02


def limit_to_one_core():
    """Make the timing honest: one OpenCV thread (BLAS threads are set by the entry point's env)."""
    import cv2
    cv2.setNumThreads(1)


def make_dataset(kind, count, seed, camera):
    """List of (BlockSpec, T_camera_block, colour name) for dataset ``kind``."""
    rng = np.random.default_rng(seed)
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


def true_table_plane(T_camera_block):
    """The table-top plane (the block's bottom face) in the camera frame, normal towards the block's top."""
    normal = T_camera_block[:3, 2]
    bottom_centre = T_camera_block[:3, 3] - BLOCK_HEIGHT * normal
    return models.Plane(normal, float(normal @ bottom_centre))


def run_dataset(kind, samples, camera, config, seed):
    """Render, detect and estimate every sample; returns one result dict per (sample, estimator)."""
    rng = np.random.default_rng(seed + 1)
    rows = []
    for index, (spec, T_true, colour) in enumerate(samples):
        image, truths = synthetic.render_block_scene(camera, [(spec, T_true)], rng)
        start = time.perf_counter()
        detections = vision.detect(image, config)
        detect_ms = 1000.0 * (time.perf_counter() - start)
        target = vision.select_target(detections, spec.shape, colour, (camera.width, camera.height))
        base = {'dataset': kind, 'index': index, 'shape': spec.shape, 'colour': colour, 'side_m': spec.side,
                'distance_m': float(np.linalg.norm(T_true[:3, 3])), 'detect_ms': detect_ms,
                'detected': target is not None}
        if target is not None:
            base['vertex_err_px'] = _vertex_error_px(target.vertices_px, truths[0]['vertices_px'])
        model = models.model_for(spec.shape, spec.side, spec.height)
        for estimator in ESTIMATORS:
            row = dict(base, estimator=estimator)
            if target is not None:
                method = estimator.split('+')[0]
                plane = true_table_plane(T_true) if estimator.endswith('+plane') else None
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


def _vertex_error_px(detected, true):
    """Mean distance (px) between detected vertices and the true ones, matched by nearest neighbour."""
    distances = np.linalg.norm(detected[:, None, :] - true[None, :, :], axis=2)
    return float(np.mean(distances.min(axis=1)))


def summarise(rows, kind, estimator):
    """Statistics of one (dataset, estimator) pair."""
    selected = [r for r in rows if r['dataset'] == kind and r['estimator'] == estimator]
    estimated = [r for r in selected if 'position_err_mm' in r]

    def stat(key, q, absolute=False):
        values = np.array([r[key] for r in estimated if key in r], dtype=float)
        if absolute:
            values = np.abs(values)
        return float(np.percentile(values, q)) if len(values) else float('nan')

    frame_ms = [r['detect_ms'] + r['estimate_ms'] for r in selected if 'estimate_ms' in r]
    return {
        'dataset': kind, 'estimator': estimator, 'frames': len(selected),
        'detection_rate': sum(r['detected'] for r in selected) / max(1, len(selected)),
        'pose_rate': len(estimated) / max(1, len(selected)),
        'position_err_mm_median': stat('position_err_mm', 50), 'position_err_mm_p90': stat('position_err_mm', 90),
        'depth_err_mm_mean': float(np.mean([r['depth_err_mm'] for r in estimated])) if estimated else float('nan'),
        'abs_depth_err_mm_mean': float(np.mean([abs(r['depth_err_mm']) for r in estimated])) if estimated else float('nan'),
        'abs_depth_err_mm_median': stat('depth_err_mm', 50, absolute=True),
        'abs_depth_err_mm_p90': stat('depth_err_mm', 90, absolute=True),
        'orientation_err_deg_median': stat('orientation_err_deg', 50),
        'orientation_err_deg_p90': stat('orientation_err_deg', 90),
        'vertex_err_px_median': float(np.median([r['vertex_err_px'] for r in selected if 'vertex_err_px' in r]
                                                or [np.nan])),
        'detect_ms_median': float(np.median([r['detect_ms'] for r in selected])),
        'frame_ms_median': float(np.median(frame_ms)) if frame_ms else float('nan'),
    }


COLUMNS = [('detection_rate', 'detected', '{:.1%}'), ('pose_rate', 'posed', '{:.1%}'),
           ('position_err_mm_median', 'pos med mm', '{:.2f}'), ('position_err_mm_p90', 'pos p90 mm', '{:.2f}'),
           ('abs_depth_err_mm_mean', '|dZ| mean mm', '{:.2f}'), ('abs_depth_err_mm_p90', '|dZ| p90 mm', '{:.2f}'),
           ('orientation_err_deg_median', 'rot med deg', '{:.2f}'), ('orientation_err_deg_p90', 'rot p90 deg', '{:.2f}'),
           ('vertex_err_px_median', 'vertex px', '{:.3f}'), ('frame_ms_median', 'ms/frame', '{:.2f}')]


def format_table(summaries):
    """Markdown table of the summaries (one row per dataset and estimator)."""
    header = '| dataset | estimator | frames | ' + ' | '.join(title for _, title, _ in COLUMNS) + ' |'
    lines = [header, '|' + '---|' * (3 + len(COLUMNS))]
    for s in summaries:
        cells = [fmt.format(s[key]) for key, _, fmt in COLUMNS]
        lines.append('| %s | %s | %d | %s |' % (s['dataset'], s['estimator'], s['frames'], ' | '.join(cells)))
    return '\n'.join(lines)


def main(argv=None):
    parser = argparse.ArgumentParser(prog='bench_perception.py', description=__doc__.split('\n')[0])
    parser.add_argument('--frames', type=int, default=300, help='frames in the mixed and green40 datasets')
    parser.add_argument('--seed', type=int, default=1)
    parser.add_argument('--out', default='out/bench_perception', help='directory for the CSV and JSON results')
    parser.add_argument('--vision-config', metavar='YAML', help='vision parameters (default config/vision.yaml)')
    args = parser.parse_args(argv)
    limit_to_one_core()
    camera = camera_module.load_default_camera()
    config = vision.VisionConfig.from_yaml(args.vision_config)
    rows = []
    plan = [('mixed', args.frames), ('green40', args.frames), ('depth161', 56)]
    for offset, (kind, count) in enumerate(plan):
        samples = make_dataset(kind, count, args.seed + 100 * offset, camera)
        rows += run_dataset(kind, samples, camera, config, args.seed + 100 * offset)
    summaries = [summarise(rows, kind, estimator) for kind, _ in plan for estimator in ESTIMATORS]
    os.makedirs(args.out, exist_ok=True)
    with open(os.path.join(args.out, 'frames.csv'), 'w', newline='') as f:
        keys = sorted({k for r in rows for k in r})
        writer = csv.DictWriter(f, fieldnames=keys)
        writer.writeheader()
        writer.writerows(rows)
    with open(os.path.join(args.out, 'summary.json'), 'w') as f:
        json.dump(summaries, f, indent=1)
    print(format_table(summaries))
    print('\n(per-frame results: %s/frames.csv; summary: %s/summary.json)' % (args.out, args.out))
    return 0
