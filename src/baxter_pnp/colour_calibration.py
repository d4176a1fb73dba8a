"""``calibrate_colour.py IMAGE --name NAME [--roi X,Y,W,H] [-o VISION.yaml]``: learn a colour class of the chroma
pipeline from a view of one block and write it into a vision YAML (``chroma.classes.NAME``).

Without ``--roi`` the block is taken to fill the central third of the image. Prints the class it learnt and
how many pixels of the region the learnt class then covers. The output is the input vision YAML
(``--vision-config``, default ``config/vision.yaml``) with the class added or replaced (comments are not kept);
without ``-o`` nothing is written.
"""
import argparse
import sys

import cv2
import yaml

from baxter_pnp import vision
from baxter_pnp.params import ParameterError, load_mapping
from baxter_pnp.vision import chroma
from baxter_pnp.vision.config import DEFAULT_VISION_YAML, ColourClass
from baxter_pnp.runtime import command_summary


def parse_roi(text):
    try:
        values = [int(v) for v in text.split(',')]
    except ValueError:
        values = []
    if len(values) != 4:
        raise argparse.ArgumentTypeError(f'{text!r}: expected X,Y,WIDTH,HEIGHT in pixels')
    return tuple(values)


def main(argv=None):
    parser = argparse.ArgumentParser(prog='calibrate_colour.py', description=command_summary(__doc__))
    parser.add_argument('image', metavar='IMAGE', help='a view of one block of the colour (any format OpenCV reads)')
    parser.add_argument('--name', required=True, help='colour name, e.g. green')
    parser.add_argument('--roi', type=parse_roi, help='X,Y,WIDTH,HEIGHT (px) around the block; default: central third')
    parser.add_argument('--vision-config', default=DEFAULT_VISION_YAML, metavar='YAML', help='vision YAML to start from')
    parser.add_argument('-o', '--output', metavar='YAML', help='write the vision YAML with the learnt class here')
    args = parser.parse_args(argv)
    image = cv2.imread(args.image, cv2.IMREAD_COLOR)
    if image is None:
        print(f'calibrate_colour: cannot read image {args.image}', file=sys.stderr)
        return 2
    h, w = image.shape[:2]
    roi = args.roi or (w // 3, h // 3, w // 3, h // 3)
    try:
        mapping = load_mapping(args.vision_config)
        config = vision.VisionConfig.from_dict(mapping)
        hue, half_width, min_chroma, min_lightness = chroma.learn_colour_class(image, roi, config.chroma)
    except (OSError, ValueError) as error:
        print(f'calibrate_colour: {error}', file=sys.stderr)
        return 2
    learnt = {'hue_deg': round(hue, 1), 'hue_half_width_deg': round(half_width, 1),
              'min_chroma': round(min_chroma, 1), 'min_lightness': round(min_lightness, 1)}
    colour_class = ColourClass(**learnt)
    x, y, rw, rh = roi
    lab = chroma.balanced_lab(image, chroma.white_balance_gains(image, config.chroma))[y:y + rh, x:x + rw]
    covered = cv2.countNonZero(chroma.class_masks(lab, {args.name: colour_class})[args.name])
    print(f'{args.name}: {learnt}  (covers {covered} of the roi\'s {rw * rh} pixels)')
    if args.output:
        mapping.setdefault('chroma', {}).setdefault('classes', {})[args.name] = learnt
        try:
            vision.VisionConfig.from_dict(mapping)
        except ParameterError as error:
            print(f'calibrate_colour: the result would not load: {error}', file=sys.stderr)
            return 2
        with open(args.output, 'w') as f:
            yaml.safe_dump(mapping, f, default_flow_style=None, sort_keys=False)
        print(f'wrote {args.output}')
    return 0
