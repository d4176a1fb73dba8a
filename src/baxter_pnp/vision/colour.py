"""The thesis's colour stages (section 3.2, Algorithm 1, steps 1-8): BGR/HSV uint8 images in, binary masks and
blob contours out. HSV on OpenCV's scales (hue 0-179, saturation and value 0-255); images indexed [row, column]."""
import functools
import math

import cv2
import numpy as np

LAPLACIAN_KERNEL = np.array([[-1, -1, -1], [-1, 8, -1], [-1, -1, -1]], dtype=np.float32)


@functools.lru_cache(maxsize=8)
def gamma_lut(gamma):
    """(256,) uint8 lookup table of ``255 (i / 255) ** gamma`` (eq. 3.13), rounded (cached, read-only)."""
    lut = np.round(255.0 * (np.arange(256) / 255.0) ** gamma).astype(np.uint8)
    lut.flags.writeable = False
    return lut


def saturation_threshold(saturation, epsilon, floor=0.0):
    """Dynamic threshold ``(S_max - S_min) / epsilon`` of a uint8 saturation channel (eq. 3.14), at least ``floor``.

    The floor is ours: in an image without any colour (S_max close to S_min) eq. 3.14 tends to 0 and
    every pixel, grey background included, would be over-saturated.
    """
    s_min, s_max, _, _ = cv2.minMaxLoc(saturation)
    return max((s_max - s_min) / epsilon, floor)


def oversaturate(saturation, threshold, s_value=250, v_value=180):
    """Algorithm 1, lines 9-16: uint8 ``(S, V)``, ``(s_value, v_value)`` where ``saturation >= threshold``, else 0."""
    # integer pixels: s >= t  <=>  s > ceil(t) - 1
    cut = math.ceil(threshold) - 1
    _, s_out = cv2.threshold(saturation, cut, s_value, cv2.THRESH_BINARY)
    _, v_out = cv2.threshold(saturation, cut, v_value, cv2.THRESH_BINARY)
    return s_out, v_out


def lowpass_kernel(b):
    """(3, 3) low-pass kernel of eq. 3.17: ``(1/(2+b)^2) [1 b 1]^T [1 b 1]`` (sums to 1)."""
    k = lowpass_kernel_1d(b)
    return np.outer(k, k)


def lowpass_kernel_1d(b):
    """(3,) separable factor ``[1 b 1] / (2 + b)`` of ``lowpass_kernel``."""
    return np.array([1.0, b, 1.0], dtype=np.float32) / (2.0 + b)


def lowpass(channel, b):
    """``channel`` convolved with the kernel of eq. 3.17 (separably; same size and type, borders reflected)."""
    k = lowpass_kernel_1d(b)
    return cv2.sepFilter2D(channel, -1, k, k)


def colour_mask(hsv, ranges):
    """uint8 mask (255 inside) of the pixels of ``hsv`` inside any of the inclusive HSV ``ranges``."""
    mask = None
    for low, high in ranges:
        in_range = cv2.inRange(hsv, low, high)
        mask = in_range if mask is None else cv2.bitwise_or(mask, in_range)
    return mask


def open_close(mask, kernel_px):
    """Morphological opening (removes specks) then closing (fills holes) with a square kernel."""
    kernel = np.ones((kernel_px, kernel_px), np.uint8)
    return cv2.morphologyEx(cv2.morphologyEx(mask, cv2.MORPH_OPEN, kernel), cv2.MORPH_CLOSE, kernel)


def laplacian_sharpen(mask):
    """``mask`` convolved with the Laplacian kernel (uint8, saturated): its inner boundary ring.

    Pixels beyond the image count as background, so the ring of a blob cut by the border stays closed.
    """
    return cv2.filter2D(mask, -1, LAPLACIAN_KERNEL, borderType=cv2.BORDER_CONSTANT)


def find_blobs(binary, min_area_px):
    """Outer contours of ``binary`` (``CHAIN_APPROX_NONE``) whose area is at least ``min_area_px``."""
    contours, _ = cv2.findContours(binary, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
    return [c for c in contours if cv2.contourArea(c) >= min_area_px]


def dynamic_threshold(hsv, config):
    """Eq. 3.14 on the gamma-corrected saturation of ``hsv``, floored at ``min_saturation_threshold``."""
    return saturation_threshold(cv2.LUT(hsv[..., 1], gamma_lut(config.gamma)), config.saturation_epsilon,
                                config.min_saturation_threshold)


def oversaturated_hsv(hsv, threshold, config):
    """Algorithm 1 on an HSV image with a given dynamic threshold: HSV with over-saturated, low-passed S and V.

    Gamma correction and over-saturation depend on S alone, so they are applied together, as the
    two 256-entry tables of their outputs for every S (``_oversaturation_luts``).
    """
    hue, saturation, _ = cv2.split(hsv)
    s_lut, v_lut = _oversaturation_luts(config.gamma, threshold, config.oversaturated_s, config.oversaturated_v)
    return cv2.merge([hue, lowpass(cv2.LUT(saturation, s_lut), config.lowpass_b),
                      lowpass(cv2.LUT(saturation, v_lut), config.lowpass_b)])


@functools.lru_cache(maxsize=64)
def _oversaturation_luts(gamma, threshold, s_value, v_value):
    """(S table, V table): ``oversaturate(gamma_lut(gamma)[S], threshold, ...)`` per uint8 S (cached, read-only)."""
    tables = oversaturate(gamma_lut(gamma)[None], threshold, s_value, v_value)
    for table in tables:
        table.flags.writeable = False
    return tables

