"""The chroma colour stage (the default ``pipeline: chroma``): BGR uint8 in -> one binary mask per colour class out.

Built for real cameras: the image is white-balanced from its own achromatic majority (the table), converted to
CIELAB, and a pixel belongs to a colour class when its hue angle in the a*b* plane lies in the class's sector and
its chroma and lightness clear the class's floors. Black, white and grey have (near) zero chroma whatever the
exposure, so they are never a colour; the floor on lightness keeps the chroma noise of near-black pixels out.
Units: CIELAB as OpenCV's 8-bit conversion gives it, rescaled to L* 0-100 and a*, b* (and chroma) in CIELAB
units; hue angles in degrees (0 = +a*, 90 = +b*). Images indexed [row, column].
"""
import dataclasses
import functools
import math

import cv2
import numpy as np

_LAB_SCALE = 255.0 / 100.0          # OpenCV 8-bit L = L* * 255 / 100; a = a* + 128; b = b* + 128
_WB_PIXELS = 2000                   # white_balance_gains: images larger than this are sampled every _WB_STRIDE px
_WB_STRIDE = 2
_WB_MIN_LIGHTNESS = 20              # L*: darker pixels are too noisy to say what the light's colour is ...
_WB_DIM_LIGHTNESS = 5               # ... unless most of the picture is darker (dim light): then the pixels between
_WB_DIM_PERCENTILES = (30, 70)      # these percentiles of its lightness (the table's; a lit block is brighter), >= 5


def white_balance_gains(image_bgr, config):
    """(3,) float32 per-channel gains (B, G, R) that make the image's achromatic majority grey.

    The illuminant is the per-channel median of the pixels of mid lightness (neither clipped nor near
    black; on a cell that is mostly the table; in a picture mostly darker than that, dim light on a dark table, the
    middle 40 % of its lightness, the table's, not a lit block's) whose chroma is below their median chroma; the
    gains scale each channel to their mean, clipped to ``1 / max_gain .. max_gain`` so a frame filled by
    one coloured object cannot be turned grey. Ones when disabled or when too few pixels qualify. Pass a
    subsampled image (detection passes the candidate search's); above 2000 px every 2nd pixel is used.
    """
    return white_balance(image_bgr, config)[0]


def white_balance(image_bgr, config):
    """``(gains, residual_cast)``: ``white_balance_gains``, and the chroma (CIELAB units) of the cast they leave on
    the image (the magnitude of the median a*, b* of its mid-lightness pixels once balanced): 0-4 on a balanced
    real frame, large under a strongly tinted light the gains could not (or not everywhere) remove, whose tint
    must not become a colour. 0 when the balance is disabled or too few pixels qualify."""
    ones = np.ones(3, np.float32)
    if not config.white_balance:
        return ones, 0.0
    pixels = image_bgr[::_WB_STRIDE, ::_WB_STRIDE] if image_bgr.size > 3 * _WB_PIXELS else image_bgr
    pixels = np.ascontiguousarray(pixels).reshape(1, -1, 3)     # one row: OpenCV's conversions cost per row
    lab = cv2.cvtColor(pixels, cv2.COLOR_BGR2LAB).reshape(-1, 3)
    ab = lab[:, 1:].astype(np.int32) - 128
    chroma_squared = ab[:, 0] * ab[:, 0] + ab[:, 1] * ab[:, 1]
    lightness = lab[:, 0]
    lit = lightness >= _WB_MIN_LIGHTNESS * _LAB_SCALE
    mid = lit & (lightness <= 95 * _LAB_SCALE)
    if np.count_nonzero(lit) < 0.5 * len(lightness):           # dim light: the table is darker than that
        low, high = np.percentile(lightness, _WB_DIM_PERCENTILES)
        mid = (lightness >= max(low, _WB_DIM_LIGHTNESS * _LAB_SCALE)) & (lightness <= high)
    if np.count_nonzero(mid) < 0.05 * len(mid):
        return ones, 0.0
    grey = mid & (chroma_squared <= _median(chroma_squared[mid]))
    illuminant = _median(pixels[0, grey]).astype(np.float32)
    if np.any(illuminant < 1.0):
        return ones, 0.0
    gains = np.clip(illuminant.mean() / illuminant, 1.0 / config.max_gain, config.max_gain).astype(np.float32)
    cast = _median(cv2.cvtColor(balanced_bgr(pixels[:, mid], gains), cv2.COLOR_BGR2LAB)[0, :, 1:]) - 128.0
    return gains, float(np.hypot(cast[0], cast[1]))


def _median(values):
    """``np.median(values, axis=0)`` (float64) by one partial sort, without its overhead (small arrays)."""
    upper = len(values) // 2
    if len(values) % 2:
        return np.partition(values, upper, axis=0)[upper].astype(np.float64)
    part = np.partition(values, (upper - 1, upper), axis=0)
    return (part[upper - 1].astype(np.float64) + part[upper]) / 2.0


def balanced_bgr(image_bgr, gains):
    """The image scaled per channel by ``gains``, every channel then clipped at ``255 * min(gains)``, the level where
    the first channel's clipped highlights end up (so a highlight clipped in one channel stays grey, as raw
    converters keep it, instead of taking the other channels' colour: a white screen under a cast); the image itself
    when the gains are all 1."""
    if np.all(gains == 1.0):
        return image_bgr
    balanced = cv2.transform(image_bgr, np.diag(gains).astype(np.float32))
    ceiling = int(255.0 * float(np.min(gains)))
    return np.minimum(balanced, np.uint8(ceiling)) if ceiling < 255 else balanced


def balanced_lab(image_bgr, gains):
    """The image scaled per channel by ``gains`` (saturating) and converted to 8-bit CIELAB (OpenCV's scales)."""
    return cv2.cvtColor(balanced_bgr(image_bgr, gains), cv2.COLOR_BGR2LAB)


def class_masks(lab, classes, extra_chroma=0.0, floor_fraction=1.0):
    """{name: uint8 mask (255 inside)} of the pixels of the 8-bit CIELAB image ``lab`` in each ``ColourClass``,
    every class's chroma floor times ``floor_fraction`` and raised by ``extra_chroma`` (rounded to a whole unit)."""
    extra = float(round(extra_chroma))
    ab_index = (lab[..., 1].astype(np.int32) << 8) | lab[..., 2]
    bright = {}
    masks = {}
    for name, colour_class in classes.items():
        floor = colour_class.min_lightness
        if floor not in bright:
            bright[floor] = cv2.threshold(lab[..., 0], floor * _LAB_SCALE - 1e-6, 255, cv2.THRESH_BINARY)[1]
        table = _ab_table(_with_floor(colour_class, floor_fraction, extra))
        masks[name] = cv2.bitwise_and(np.take(table, ab_index), bright[floor])
    return masks


@functools.lru_cache(maxsize=64)
def _with_floor(colour_class, floor_fraction, extra):
    """``colour_class`` with its chroma floor times ``floor_fraction`` plus ``extra`` (cached: called per region)."""
    if floor_fraction == 1.0 and extra == 0.0:
        return colour_class
    return dataclasses.replace(colour_class, min_chroma=colour_class.min_chroma * floor_fraction + extra)


@functools.lru_cache(maxsize=32)
def _ab_table(colour_class):
    """(65536,) uint8 table over OpenCV's 8-bit (a, b), index ``256 a + b``: 255 where hue and chroma are in
    ``colour_class``."""
    a, b = np.meshgrid(np.arange(256) - 128.0, np.arange(256) - 128.0, indexing='ij')
    hue = np.degrees(np.arctan2(b, a))
    off = (hue - colour_class.hue_deg + 180.0) % 360.0 - 180.0
    inside = (np.abs(off) <= colour_class.hue_half_width_deg) & (np.hypot(a, b) >= colour_class.min_chroma)
    table = np.where(inside, 255, 0).astype(np.uint8).ravel()
    table.flags.writeable = False
    return table


def hue_and_chroma(lab_pixels):
    """((n,) hue angle deg in [0, 360), (n,) chroma, (n,) L*) of (n, 3) 8-bit CIELAB pixels."""
    pixels = np.asarray(lab_pixels, dtype=float).reshape(-1, 3)
    a, b = pixels[:, 1] - 128.0, pixels[:, 2] - 128.0
    return np.degrees(np.arctan2(b, a)) % 360.0, np.hypot(a, b), pixels[:, 0] / _LAB_SCALE


def learn_colour_class(image_bgr, roi, config, min_sample_chroma=10.0):
    """``(hue_deg, hue_half_width_deg, min_chroma, min_lightness)`` of a colour from a view of one block.

    ``roi`` = (x, y, width, height) px around the block (a little table around it does no harm: pixels
    below ``min_sample_chroma`` are the achromatic background and are left out); the image is
    white-balanced as detection will balance it (``config``: a ``ChromaConfig``). The sector is the
    circular mean hue +- 3 circular standard deviations (10-60 deg); the floors are half the 5th
    percentiles of chroma and lightness (at least 15 and 3), so the block's shaded side faces and dimmer
    views still belong. ValueError when the region holds fewer than 30 coloured pixels.
    """
    x, y, w, h = (int(v) for v in roi)
    if w <= 0 or h <= 0 or x < 0 or y < 0 or x + w > image_bgr.shape[1] or y + h > image_bgr.shape[0]:
        raise ValueError(f'roi {x},{y},{w},{h} is not inside the {image_bgr.shape[1]}x{image_bgr.shape[0]} image')
    lab = balanced_lab(image_bgr, white_balance_gains(image_bgr, config))[y:y + h, x:x + w]
    hue, chroma, lightness = hue_and_chroma(lab)
    coloured = chroma >= min_sample_chroma
    if np.count_nonzero(coloured) < 30:
        raise ValueError(f'only {np.count_nonzero(coloured)} coloured pixels in the roi (need 30): '
                         'is the block inside it, and is it coloured?')
    angles = np.radians(hue[coloured])
    mean_vector = np.array([np.cos(angles).mean(), np.sin(angles).mean()])
    spread = np.degrees(np.sqrt(-2.0 * np.log(max(np.hypot(*mean_vector), 1e-9))))
    return (float(np.degrees(np.arctan2(mean_vector[1], mean_vector[0])) % 360.0),
            float(np.clip(3.0 * spread, 10.0, 60.0)),
            float(max(15.0, 0.5 * np.percentile(chroma[coloured], 5))),
            float(max(3.0, 0.5 * np.percentile(lightness[coloured], 5))))


def along_hue(lab, mask, hue_deg):
    """(k,) float32 chroma along ``hue_deg`` (CIELAB units: a*b* projected on that hue's direction) of the pixels
    of the 8-bit CIELAB image ``lab`` where ``mask`` is set."""
    direction = np.array([math.cos(math.radians(hue_deg)), math.sin(math.radians(hue_deg))], np.float32)
    return (lab[mask > 0][:, 1:].astype(np.float32) - 128.0) @ direction


def along_hue_image(lab, hue_deg):
    """uint8 image of the chroma along ``hue_deg`` (``along_hue``) of each pixel of the 8-bit CIELAB image ``lab``,
    rounded and offset by 128 (clipped to 0-255: -128..127 CIELAB units)."""
    c, s = math.cos(math.radians(hue_deg)), math.sin(math.radians(hue_deg))
    return cv2.transform(lab, np.array([[0.0, c, s, 128.0 * (1.0 - c - s)]], np.float32))


def hue_contrast(lab, inside, around, hue_deg):
    """Median chroma along ``hue_deg`` (``along_hue``) of the pixels of the 8-bit CIELAB image ``lab`` where
    ``inside`` is set, less that of the pixels where ``around`` is set (a median of nothing is 0)."""
    def median(values):
        return float(np.median(values)) if len(values) else 0.0
    return median(along_hue(lab, inside, hue_deg)) - median(along_hue(lab, around, hue_deg))
