"""``make demo-perception``: the perception pipeline end to end on rendered images.

Renders a few hand-camera views of coloured blocks with known poses (thesis camera, 640x480), runs
``detect_image`` on them, and prints each estimate beside the ground truth. Leaves the images and the
annotated results (contour, vertices, pose axes, depth) in ``OUT/images`` and ``OUT/annotated``.
"""
import argparse
import os

import cv2
import numpy as np

from baxter_pnp import camera as camera_module
from baxter_pnp import detect_cli, synthetic
from baxter_pnp.runtime import command_summary

SCENES = [  # (shape, side m, colour BGR, distance m, tilt deg)
    ('square', 0.040, (40, 170, 40), 0.161, 0.0),
    ('square', 0.040, (40, 170, 40), 0.300, 30.0),
    ('triangle', 0.050, (40, 170, 40), 0.250, 15.0),
    ('hexagon', 0.040, (40, 170, 40), 0.200, 25.0),
]


def main(argv=None):
    parser = argparse.ArgumentParser(prog='perception_demo.py', description=command_summary(__doc__))
    parser.add_argument('--out', default='out/demo')
    parser.add_argument('--seed', type=int, default=7)
    args = parser.parse_args(argv)
    camera = camera_module.load_default_camera()
    rng = np.random.default_rng(args.seed)
    images_dir = os.path.join(args.out, 'images')
    os.makedirs(images_dir, exist_ok=True)
    for index, (shape, side, colour, distance, tilt) in enumerate(SCENES):
        spec = synthetic.BlockSpec(shape, side, 0.02, colour)
        T_camera_block = synthetic.random_block_pose(rng, distance_range=(distance, distance),
                                                     max_tilt_deg=tilt, camera=camera, block=spec)
        image, _ = synthetic.render_block_scene(camera, [(spec, T_camera_block)], rng)
        path = os.path.join(images_dir, '%02d_%s.png' % (index, shape))
        cv2.imwrite(path, image)
        x, y, z = 1000.0 * T_camera_block[:3, 3]
        print('truth %s: %s side %.0f mm at (%.1f, %.1f, %.1f) mm' % (os.path.basename(path), shape,
                                                                   1000 * side, x, y, z))
        status = detect_cli.main([path, '--side', str(side), '--shape', shape,
                                  '--annotate', os.path.join(args.out, 'annotated')])
        if status:
            return status
    print('annotated images in %s' % os.path.join(args.out, 'annotated'))
    return 0
