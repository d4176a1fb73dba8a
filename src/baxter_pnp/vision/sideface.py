"""Side-face strips cut off a polygon along their crease (beyond the thesis): where a side face is lit almost as
brightly as the top face, top-face isolation (``topface``) keeps it, and the polygon's edge on that side is the
side face's bottom edge. The top face's edge is then a crease inside the polygon: a straight line nearly parallel
to that edge (the two edges of a side face are parallel on the block), across which V rises from the strip to the
face all along the edge, the strip darker than the face over its whole width, and which ends at the block's
outline (a shadow's edge goes on across the table). ``cut_side_faces`` finds such a crease for each edge and moves
the edge onto it. Pixels (u, v) of the raw image; V = max(B, G, R) (OpenCV's HSV).
"""
import cv2
import numpy as np

from baxter_pnp.vision.polygon import intersect_lines

_PROFILES = 14                                  # profiles across each edge, spread over its middle 70 %
_STEP_PX = 0.5
_START_PX = 2.5                                 # the first sample inward: clear of the outline's own blur
_RISE_SPAN = 4                                  # samples (2 px) over which V rises across a crease
_TILTS = np.linspace(-0.12, 0.12, 9)            # a crease's slope against the edge: perspective, up to ~7 deg
_PRECHECK = 0.8                                 # slopes searched where straight profiles rise by this x min_rise
_TABLE_REACH_PX = (4.0, 7.0, 10.0)              # the table sampled this far beyond a crease's ends ...
_TABLE_SIDE_PX = 3.0                            # ... this far to either side of its line (_shadow_edge)
_STRIP_PX = (3.0, 1.5)                          # the strip is judged from this depth to this far before the crease
_MIN_STRIP_SAMPLES = 3                          # ... at this many depths at least (1 px): else no strip, only blur


def cut_side_faces(image_bgr, polygon, config, value=None, value_origin=(0, 0)):
    """``polygon`` (n, 2) (image px), its edges that bound a side-face strip moved onto the strip's crease (the
    vertices are the new edge lines' intersections); the polygon itself when no edge has one, or when it is smaller than
    ``config.min_size_px`` (square root of its area: on a small block a rim's shaded band or a row of pips looks
    the same).

    Per edge, V is sampled along lines at every depth (``_STEP_PX``) from ``_START_PX`` to ``config.max_depth_fraction``
    of the polygon's size and at each slope of ``_TILTS``, a sloped line only where it stays in that band all along
    the edge; the crease is the line across which the profiles' mean rises most over 2 px, sought first in the band
    every slope stays in, then (none found there) at every depth a slope allows: a strip narrower than the slopes'
    reach (6 px beside a 100 px face, a block near the camera) lies there. It counts when that rise is at least
    ``config.min_rise`` of the face's V, at least ``config.min_agreement`` of the profiles rise across it, and the
    strip (every depth before it) is flat and
    stays under ``config.max_strip_brightness`` of the face's V (after it): a side face, not the outline's blur, a
    printed mark, a row of pips or a shadow's edge inside the face. The slopes are searched only on edges whose
    profiles, taken straight, already rise by ``_PRECHECK`` of ``min_rise`` somewhere (most edges have no crease).
    ``value``: the V (uint8) of a region of the image holding the polygon, whose top-left pixel is ``value_origin``
    (the detection's HSV crop), else V is taken from ``image_bgr``."""
    polygon = np.asarray(polygon, dtype=float).reshape(-1, 2)
    n = len(polygon)
    following = np.arange(1, n + 1) % n
    edges = polygon[following] - polygon
    lengths = np.sqrt(edges[:, 0] ** 2 + edges[:, 1] ** 2)
    area2 = float((polygon[:, 0] * polygon[following, 1] - polygon[following, 0] * polygon[:, 1]).sum())
    size = np.sqrt(abs(area2) / 2.0)
    depths = np.arange(_START_PX, config.max_depth_fraction * size + 1e-9, _STEP_PX)
    if size < config.min_size_px or len(depths) < 3 * _RISE_SPAN or np.any(lengths < 1e-6):
        return polygon
    reach = np.abs(_TILTS) * 0.35 * lengths.max()           # (T,) each slope's largest depth change along an edge
    usable = (depths >= _START_PX + reach[:, None] - 1e-9) & (depths <= depths[-1] - reach[:, None] + 1e-9)
    deep = usable & (depths >= _START_PX + reach.max() - 1e-9) & (depths <= depths[-1] - reach.max() + 1e-9)
    directions = edges / lengths[:, None]
    inward = (-1.0 if area2 >= 0 else 1.0) * directions[:, ::-1] * (1.0, -1.0)
    value, origin = _value_around(image_bgr, polygon, value, np.asarray(value_origin))
    along = ((0.15 + 0.7 * (np.arange(_PROFILES) + 0.5) / _PROFILES) - 0.5)[None, :] * lengths[:, None]   # (n, M)
    centres = polygon + 0.5 * edges - origin                                                           # (n, 2)
    straight = _profiles(value, centres, directions, inward, along, np.zeros((n, 1, _PROFILES)), depths)[:, 0]
    mean = np.add.reduce(straight, axis=1) / _PROFILES                                                # (n, K)
    candidates = np.nonzero((mean[:, _RISE_SPAN:] - mean[:, :-_RISE_SPAN]).max(axis=1)
                            >= _PRECHECK * config.min_rise * mean.max(axis=1))[0]
    if len(candidates) == 0:
        return polygon
    shifts = _TILTS[None, :, None] * along[candidates, None, :]                                       # (c, T, M)
    profiles = _profiles(value, centres[candidates], directions[candidates], inward[candidates],
                         along[candidates], shifts, depths)
    points, lines = centres + origin, directions.copy()
    found = False
    for index, k in enumerate(candidates):
        crease = (_crease(profiles[index], straight[k], along[k], depths, deep, config)
                  or _crease(profiles[index], straight[k], along[k], depths, usable, config))
        if crease is None:
            continue
        tilt, depth = crease
        line = directions[k] + tilt * inward[k]
        line = line / np.sqrt(line @ line)
        point = points[k] + depth * inward[k]
        if _shadow_edge(value, origin, polygon, k, point, line, inward[k], config):
            continue
        points[k], lines[k] = point, line
        found = True
    if not found:
        return polygon
    previous = np.arange(-1, n - 1)
    corners = intersect_lines(points[previous], lines[previous], points, lines)
    moves = corners - polygon
    if not np.isfinite(corners).all() or np.max(moves[:, 0] ** 2 + moves[:, 1] ** 2) > (0.5 * size) ** 2:
        return polygon                  # nearly parallel neighbours: no corner where the lines would meet
    return corners


def _value_around(image_bgr, polygon, value, value_origin):
    """(V (float32) of the image window holding ``polygon`` plus a margin, the window's origin (2,) in the image),
    from ``value`` (a region's V, its origin ``value_origin``) when given, else from ``image_bgr``."""
    if value is None:
        value_origin = np.zeros(2, int)
        h, w = image_bgr.shape[:2]
    else:
        h, w = value.shape[:2]
    margin = int(max(_TABLE_REACH_PX) + _TABLE_SIDE_PX + 2)
    x0, y0 = np.maximum(np.floor(polygon.min(axis=0) - value_origin).astype(int) - margin, 0)
    x1, y1 = np.minimum(np.ceil(polygon.max(axis=0) - value_origin).astype(int) + margin + 1, (w, h))
    if value is None:
        window = image_bgr[y0:y1, x0:x1]
        window = cv2.max(cv2.max(window[..., 0], window[..., 1]), window[..., 2])
    else:
        window = value[y0:y1, x0:x1]
    return window.astype(np.float32), value_origin + (x0, y0)


def _shadow_edge(value, origin, polygon, k, point, line, inward, config):
    """True when, beyond both ends of the crease (``point``, unit ``line``, image px) found inside edge ``k``
    (``inward``: its inward normal), the table is darker on the strip's side of the line's extension too (at most
    ``config.max_strip_brightness`` of the other side): the edge of a shadow across block and table (the arm's, a
    cup's), not a crease, which ends at the block's outline."""
    n = len(polygon)
    ends = []
    for a, b, outward in ((polygon[k - 1], polygon[k], -1.0), (polygon[(k + 1) % n], polygon[(k + 2) % n], 1.0)):
        side = b - a                                             # the neighbouring edge the crease ends on
        cross = line[0] * side[1] - line[1] * side[0]
        if abs(cross) < 1e-9:
            return False
        t = ((a[0] - point[0]) * side[1] - (a[1] - point[1]) * side[0]) / cross
        ends.append((point + t * line, outward))
    reach = np.array(_TABLE_REACH_PX)
    beyond = np.concatenate([end + outward * reach[:, None] * line for end, outward in ends])        # (2R, 2)
    samples = np.concatenate([beyond - _TABLE_SIDE_PX * inward, beyond + _TABLE_SIDE_PX * inward]) - origin
    table = cv2.remap(value, samples[None, :, 0].astype(np.float32), samples[None, :, 1].astype(np.float32),
                      cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)[0]
    strip_side, face_side = table[:len(beyond)].mean(), table[len(beyond):].mean()
    return bool(strip_side <= config.max_strip_brightness * face_side)


def _profiles(value, centres, directions, inward, along, shifts, depths):
    """(c, T, M, K) V along each edge's lines: edge middle ``centres`` (c, 2) (window px), profiles ``along`` (c, M)
    px from it, each line's depth ``depths`` (K,) at the middle plus ``shifts`` (c, T, M) px inward."""
    sample_depths = (depths + shifts[..., None]).astype(np.float32)                             # (c, T, M, K)
    feet = (centres[:, None, :] + along[..., None] * directions[:, None, :]).astype(np.float32)   # (c, M, 2)
    inward = inward.astype(np.float32)
    shape = sample_depths.shape
    map_u = feet[:, None, :, None, 0] + sample_depths * inward[:, None, None, None, 0]
    map_v = feet[:, None, :, None, 1] + sample_depths * inward[:, None, None, None, 1]
    return cv2.remap(value, map_u.reshape(-1, shape[-1]), map_v.reshape(-1, shape[-1]), cv2.INTER_LINEAR,
                     borderMode=cv2.BORDER_REPLICATE).reshape(shape)


def _crease(profiles, straight, along, depths, usable, config):
    """(tilt, depth at the edge's middle (px)) of the crease in ``profiles`` (T, M, K), or None
    (``cut_side_faces``); ``usable`` (T, K): the depths at which each slope's line stays within the searched band
    (clear of the outline's blur) all along the edge. The strip is judged on the straight profiles ``straight``
    (M, K) (at ``along`` (M,) px from the edge's middle), clear of the outline's and the crease's blur
    (``_STRIP_PX``): a wedge-shaped strip (a side face seen in perspective) is as wide as the sloped crease leaves
    it, not as the band of the slope. The range of its middle (``_middle``) must stay within half the crease's rise
    over 2 px: flat, not a ramp from the outline."""
    mean = np.add.reduce(profiles, axis=1) / profiles.shape[1]                      # (T, K)
    rises = np.where(usable[:, _RISE_SPAN:] & usable[:, :-_RISE_SPAN],
                     mean[:, _RISE_SPAN:] - mean[:, :-_RISE_SPAN], -np.inf)         # (T, K - span)
    tilt, j = np.unravel_index(int(np.argmax(rises)), rises.shape)
    if not np.isfinite(rises[tilt, j]):
        return None                     # no slope fits the band
    crease = j + _RISE_SPAN // 2                                                    # index of the crease's depth
    last = np.flatnonzero(usable[tilt])[-1]
    strip = _strip(straight, along, depths, depths[crease] + _TILTS[tilt] * along - _STRIP_PX[1])
    if len(strip) < _MIN_STRIP_SAMPLES:
        return None                     # no strip: the outline's own blur or a rim's shaded band
    face = float(mean[tilt, crease + 2:last + 1].mean())
    rise = float(rises[tilt, j])
    agreement = float(np.mean(profiles[tilt, :, j + _RISE_SPAN] > profiles[tilt, :, j]))
    if not (rise >= config.min_rise * face and agreement >= config.min_agreement
            and float(strip.max()) <= config.max_strip_brightness * face
            and float(np.ptp(_middle(strip))) <= 0.5 * rise):
        return None
    return _TILTS[tilt], depths[crease]


def _middle(strip):
    """``strip`` without a tenth of its samples at either end (the blur of the outline and of the crease)."""
    trim = len(strip) // 10
    return strip[trim:len(strip) - trim]


def _strip(straight, along, depths, limits):
    """(S,) mean V at each of the ``depths`` from ``_STRIP_PX[0]`` on over the profiles ``straight`` (M, K) whose
    depth ``limits`` (M,) it is within, as long as half the profiles are."""
    inside = (depths[None, :] <= limits[:, None]) & (depths >= _STRIP_PX[0])        # (M, K)
    count = np.add.reduce(inside, axis=0)
    kept = count >= 0.5 * len(limits)
    return np.add.reduce(np.where(inside, straight, 0.0), axis=0)[kept] / count[kept]
