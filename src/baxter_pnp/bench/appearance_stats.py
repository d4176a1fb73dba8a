"""Real and rendered hand-camera frames side by side: the image statistics the fake's ``appearance`` is matched on.

``python3 scripts/bench_appearance.py [--real DIR ...] [--out DIR]`` prints, for each folder of real frames
(default ``../shared/real/baxter_hand_a`` and ``baxter_hand_b``) and for the fake's renders under each preset
(``clean``, ``baxter``; the default scene seen from the ``down`` and ``angled`` start poses and from 8 random hand
poses over the table), the median and range over the frames of: lightness (CIELAB L*, 0-100: median, 10th and 90th
percentile), chroma (median, 95th percentile), noise (grey levels: the residual of a 3x3 median filter on the
flattest 30 % of the image, per channel B, G, R), the colour of grey (B/G and R/G of the achromatic pixels) and
vignetting (mean L* beyond 0.9 of the half-width from the centre over mean L* within 0.3). ``--out`` writes one
picture of each for the README.
"""
import argparse
import glob
import os

import cv2
import numpy as np

from baxter_pnp.runtime import PACKAGE_ROOT, command_summary

REAL_DEFAULT = [os.path.join(PACKAGE_ROOT, '..', 'shared', 'real', name) for name in ('baxter_hand_a', 'baxter_hand_b')]
STATISTICS = ('L_median', 'L_p10', 'L_p90', 'chroma_median', 'chroma_p95', 'noise_bgr', 'grey_b_over_g',
              'grey_r_over_g', 'corner_over_centre')


def image_statistics(bgr):
    """dict of the statistics above for one uint8 BGR image."""
    lab = cv2.cvtColor(bgr, cv2.COLOR_BGR2LAB).astype(np.float32)
    lightness = lab[..., 0] * (100.0 / 255.0)
    chroma = np.hypot(lab[..., 1] - 128.0, lab[..., 2] - 128.0)
    height, width = lightness.shape
    rows, cols = np.mgrid[0:height, 0:width]
    radius = np.hypot(cols - width / 2.0, rows - height / 2.0) / (width / 2.0)
    grey = cv2.GaussianBlur(cv2.cvtColor(bgr, cv2.COLOR_BGR2GRAY).astype(np.float32), (5, 5), 0)
    gradient = cv2.Sobel(grey, cv2.CV_32F, 1, 0) ** 2 + cv2.Sobel(grey, cv2.CV_32F, 0, 1) ** 2
    flat = gradient < np.percentile(gradient, 30)
    noise = [float((bgr[..., c].astype(np.float32) - cv2.medianBlur(bgr[..., c], 3))[flat].std()) for c in range(3)]
    achromatic = bgr[chroma < 8].astype(np.float64)
    b, g, r = achromatic.mean(axis=0) if len(achromatic) else (np.nan,) * 3
    return {'L_median': float(np.median(lightness)), 'L_p10': float(np.percentile(lightness, 10)),
            'L_p90': float(np.percentile(lightness, 90)), 'chroma_median': float(np.median(chroma)),
            'chroma_p95': float(np.percentile(chroma, 95)), 'noise_bgr': noise,
            'grey_b_over_g': float(b / g), 'grey_r_over_g': float(r / g),
            'corner_over_centre': float(lightness[radius > 0.9].mean() / max(lightness[radius < 0.3].mean(), 1e-6))}


def summarise(images):
    """{statistic: (median, min, max)} over ``images`` (each value an array for per-channel statistics)."""
    rows = [image_statistics(image) for image in images]
    return {key: tuple(np.round(f(np.array([row[key] for row in rows]), axis=0), 3)
                       for f in (np.median, np.min, np.max)) for key in STATISTICS}


def real_frames(folder):
    paths = sorted(glob.glob(os.path.join(folder, '*.jpg')) + glob.glob(os.path.join(folder, '*.png')))
    return [cv2.imread(path) for path in paths]


def rendered_frames(preset, seed=0, random_poses=8):
    """Frames of the fake's left hand camera (640x400) on the default scene under ``preset``."""
    import dataclasses
    from baxter_pnp.kinematics import ArmKinematics
    from baxter_pnp.sim.appearance import AppearanceConfig, expand
    from baxter_pnp.sim.cameras import sensor_model, sensor_window
    from baxter_pnp.sim.scene import load_scene
    from baxter_pnp.sim.world import SimWorld
    camera = sensor_model('left_hand_camera').windowed(sensor_window(640, 400))
    rng = np.random.default_rng(seed)
    look = AppearanceConfig.from_dict(expand(preset))
    frames = []
    kinematics = ArmKinematics('left')
    try:
        starts = ['down', 'angled'] + [None] * random_poses
        for start in starts:
            scene = dataclasses.replace(load_scene(), appearance=look, start=start or 'down')
            world = SimWorld(scene)
            try:
                if start is None:       # a hand pose over the table, camera looking down-ish
                    seed = [scene.start_positions()[name] for name in kinematics.joint_names]
                    angles = kinematics.ik(_random_view(rng), seed=seed)
                    if angles is None:
                        continue
                    world.set_arm_positions('left', dict(zip(kinematics.joint_names, angles)))
                frames.append(world.render_camera('left_hand_camera', camera, rng))
            finally:
                world.close()
    finally:
        kinematics.close()
    return frames


def _random_view(rng):
    """A gripper pose 0.15-0.35 m above the table, pointing down within 25 deg."""
    from scipy.spatial.transform import Rotation
    from baxter_pnp.transforms import make_transform
    tilt = Rotation.from_rotvec(np.append(rng.uniform(-1, 1, 2), 0.0) * np.radians(18))
    R = (tilt * Rotation.from_euler('xz', [np.pi, rng.uniform(-np.pi, np.pi)])).as_matrix()
    return make_transform(R, [rng.uniform(0.55, 0.8), rng.uniform(0.05, 0.4), -0.15 + rng.uniform(0.15, 0.35)])


def print_table(columns):
    """One row per statistic, one column per (name, summary)."""
    print('| statistic | ' + ' | '.join(name for name, _ in columns) + ' |')
    print('|---|' + '---|' * len(columns))
    for key in STATISTICS:
        cells = []
        for _, summary in columns:
            median, low, high = summary[key]
            cells.append('%s (%s..%s)' % tuple(_fmt(v) for v in (median, low, high)))
        print('| %s | %s |' % (key, ' | '.join(cells)))


def _fmt(value):
    value = np.atleast_1d(value)
    return '/'.join('%.2f' % v for v in value)


def main(argv=None):
    parser = argparse.ArgumentParser(description=command_summary(__doc__))
    parser.add_argument('--real', nargs='*', default=REAL_DEFAULT, help='folders of real frames')
    parser.add_argument('--presets', nargs='*', default=['clean', 'baxter'], help='appearance presets to render')
    parser.add_argument('--out', help='write one real and one rendered picture per column here')
    args = parser.parse_args(argv)
    columns, pictures = [], []
    for folder in args.real:
        frames = real_frames(folder)
        if not frames:
            print('%s: no frames (skipped)' % folder)
            continue
        columns.append(('real %s (%d)' % (os.path.basename(os.path.normpath(folder)), len(frames)), summarise(frames)))
        pictures.append((os.path.basename(os.path.normpath(folder)), frames[len(frames) // 2]))
    for preset in args.presets:
        frames = rendered_frames(preset)
        columns.append(('fake %s (%d)' % (preset, len(frames)), summarise(frames)))
        pictures.append(('fake_' + preset, frames[1]))
    print_table(columns)
    if args.out:
        os.makedirs(args.out, exist_ok=True)
        for name, image in pictures:
            cv2.imwrite(os.path.join(args.out, name + '.png'), cv2.resize(image, (640, 400)))
    return 0
