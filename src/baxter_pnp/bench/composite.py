"""Rendered blocks put into real hand-camera frames (beyond the thesis): the independent renderer's blocks, their
shadows and ground truth, composited into real Baxter hand-camera frames where these show a bare table or floor.

The renderer's light, table and camera are its own guesses; a real frame has the real ones (its light's level and
colour, the camera's white balance, noise, blur and JPEG, the table's texture) and real clutter around (a
chessboard, laptops, cables, an e-stop box). ``render_independent.render_layers`` gives the blocks as layers on the
radiance scale of its table: the composite is the real frame darkened by the blocks' shadows, and over it the
blocks' colour times the real light, the real frame blurred wide (``LIGHT_SIGMA_PX``) over the rendered table's
radiance: a block as bright against the real table as against the rendered one. Blur, noise and a JPEG round trip
of the block as the look's. A block is placed only where the frame under it and its shadow is table-like
(``table_like``): on a chessboard square or a laptop it would take that surface's brightness as its light.

Frames: ``baxter_hand_a`` (the robot's own CameraInfo) and ``baxter_hand_b`` (its self-calibration, no
distortion), 640x400, under the real folder (``../shared/real``); none of them shows a coloured block, so every
other detection is a false one. Images BGR uint8; pixels (u, v).
"""
import glob
import os

import cv2
import numpy as np

from baxter_pnp import models, pick, vision
from baxter_pnp.bench import as_picked, render_independent
from baxter_pnp.camera import CameraModel

HAND_A = ('baxter_hand_a/*.jpg', 'baxter_hand_a/camera_info_as_published.yaml')
HAND_B = 'baxter_hand_b/*.png'
HAND_B_K = ((410.6, 0.0, 330.0), (0.0, 409.0, 225.5), (0.0, 0.0, 1.0))   # its frames' self-calibration (README)
LIGHT_SIGMA_PX = 12.0          # the real light: the frame blurred this wide
PLACE_MARGIN_PX = 10           # the frame around a block and its shadow must be table-like this far out ...
TABLE_MAX_STD = 10.0           # ... its grey level's standard deviation at most this (cables, print, edges: more)
TABLE_MAX_TINT = 18.0          # ... its mean channels within this of each other (a grey table or floor)
TABLE_GREY = (35.0, 200.0)     # ... and its mean grey level in this range (not a shadow's black, not white paper)
JPEG_GRID_PX = 16              # JPEG's macroblock (4:2:0): a window on this grid re-encodes alone
FOUND_FRACTION = 0.5           # a block is found when a detection of its colour and shape lies within this of a side
TABLE_HEIGHT_SIGMA = pick.PickConfig().table_height_sigma   # m: the table's height as a robot knows it


def real_backgrounds(real_dir):
    """[(name, BGR image, CameraModel)] of the real hand-camera frames under ``real_dir``; [] when absent."""
    frames = []
    info = os.path.join(real_dir, HAND_A[1])
    if os.path.exists(info):
        camera_a = CameraModel.from_yaml(info)
        frames += [(path, camera_a) for path in sorted(glob.glob(os.path.join(real_dir, HAND_A[0])))]
    camera_b = CameraModel(640, 400, np.array(HAND_B_K), np.zeros(5), name='baxter_hand_b', frame_id='left_hand_camera')
    frames += [(path, camera_b) for path in sorted(glob.glob(os.path.join(real_dir, HAND_B)))]
    loaded = [(os.path.relpath(path, real_dir), cv2.imread(path), camera) for path, camera in frames]
    return [(name, image, camera) for name, image, camera in loaded
            if image is not None and image.shape[:2] == (camera.height, camera.width)]


def table_like(image, box):
    """True when ``image`` (BGR uint8) within ``box`` = (x0, y0, x1, y1) is a bare table or floor (``TABLE_*``)."""
    x0, y0, x1, y1 = box
    patch = image[y0:y1, x0:x1].reshape(-1, 3).astype(np.float32)
    if len(patch) == 0:
        return False
    mean = patch.mean(axis=0)
    grey = patch.mean(axis=1)
    return bool(grey.std() <= TABLE_MAX_STD and np.ptp(mean) <= TABLE_MAX_TINT
                and TABLE_GREY[0] <= grey.mean() <= TABLE_GREY[1])


def footprint(alpha, shadow, margin=PLACE_MARGIN_PX):
    """(x0, y0, x1, y1) around what the layers change (a block and its shadow) plus ``margin`` px, or None."""
    rows, cols = np.nonzero((alpha > 0.01) | (shadow < 0.99))
    if len(rows) == 0:
        return None
    h, w = alpha.shape
    return (max(cols.min() - margin, 0), max(rows.min() - margin, 0),
            min(cols.max() + margin + 1, w), min(rows.max() + margin + 1, h))


def composite(background, layers, look, rng):
    """``background`` (BGR uint8) with ``render_independent.render_layers``'s ``layers`` = (colour, alpha, shadow,
    table_bgr) put in (module docstring), then the ``look``'s blur and noise on the block and a JPEG round trip of the
    window around what changed (``JPEG_GRID_PX``-aligned: the rest of the frame stays as the camera sent it)."""
    colour, alpha, shadow, table_bgr = layers
    real = background.astype(np.float32)
    light = cv2.GaussianBlur(real, (0, 0), LIGHT_SIGMA_PX) / np.maximum(table_bgr, 1.0)
    if look.blur_sigma:
        colour = cv2.GaussianBlur(colour, (0, 0), look.blur_sigma)
        alpha = cv2.GaussianBlur(alpha, (0, 0), look.blur_sigma)
    image = real * (shadow * (1.0 - alpha))[..., None] + colour * light
    if look.noise_sigma:
        noise = rng.normal(0.0, look.noise_sigma, image.shape).astype(np.float32)
        image += noise * alpha[..., None]
    image = cv2.convertScaleAbs(np.maximum(image, 0.0))
    box = footprint(alpha, shadow)
    if look.jpeg_quality and box is not None:
        h, w = image.shape[:2]
        x0, y0 = (box[0] // JPEG_GRID_PX) * JPEG_GRID_PX, (box[1] // JPEG_GRID_PX) * JPEG_GRID_PX
        x1, y1 = min(-(-box[2] // JPEG_GRID_PX) * JPEG_GRID_PX, w), min(-(-box[3] // JPEG_GRID_PX) * JPEG_GRID_PX, h)
        _, buffer = cv2.imencode('.jpg', image[y0:y1, x0:x1], [cv2.IMWRITE_JPEG_QUALITY, int(look.jpeg_quality)])
        image[y0:y1, x0:x1] = cv2.imdecode(buffer, cv2.IMREAD_COLOR)
    return image


def place(samples, backgrounds, rng, tries=None):
    """[(sample, name, composite BGR, camera, truth)]: each ``(block, T_camera_block, colour)`` of ``samples`` put into
    the first of the ``backgrounds`` (shuffled, ``tries`` of them at most) where it lands on a table-like area;
    samples that fit nowhere are left out."""
    placed = []
    for block, T, colour in samples:
        for index in rng.permutation(len(backgrounds))[:tries]:
            name, background, camera = backgrounds[index]
            look = render_independent.random_look(rng)
            colour_layer, alpha, shadow, table_bgr, truths = render_independent.render_layers(
                camera, [(block, T)], rng, look)
            box = footprint(alpha, shadow)
            if box is None or not truths[0]['visible'] or not table_like(background, box):
                continue
            image = composite(background, (colour_layer, alpha, shadow, table_bgr), look, rng)
            placed.append(((block, T, colour), name, image, camera, truths[0]))
            break
    return placed


def measure(kind, samples, backgrounds, config, rng):
    """One row of the composite table for dataset ``kind``: of ``samples`` placed into ``backgrounds``, the share
    found (a detection of the block's colour and shape within ``FOUND_FRACTION`` of a side of its centre), the false
    detections ([(frame, colour, shape, (u, v))]: any other; the frames show no block), the found ones' mean vertex
    error (px) and, as a pick looks (``as_picked.look_at``, the table's height known to ``TABLE_HEIGHT_SIGMA``), the
    share right at the first look and the position error's median (mm)."""
    placed = place(samples, backgrounds, rng)
    found, false, vertex_errors, looks = 0, [], [], []
    for (block, T, colour), name, image, camera, truth in placed:
        size = np.sqrt(cv2.contourArea(truth['vertices_px'].astype(np.float32)))
        detections = vision.detect(image, config)
        mine = [d for d in detections if d.colour == colour and d.shape == block.shape
                and np.linalg.norm(d.centroid_px - truth['centroid_px']) <= FOUND_FRACTION * size]
        false += [(name, d.colour, d.shape, tuple(np.round(d.centroid_px, 1).tolist())) for d in detections
                  if np.linalg.norm(d.centroid_px - truth['centroid_px']) > size]
        if mine:
            found += 1
            vertices = mine[0].vertices_px
            vertex_errors.append(float(np.mean([np.min(np.linalg.norm(truth['vertices_px'] - v, axis=1))
                                                for v in vertices])))
        true_plane = as_picked.true_table_plane(T, block.height)
        known = models.Plane(true_plane.normal, true_plane.offset + rng.normal(0.0, TABLE_HEIGHT_SIGMA))
        looks.append(as_picked.look_at(image, block, colour, T, known, camera, config))
    n = max(1, len(placed))
    summary = as_picked.summarise_looks(kind, looks)
    return {'dataset': kind, 'samples': len(samples), 'placed': len(placed),
            'backgrounds': len({name for _, name, *_ in placed}), 'found': found / n, 'false_detections': false,
            'vertex_err_px_mean': float(np.mean(vertex_errors)) if vertex_errors else float('nan'),
            'right_first_look': summary['right'], 'position_err_mm_median': summary['position_err_mm_median']}


def format_table(rows):
    """Markdown table of ``measure``'s rows."""
    lines = ['| dataset | placed of | real frames | found | false detections | vertex mean px | right at first look '
             '| pos med mm |', '|---|---|---|---|---|---|---|---|']
    lines += ['| %s | %d of %d | %d | %.1f%% | %d | %.3f | %.1f%% | %.2f |' % (
        r['dataset'], r['placed'], r['samples'], r['backgrounds'], 100.0 * r['found'], len(r['false_detections']),
        r['vertex_err_px_mean'], 100.0 * r['right_first_look'], r['position_err_mm_median']) for r in rows]
    return '\n'.join(lines)
