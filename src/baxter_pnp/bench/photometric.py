"""Photometric robustness (``make bench-perception``'s last tables): the real frames that show no coloured block
(``../shared/real``: the Baxter lab frames, the blue-tinted chessboard frames and the printed shapes), the real
cubes labelled in ``tests/data/real_labels.yaml`` and the independent renderer's blocks, each under the changes
another camera, exposure or lab brings: exposure, a colour cast, gamma, vignetting, a coloured glow in an image
corner, saturation; and what differs between two frames of one scene: a second JPEG round trip, sensor noise.
Counted: what the vision finds on the blockless frames (all of it is false) and how many blocks it still finds.
A detector tuned on a few real frames can be right on them and wrong one exposure step away (docs/perception.md,
"Fragments of larger coloured areas").

Images are BGR uint8 in and out; every change is deterministic."""
import glob
import os

import cv2
import numpy as np
import yaml

from baxter_pnp import vision
from baxter_pnp.bench import render_independent

REAL_NEGATIVES = ('baxter_hand_a/*.jpg', 'baxter_hand_b/*.png', 'printed_shapes/*.jpg')   # under the real folder
GLOW_BGR = (0.0, 10.0, 60.0)       # a reddish glow (lens flare, a warm lamp) added at the top-left corner ...
GLOW_SIGMA_FRACTION = 0.125        # ... a Gaussian of this fraction of the image width
FOUND_CENTROID_FRACTION = 0.15     # a block is found when its detection's centroid lies within this fraction of
                                   # its size (the square root of its projected area) of the true one
CUBE_CENTROID_PX = 4.0             # a labelled real cube, when within this of its labelled centre (its test's)


def _gains(image, gains_bgr):
    return np.clip(image.astype(np.float32) * np.asarray(gains_bgr, np.float32), 0, 255).astype(np.uint8)


def _gamma(image, gamma):
    table = np.clip(255.0 * (np.arange(256) / 255.0) ** gamma + 0.5, 0, 255).astype(np.uint8)
    return cv2.LUT(image, table)


def _vignetting(image, strength):
    h, w = image.shape[:2]
    v, u = np.mgrid[:h, :w]
    radial = ((u - w / 2.0) ** 2 + (v - h / 2.0) ** 2) / ((w / 2.0) ** 2 + (h / 2.0) ** 2)
    return np.clip(image * (1.0 - strength * radial)[..., None], 0, 255).astype(np.uint8)


def _corner_glow(image):
    h, w = image.shape[:2]
    v, u = np.mgrid[:h, :w]
    glow = np.exp(-(u ** 2 + v ** 2) / (2.0 * (GLOW_SIGMA_FRACTION * w) ** 2))
    return np.clip(image + glow[..., None] * np.asarray(GLOW_BGR), 0, 255).astype(np.uint8)


def _jpeg_again(image, quality):
    _, buffer = cv2.imencode('.jpg', image, [cv2.IMWRITE_JPEG_QUALITY, quality])
    return cv2.imdecode(buffer, cv2.IMREAD_COLOR)


def _sensor_noise(image, sigma):
    noise = np.random.default_rng(0).normal(0.0, sigma, image.shape)       # the same noise each time: deterministic
    return np.clip(image + noise, 0, 255).astype(np.uint8)


def _saturation(image, factor):
    hsv = cv2.cvtColor(image, cv2.COLOR_BGR2HSV).astype(np.float32)
    hsv[..., 1] *= factor
    return cv2.cvtColor(np.clip(hsv, 0, 255).astype(np.uint8), cv2.COLOR_HSV2BGR)


VARIANTS = {
    'as taken': lambda image: image,
    'exposure x0.6': lambda image: _gains(image, (0.6, 0.6, 0.6)),
    'exposure x1.4': lambda image: _gains(image, (1.4, 1.4, 1.4)),
    'warm cast': lambda image: _gains(image, (0.85, 1.0, 1.15)),
    'cool cast': lambda image: _gains(image, (1.15, 1.0, 0.85)),
    'green cast': lambda image: _gains(image, (0.92, 1.1, 0.92)),
    'gamma 0.7': lambda image: _gamma(image, 0.7),
    'gamma 1.4': lambda image: _gamma(image, 1.4),
    'vignetting 0.5': lambda image: _vignetting(image, 0.5),
    'red glow in a corner': _corner_glow,
    'saturation x1.5': lambda image: _saturation(image, 1.5),
    'JPEG again (q 80)': lambda image: _jpeg_again(image, 80),
    'sensor noise (sigma 2)': lambda image: _sensor_noise(image, 2.0),
}


def real_negative_frames(real_dir):
    """[(relative path, BGR image)] of the real frames that show no coloured block, [] when ``real_dir`` is absent."""
    paths = sorted(p for pattern in REAL_NEGATIVES for p in glob.glob(os.path.join(real_dir, pattern)))
    frames = [(os.path.relpath(p, real_dir), cv2.imread(p)) for p in paths]
    return [(name, image) for name, image in frames if image is not None]


def real_cubes_found(real_dir, labels_path, config):
    """{variant: (found, count)} of the labelled cubes (``labels_path``: ``tests/data/real_labels.yaml``, pixel
    centres of the photos in ``real_dir``/coloured_cubes, stored with red and blue swapped) under each of
    ``VARIANTS``: a square of the label's colour within ``CUBE_CENTROID_PX`` of its centre; {} without the photos or
    the labels."""
    if not os.path.exists(labels_path):
        return {}
    with open(labels_path) as f:
        labels = yaml.safe_load(f)
    counts = {variant: [0, 0] for variant in VARIANTS}
    for name, entry in labels['images'].items():
        image = cv2.imread(os.path.join(real_dir, 'coloured_cubes', name))
        if image is None:
            return {}
        image = np.ascontiguousarray(image[..., ::-1])
        for variant, change in VARIANTS.items():
            detections = vision.detect(change(image), config)
            counts[variant][1] += len(entry['cubes'])
            counts[variant][0] += sum(any(d.colour == cube['colour'] and d.shape == 'square'
                                          and np.linalg.norm(d.centroid_px - cube['centre']) <= CUBE_CENTROID_PX
                                          for d in detections) for cube in entry['cubes'])
    return {variant: tuple(count) for variant, count in counts.items()}


def false_detections(frames, config):
    """{variant: [(frame, colour, shape, (u, v))]}: every detection (all of them false) on ``frames`` under each
    of ``VARIANTS``."""
    found = {}
    for variant, change in VARIANTS.items():
        found[variant] = [(name, d.colour, d.shape, tuple(np.round(d.centroid_px, 1)))
                          for name, image in frames for d in vision.detect(change(image), config)]
    return found


def blocks_found(samples, camera, config, rng):
    """{variant: (found, count)} of the independent renderer's ``samples`` ((block, T_camera_block, colour), as
    ``perception_bench.make_dataset`` gives them) under each of ``VARIANTS``: the target of the block's shape and
    colour (``vision.select_target``) within ``FOUND_CENTROID_FRACTION`` of its size of the true centroid."""
    counts = {variant: [0, 0] for variant in VARIANTS}
    for block, T_camera_block, colour in samples:
        image, truths = render_independent.render_scene(camera, [(block, T_camera_block)], rng)
        centre = truths[0]['centroid_px']
        size = np.sqrt(abs(cv2.contourArea(truths[0]['vertices_px'].astype(np.float32))))
        for variant, change in VARIANTS.items():
            target = vision.select_target(vision.detect(change(image), config), block.shape, colour,
                                          (camera.width, camera.height))
            counts[variant][1] += 1
            counts[variant][0] += bool(target is not None and np.linalg.norm(target.centroid_px - centre)
                                       <= FOUND_CENTROID_FRACTION * size)
    return {variant: tuple(count) for variant, count in counts.items()}


def format_tables(false_found, frame_count, blocks):
    """Markdown: the false detections on the real frames per variant, and ``blocks`` ({dataset: blocks_found's or
    real_cubes_found's result}) found per variant."""
    lines = ['| change | false detections on %d real frames | of them squares |' % frame_count, '|---|---|---|']
    lines += ['| %s | %d | %d |' % (variant, len(found), sum(shape == 'square' for _, _, shape, _ in found))
              for variant, found in false_found.items()]
    if blocks:
        lines += ['', '| change | ' + ' | '.join('%s found' % kind for kind in blocks) + ' |',
                  '|---|' + '---|' * len(blocks)]
        lines += ['| %s | ' % variant + ' | '.join('%d/%d' % blocks[kind][variant] for kind in blocks) + ' |'
                  for variant in VARIANTS]
    return '\n'.join(lines)
