"""Top-face isolation (beyond the thesis): the brightest face, in V of the original image, inside a blob whose
side faces (same hue, darker) joined it in oblique views. Contours (M, 1, 2) int32 in the pixels of the HSV image."""
import cv2
import numpy as np

_SQUARE5 = np.ones((5, 5), np.uint8)


def isolate_top_face(blob, hsv, config):
    """Outline (M, 1, 2) int32 of the block's top face within the contour ``blob``, or None if none is found.

    ``hsv``: the original image in HSV (uint8, OpenCV scales), in the coordinates of ``blob``. A
    block's faces share its colour; under light from above the table the top face is the most
    brightly lit, so it is the brightest face in V and its side faces are darker. The V of the
    blob's interior (the blob eroded by 2 px, clear of the pixels it shares with the table) is split
    in two by Otsu's threshold; while the split is significant (the classes' means differ by at
    least ``min_contrast`` of the bright one's, and the bright class holds at least
    ``min_face_fraction`` of the interior) the bright class is split again, so that a side face lit
    nearly as brightly as the top goes too. The top face is then the largest connected region of
    the blob above the last significant threshold whose saturation is at least half the bright
    interior's mean: the pixels a side face shares with the (paler but brighter) table are as bright
    as the top, not as saturated. It is the blob itself when the first split is not significant
    (one face: the lighting gradient across a face changes its V by a few per cent, a face edge by
    tens). None when the region's solidity (area / convex-hull area) is below ``min_solidity``.
    """
    x, y, w, h = cv2.boundingRect(blob)
    box = (slice(y, y + h), slice(x, x + w))
    inside = np.zeros((h, w), np.uint8)
    cv2.drawContours(inside, [blob], -1, 255, cv2.FILLED, offset=(-x, -y))
    value, saturation = hsv[box][..., 2].copy(), hsv[box][..., 1].copy()
    interior = cv2.erode(inside, _SQUARE5)
    values = value[interior > 0]
    minimum_count = max(config.min_face_fraction * len(values), 1)
    threshold = None
    while len(values) >= 2:
        cut, _ = cv2.threshold(values, 0, 255, cv2.THRESH_BINARY | cv2.THRESH_OTSU)
        bright = values > cut
        bright_values = values[bright]
        if len(bright_values) < minimum_count or len(bright_values) == len(values):
            break
        bright_mean, dark_mean = float(bright_values.mean()), float(values[~bright].mean())
        if bright_mean - dark_mean < config.min_contrast * bright_mean:
            break
        threshold, values = cut, bright_values
    if threshold is None:
        return blob
    _, bright = cv2.threshold(value, threshold, 255, cv2.THRESH_BINARY)
    top_saturation = cv2.mean(saturation, cv2.bitwise_and(bright, interior))[0]
    _, saturated = cv2.threshold(saturation, 0.5 * top_saturation, 255, cv2.THRESH_BINARY)
    top = cv2.bitwise_and(cv2.bitwise_and(bright, saturated), inside)
    contours, _ = cv2.findContours(top, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE, offset=(x, y))
    if not contours:
        return None
    outline = max(contours, key=cv2.contourArea)
    if cv2.contourArea(outline) < config.min_solidity * cv2.contourArea(cv2.convexHull(outline)):
        return None
    return outline

