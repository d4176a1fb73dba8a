"""``detect_image.py``: run the perception pipeline on image files and recorded runs (rosbags); print what it finds.

Inputs (positional, mixed): image files (any format OpenCV reads, 8 bits per channel, colour; an alpha channel is
dropped) and ``.bag`` files recorded with ``rosbag record`` (docs/perception.md, "Replaying a recorded run").
Per image file, one JSON object (``--json``) or a readable summary::

    {"image": "...", "detections": [{"shape", "colour", "vertices_px", "centroid_px", "position_m",
      "orientation_xyzw", "depth_m", "residual_px", "error"}]}

Per frame of a bag's image topic, with the CameraInfo in effect at its stamp (``bag_replay``)::

    {"bag": "...", "topic": "...", "stamp": s, "seq": n, "frame_id": "...", "detections": [...]}

Poses are in the camera optical frame (x right, y down, z forward), metres; with ``--table-plane`` the blocks are
posed as standing on that table (``perception.observe_blocks``'s ``table_plane``), as the pick's looks pose them.
An image file whose size differs from the camera model's (``--camera-info``, or the thesis calibration) gets the
model scaled to it, with a warning, if the aspect ratios are close (``MAX_ASPECT_CHANGE``); a bag frame must have
the size its CameraInfo describes.
Exit status: 0 when every image and frame was read and posed or found empty, 1 when one could not be used (file
unreadable, corrupt bag, bad encoding, size or camera_info), 2 on bad arguments or configuration (unknown topic:
the bag's topics are listed).
"""
import argparse
import contextlib
import json
import math
import os
import sys

import cv2
import numpy as np
import yaml

from baxter_pnp import bag_replay
from baxter_pnp import camera as camera_module
from baxter_pnp import models, perception, vision
from baxter_pnp.runtime import command_summary

# The camera model is scaled to an image whose width/height ratio is within this factor of the model's (4:3 <->
# 16:10 or 16:9 crops); beyond it the model says nothing about the image.
MAX_ASPECT_CHANGE = 1.5
JPEG_START, JPEG_END = b'\xff\xd8', b'\xff\xd9'


def parse_args(argv):
    parser = argparse.ArgumentParser(prog='detect_image.py', description=command_summary(__doc__),
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument('inputs', nargs='+', metavar='IMAGE_OR_BAG',
                        help='image files (any format OpenCV reads) and .bag files, in any order')
    parser.add_argument('--camera-info', metavar='YAML',
                        help='camera calibration: a camera_calibration_parsers YAML, or a CameraInfo as `rostopic echo` '
                             'prints it (ROI and binning applied); default for image files: the thesis calibration; '
                             'for bags: used only for frames before the first CameraInfo (or a bag without one)')
    parser.add_argument('--image-topic', metavar='TOPIC',
                        help='image topic of the bags (sensor_msgs/Image), e.g. /cameras/left_hand_camera/image; '
                             'default: the bag\'s only image topic')
    parser.add_argument('--camera-info-topic', metavar='TOPIC',
                        help='CameraInfo topic of the bags; default: the image topic\'s sibling camera_info')
    parser.add_argument('--every', type=int, default=1, metavar='N', help='bags: every N-th frame (default 1: all)')
    parser.add_argument('--max-frames', type=int, metavar='N', help='bags: at most N frames per bag')
    parser.add_argument('--side', type=float, required=True, help='side length of the block (m), e.g. 0.04')
    parser.add_argument('--height', type=float, default=0.02, help='height of the block (m), default 0.02')
    parser.add_argument('--edge-radius', type=float, default=0.0,
                        help='radius the blocks\' top edges are rounded over (m), default 0: sharp')
    parser.add_argument('--shape', choices=sorted(models.SHAPES), help='only this shape')
    parser.add_argument('--colour', '--color', dest='colour', help='only this colour (a name in the vision config)')
    parser.add_argument('--method', choices=['sqp', 'ippe', 'sqpnp'], default='sqp', help='pose estimator')
    parser.add_argument('--table-plane', metavar='NX,NY,NZ,D',
                        help='the table top in the camera optical frame: the points X with N . X = D (m; N towards '
                             'the camera, so D < 0), e.g. 0,0,-1,-0.5 for a camera 0.5 m straight above it (write '
                             '--table-plane=... when N starts with a minus): blocks are then posed as standing on '
                             'it, as the pick does (default: no table)')
    parser.add_argument('--towers', action='store_true',
                        help='with --table-plane: blocks may stand on others (a pose above the table is kept)')
    parser.add_argument('--vision-config', metavar='YAML', help='vision parameters (default config/vision.yaml)')
    parser.add_argument('--json', action='store_true', help='print one JSON object per image or frame')
    parser.add_argument('--annotate', metavar='OUT_DIR',
                        help='write annotated images into OUT_DIR (bag frames: <bag name>_<secs>.<nsecs>.png)')
    args = parser.parse_args(argv)
    if not (math.isfinite(args.side) and args.side > 0 and math.isfinite(args.height) and args.height > 0):
        parser.error('--side and --height must be positive numbers (metres)')
    try:
        models.check_edge_radius(args.side, args.height, args.edge_radius,
                                 [args.shape] if args.shape else tuple(models.SHAPES))
    except ValueError as exc:
        parser.error('--edge-radius: %s' % exc)
    if args.every < 1 or (args.max_frames is not None and args.max_frames < 1):
        parser.error('--every and --max-frames must be at least 1')
    if args.table_plane is not None:
        try:
            args.table_plane = parse_table_plane(args.table_plane)
        except ValueError as exc:
            parser.error('--table-plane: %s' % exc)
    elif args.towers:
        parser.error('--towers needs --table-plane')
    return args


def parse_table_plane(text):
    """``models.Plane`` of ``'NX,NY,NZ,D'`` (camera optical frame, m); ValueError unless four finite numbers with a
    non-zero normal that put the camera on the side the normal points to (D < 0 once the normal is unit)."""
    try:
        values = [float(v) for v in text.split(',')]
    except ValueError:
        raise ValueError(f'expected four numbers NX,NY,NZ,D, got {text!r}') from None
    if len(values) != 4:
        raise ValueError(f'expected four numbers NX,NY,NZ,D, got {len(values)}')
    plane = models.Plane(values[:3], values[3])      # ValueError: a zero or non-finite normal, a non-finite D
    if plane.signed_distance([0.0, 0.0, 0.0]) <= 0.0:
        raise ValueError(f'the camera must be on the side the normal points to (N . 0 - D > 0), got {text!r}')
    return plane


def main(argv=None):
    args = parse_args(argv)
    try:
        given_camera = camera_module.CameraModel.from_yaml(args.camera_info) if args.camera_info else None
        file_camera = given_camera or camera_module.load_default_camera()
        config = vision.VisionConfig.from_yaml(args.vision_config)
    except (OSError, ValueError, KeyError, yaml.YAMLError) as exc:
        return _fail(2, f'bad configuration: {exc}')
    if args.colour is not None and args.colour not in config.colour_names():
        return _fail(2, f'unknown colour {args.colour!r} (known: {", ".join(config.colour_names())})')
    if args.annotate:
        os.makedirs(args.annotate, exist_ok=True)
    detector = _Detector(args, config)
    with contextlib.ExitStack() as bags:
        replays = {}
        for path in args.inputs:           # every bag's topics are checked before any output
            if _is_bag(path) and path not in replays:
                try:
                    replays[path] = bags.enter_context(bag_replay.BagReplay(
                        path, args.image_topic, args.camera_info_topic, fallback_camera=given_camera))
                except bag_replay.BagTopicError as error:
                    return _fail(2, str(error))
                except bag_replay.BagReadError as error:
                    replays[path] = error
        status = 0
        for path in args.inputs:
            if not _is_bag(path):
                status |= detector.file(path, file_camera)
            elif isinstance(replays[path], bag_replay.BagReadError):
                status |= _fail(1, str(replays[path]))
            else:
                status |= detector.bag(replays[path])
    return status


class _Detector:
    """Perception on one image file or one bag's frames, reported on stdout (errors on stderr); each returns the
    exit status contribution (0 or 1)."""

    def __init__(self, args, config):
        self.args = args
        self.config = config
        self.min_side_px = math.ceil(math.sqrt(config.min_area_px))

    def file(self, path, camera):
        try:
            image = read_image(path)
            image_camera = self._camera_for(image, camera, path)
            observations = self._observe(image, image_camera)
        except (OSError, ValueError) as error:
            return _fail(1, f'cannot use image {path}: {error}')
        self._report({'image': path}, path, observations, image, image_camera, os.path.basename(path))
        return 0

    def bag(self, replay):
        status = 0
        name = os.path.splitext(os.path.basename(replay.path))[0]
        try:
            for frame in replay.frames(self.args.every, self.args.max_frames):
                label = f'{replay.path} {replay.image_topic} frame seq {frame.seq} at {_stamp_text(frame.stamp_ns)}'
                try:
                    if frame.error:
                        raise ValueError(frame.error)
                    image_camera = self._camera_for(frame.image_bgr, frame.camera, label)
                    observations = self._observe(frame.image_bgr, image_camera)
                except ValueError as error:
                    status = _fail(1, f'cannot use {label}: {error}')
                    continue
                head = {'bag': replay.path, 'topic': replay.image_topic, 'stamp': frame.stamp,
                        'seq': frame.seq, 'frame_id': frame.frame_id}
                self._report(head, label, observations, frame.image_bgr, image_camera,
                             f'{name}_{_stamp_text(frame.stamp_ns)}.png')
        except bag_replay.BagReadError as error:
            status = _fail(1, str(error))
        if replay.skipped_without_camera_info:
            print(f'detect_image: {replay.path}: {replay.skipped_without_camera_info} frame(s) of '
                  f'{replay.image_topic} before the first CameraInfo on {replay.camera_info_topic}: skipped '
                  f'(--camera-info YAML would be used for them)', file=sys.stderr)
        return status

    def _camera_for(self, image, camera, label):
        """``camera`` for ``image`` (scaled to its size, with a warning, when the aspect ratios are close);
        ValueError if the image is too small to hold a block or the model cannot describe it."""
        height, width = image.shape[:2]
        if min(width, height) < self.min_side_px:
            raise ValueError(f'the image is {width}x{height} px: too small to hold a block (sides of at least '
                             f'{self.min_side_px} px for the vision config\'s min_area_px {self.config.min_area_px:g})')
        if (width, height) == (camera.width, camera.height):
            return camera
        change = (width / height) / (camera.width / camera.height)
        if not 1.0 / MAX_ASPECT_CHANGE <= change <= MAX_ASPECT_CHANGE:
            raise ValueError(f'the image is {width}x{height} but the camera model is {camera.width}x{camera.height}; '
                             f'their aspect ratios are too different to scale the model: give the camera\'s '
                             f'calibration with --camera-info')
        print(f'detect_image: {label} is {width}x{height} but the camera model is {camera.width}x{camera.height}; '
              f'scaling the model', file=sys.stderr)
        return camera.scaled(width, height)

    def _observe(self, image, camera):
        args = self.args
        return perception.observe_blocks(image, camera, self.config, args.side, args.height, shape=args.shape,
                                         colour=args.colour, method=args.method, edge_radius=args.edge_radius,
                                         table_plane=args.table_plane, towers=args.towers)

    def _report(self, head, label, observations, image, camera, annotated_name):
        report = dict(head, detections=[o.to_json() for o in observations])
        if self.args.json:
            print(json.dumps(report))
        else:
            print_summary(label, report['detections'])
        if self.args.annotate:
            cv2.imwrite(os.path.join(self.args.annotate, annotated_name),
                        perception.annotate(image, observations, camera))


def read_image(path):
    """uint8 BGR (H, W, 3) image of the file at ``path`` (EXIF orientation applied, an alpha channel dropped).

    OSError if it cannot be opened; ValueError saying why it is not usable: empty, not decodable (corrupt,
    truncated, not an image), a JPEG without its end marker (truncated: libjpeg decodes the missing rows as grey),
    not 8 bits per channel, or grey (the pipeline segments by colour).
    """
    data = np.fromfile(path, dtype=np.uint8)
    if data.size == 0:
        raise ValueError('empty file')
    image = cv2.imdecode(data, cv2.IMREAD_ANYDEPTH | cv2.IMREAD_ANYCOLOR)
    if image is None:
        raise ValueError('not an image OpenCV can decode (corrupt, truncated, or not an image)')
    raw = data.tobytes()
    if raw.startswith(JPEG_START) and not raw.rstrip(b'\0\r\n ').endswith(JPEG_END):
        raise ValueError('truncated JPEG (no end-of-image marker)')
    if image.dtype != np.uint8:
        raise ValueError(f'{image.dtype} pixels: only 8 bits per channel are accepted (convert the image first)')
    if image.ndim == 2 or image.shape[2] != 3:
        raise ValueError('grey image: the pipeline segments by colour')
    return image


def print_summary(label, detections):
    """Readable one-line-per-detection summary of ``label``'s detections (millimetres)."""
    print('%s: %d detection(s)' % (label, len(detections)))
    for d in detections:
        if d['position_m'] is None:
            print('  %s %s at (%.1f, %.1f) px: no pose (%s)' % (d['colour'], d['shape'], *d['centroid_px'], d['error']))
            continue
        x, y, z = (1000.0 * c for c in d['position_m'])
        print('  %s %s at (%.1f, %.1f) px: position (%.1f, %.1f, %.1f) mm, residual %.2f px'
              % (d['colour'], d['shape'], *d['centroid_px'], x, y, z, d['residual_px']))


def _is_bag(path):
    return path.lower().endswith('.bag')


def _stamp_text(stamp_ns):
    """``secs.nsecs`` (nine digits) of a time in nanoseconds."""
    return f'{stamp_ns // 10**9}.{stamp_ns % 10**9:09d}'


def _fail(status, message):
    """Print ``message`` on stderr; return ``status``."""
    print(f'detect_image: {message}', file=sys.stderr)
    return status
