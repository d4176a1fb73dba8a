"""``detect_image.py``: run the perception pipeline on image files and print what it finds.

Per image, one JSON object (``--json``) or a readable summary::

    {"image": "...", "detections": [{"shape", "colour", "vertices_px", "centroid_px", "position_m",
      "orientation_xyzw", "depth_m", "residual_px", "error"}]}

Poses are in the camera optical frame (x right, y down, z forward), metres. Exit status: 0 when
every image was read, 1 when an image could not be read, 2 on bad arguments or configuration.
"""
import argparse
import json
import os
import sys

import cv2

from baxter_pnp import camera as camera_module
from baxter_pnp import models, perception, vision


def parse_args(argv):
    parser = argparse.ArgumentParser(prog='detect_image.py', description=__doc__.split('\n')[0].strip('`: '),
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument('images', nargs='+', metavar='IMAGE', help='image files (any format OpenCV reads)')
    parser.add_argument('--camera-info', metavar='YAML',
                        help='camera calibration: a camera_calibration_parsers YAML, or a CameraInfo as `rostopic echo` '
                             'prints it (ROI and binning applied); default: the thesis calibration')
    parser.add_argument('--side', type=float, required=True, help='side length of the block (m), e.g. 0.04')
    parser.add_argument('--height', type=float, default=0.02, help='height of the block (m), default 0.02')
    parser.add_argument('--shape', choices=sorted(models.SHAPES), help='only this shape')
    parser.add_argument('--colour', '--color', dest='colour', help='only this colour (a name in the vision config)')
    parser.add_argument('--method', choices=['sqp', 'ippe', 'sqpnp'], default='sqp', help='pose estimator')
    parser.add_argument('--vision-config', metavar='YAML', help='vision parameters (default config/vision.yaml)')
    parser.add_argument('--json', action='store_true', help='print one JSON object per image')
    parser.add_argument('--annotate', metavar='OUT_DIR', help='write annotated images into OUT_DIR')
    args = parser.parse_args(argv)
    if not args.side > 0 or not args.height > 0:
        parser.error('--side and --height must be positive (metres)')
    return args


def main(argv=None):
    args = parse_args(argv)
    try:
        camera = (camera_module.CameraModel.from_yaml(args.camera_info) if args.camera_info
                  else camera_module.load_default_camera())
        config = vision.VisionConfig.from_yaml(args.vision_config)
    except (OSError, ValueError, KeyError) as exc:
        print('detect_image: bad configuration: %s' % exc, file=sys.stderr)
        return 2
    if args.colour is not None and args.colour not in config.colour_names():
        print('detect_image: unknown colour %r (known: %s)' % (args.colour, ', '.join(config.colour_names())),
              file=sys.stderr)
        return 2
    if args.annotate:
        os.makedirs(args.annotate, exist_ok=True)
    status = 0
    for path in args.images:
        image = cv2.imread(path, cv2.IMREAD_COLOR)
        if image is None:
            print('detect_image: cannot read image %s' % path, file=sys.stderr)
            status = 1
            continue
        if image.shape[1] != camera.width or image.shape[0] != camera.height:
            print('detect_image: %s is %dx%d but the camera model is %dx%d; scaling the model'
                  % (path, image.shape[1], image.shape[0], camera.width, camera.height), file=sys.stderr)
        image_camera = camera.scaled(image.shape[1], image.shape[0])
        observations = perception.observe_blocks(image, image_camera, config, args.side, args.height,
                                                 shape=args.shape, colour=args.colour, method=args.method)
        report = {'image': path, 'detections': [o.to_json() for o in observations]}
        if args.json:
            print(json.dumps(report))
        else:
            print_summary(report)
        if args.annotate:
            out = os.path.join(args.annotate, os.path.basename(path))
            cv2.imwrite(out, perception.annotate(image, observations, image_camera))
    return status


def print_summary(report):
    """Readable one-line-per-detection summary (millimetres)."""
    print('%s: %d detection(s)' % (report['image'], len(report['detections'])))
    for d in report['detections']:
        if d['position_m'] is None:
            print('  %s %s at (%.1f, %.1f) px: no pose (%s)' % (d['colour'], d['shape'], *d['centroid_px'], d['error']))
            continue
        x, y, z = (1000.0 * c for c in d['position_m'])
        print('  %s %s at (%.1f, %.1f) px: position (%.1f, %.1f, %.1f) mm, residual %.2f px'
              % (d['colour'], d['shape'], *d['centroid_px'], x, y, z, d['residual_px']))
