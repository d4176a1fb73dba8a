"""The thesis colour pipeline (section 3.2, Algorithm 1): BGR image in -> polygon vertices out. No ROS.

Default stages, each a small function below, every parameter in ``config/vision.yaml``:

1. BGR -> HSV (``cv2.cvtColor``).
2. Gamma correction ``S_out = 255 (S_in / 255) ** gamma`` with gamma = 0.6 (eq. 3.13), as a LUT.
3. Dynamic saturation threshold ``(S_max - S_min) / epsilon`` with epsilon = 2.25 (eq. 3.14).
4. Over-saturation: S = 250, V = 180 where the corrected S is at or above the threshold, S = V = 0 below.
5. Low-pass filter with the kernel of eq. 3.17, ``(1/(2+b)^2) [1 b 1]^T [1 b 1]``, b = 2 (separable).
6. Colour range (green: H 50-70, S 100-255, V 100-255 on OpenCV's 0-179 hue scale) -> binary mask
   (on the over-saturated image, as in the thesis).
7. Morphological opening, then closing.
8. Laplacian sharpening (kernel ``[-1 -1 -1; -1 8 -1; -1 -1 -1]``), then ``findContours``.
9. Area threshold; Douglas-Peucker (``approxPolyDP``); merge of vertices closer than a distance
   (the thesis's "high pass filter" of chapter 6); shape from the vertex count.

Where this departs from the letter of Algorithm 1, and why:

- Gamma is applied to S only. Algorithm 1 also raises H and V to the power gamma, but hue is an angle
  (a power law moves the colour ranges of step 6 and breaks the red wrap-around), and V is overwritten
  by the over-saturation of step 4 anyway, so its correction has no effect on the output.
- The low-pass filter is applied to S and V, not H: averaging hues across an edge, or across the red
  0/179 wrap-around, makes up hues that are in no range.
- Eq. 3.17 as transcribed shows a 4-element column ``[1 b b 1]``; its normalisation ``1/(2+b)^2`` only
  makes sense for ``[1 b 1]^T [1 b 1]``, which is what is used (it sums to 1).
- The merge distance is a fraction of the polygon's perimeter, not a pixel count: the thesis notes that
  its fixed-distance filter lowered the height at which a (smaller-looking) square was still found.

Beyond the thesis (all switchable in the YAML):

- Cut corners (``remove_cut_corners``, after the merge): morphology rounds acute corners and a side
  face can clip one, and Douglas-Peucker then keeps both ends of the cut; an edge whose neighbours,
  extended, meet in a point adding less than ``cut_corner_area_fraction`` of the area is replaced by
  that point (a true corner adds 8 % or more even in strong perspective). 0 disables it.
- Top-face isolation (``isolate_top_face``): in oblique views the side faces (same hue, darker) join
  the blob and turn a square into a hexagon. Under light from above the table the top face is the
  brightest face: V of the original image, inside the blob, is split by Otsu's threshold (repeated
  while the split is significant, for a side face nearly as bright as the top), and the brightest
  region that is as saturated as the top (not the pale mix of a side face and the table) is kept.
  A side face lit within ``min_contrast`` (12 %) of the top, or brighter (a low light), is not split off.
- Coarse corners (``fit_polygon_sides``): lines fitted to the sides of the outline, away from the
  corners that morphology and the face split round off, intersected.
- Sub-pixel vertices (``refine_vertices``): each edge is re-measured on the original image along its
  normal and a line is fitted to the edge points (Huber), consecutive lines intersected. The edge
  point of a profile (``_edge_crossings``) comes from a two-colour model, top face and table: the
  table's share locates the table's edge, and the darkening no mix of the two explains measures the
  side face in between: one thinner than the blur (1-3 px, near face-on views off-centre) is removed
  by its darkening mass, a wider one by the step to its colour.
- A floor under the dynamic threshold (``min_saturation_threshold``) and a zero border for the
  Laplacian, so a colourless image stays empty and a blob cut by the image border keeps a closed outline.
- Speed (``roi``): the candidate blobs of each colour are found by the same stages on a subsampled
  image; the full pipeline then runs only in padded regions around them, for their colours. The
  dynamic threshold (eq. 3.14) is then taken from the subsampled image's saturation range.

Pixels are (u, v) = (column, row), origin at the centre of the top-left pixel; vertex coordinates are
in the raw (distorted) image.
"""
import dataclasses
import functools
import math
import os
from dataclasses import dataclass, field

import cv2
import numpy as np
import yaml

from baxter_pnp.models import SHAPES
from baxter_pnp.runtime import PACKAGE_ROOT

DEFAULT_VISION_YAML = os.path.join(PACKAGE_ROOT, 'config', 'vision.yaml')
SHAPE_OF_VERTEX_COUNT = {n: shape for shape, n in SHAPES.items()}
_SQUARE5 = np.ones((5, 5), np.uint8)
LAPLACIAN_KERNEL = np.array([[-1, -1, -1], [-1, 8, -1], [-1, -1, -1]], dtype=np.float32)
_TIE_AREA_FRACTION = 0.02   # select_target: areas within 2 % of the largest count as a tie


# ================================================================================== configuration
@dataclass(frozen=True)
class TopFaceConfig:
    """Top-face isolation: the brightest face (by V) inside the blob (see ``isolate_top_face``)."""
    enabled: bool = True
    min_contrast: float = 0.12
    min_face_fraction: float = 0.1
    min_solidity: float = 0.8


@dataclass(frozen=True)
class SubpixelConfig:
    """Sub-pixel edge-line refinement of the vertices (see ``refine_vertices``); lengths in pixels."""
    enabled: bool = True
    passes: int = 1
    profile_half_length_px: float = 4.0
    profile_step_px: float = 0.5
    profiles_per_edge: int = 16
    corner_margin_px: float = 1.5
    min_edge_length_px: float = 4.0
    min_points: int = 6
    min_contrast: float = 20.0
    side_face_darkening: float = 0.5
    min_strip_mass_px: float = 0.15
    resolved_strip_px: float = 2.5
    max_rms_px: float = 0.5
    max_shift_px: float = 5.0


@dataclass(frozen=True)
class RoiConfig:
    """Candidate search on an image subsampled by ``downsample``; full pipeline in padded regions."""
    enabled: bool = True
    downsample: int = 8
    padding_px: int = 16


@dataclass(frozen=True)
class VisionConfig:
    """Parameters of the pipeline; the fields mirror ``config/vision.yaml`` (see its comments).

    ``colours`` maps a colour name to a tuple of inclusive HSV ranges ``((h, s, v) low, (h, s, v) high)``
    whose masks are OR-ed (red needs two: its hue wraps around 0).
    """
    gamma: float = 0.6
    saturation_epsilon: float = 2.25
    min_saturation_threshold: float = 30.0
    oversaturated_s: int = 250
    oversaturated_v: int = 180
    lowpass_b: float = 2.0
    colours: dict = field(default_factory=lambda: {'green': (((50, 100, 100), (70, 255, 255)),)})
    morphology_kernel_px: int = 3
    laplacian_sharpening: bool = True
    min_area_px: float = 100.0
    approx_epsilon_fraction: float = 0.02
    merge_distance_fraction: float = 0.05
    cut_corner_area_fraction: float = 0.04
    border_margin_px: float = 3.0
    top_face: TopFaceConfig = field(default_factory=TopFaceConfig)
    subpixel: SubpixelConfig = field(default_factory=SubpixelConfig)
    roi: RoiConfig = field(default_factory=RoiConfig)

    def __post_init__(self):
        if not self.gamma > 0:
            raise ValueError(f'vision config: gamma must be > 0, got {self.gamma}')
        if not self.saturation_epsilon > 0:
            raise ValueError(f'vision config: saturation_epsilon must be > 0, got {self.saturation_epsilon}')
        if not self.lowpass_b >= 0:
            raise ValueError(f'vision config: lowpass_b must be >= 0, got {self.lowpass_b}')
        if self.morphology_kernel_px < 1:
            raise ValueError(f'vision config: morphology_kernel_px must be >= 1, got {self.morphology_kernel_px}')
        if self.roi.downsample < 1:
            raise ValueError(f'vision config: roi.downsample must be >= 1, got {self.roi.downsample}')
        if not self.colours:
            raise ValueError('vision config: no colours defined')
        object.__setattr__(self, 'colours', {name: _parse_colour_ranges(name, ranges)
                                             for name, ranges in self.colours.items()})

    def colour_names(self):
        """Names of the configured colours, in YAML order."""
        return list(self.colours)

    @classmethod
    def from_dict(cls, d):
        """Config from a dictionary shaped like the YAML; ValueError on an unknown or malformed key."""
        if not isinstance(d, dict):
            raise ValueError('vision config: not a mapping')
        sections = {'top_face': TopFaceConfig, 'subpixel': SubpixelConfig, 'roi': RoiConfig}
        kwargs = {}
        for key, value in d.items():
            if key in sections:
                kwargs[key] = _dataclass_from_dict(sections[key], value, f'vision config: {key}')
            else:
                kwargs[key] = value
        return _dataclass_from_dict(cls, kwargs, 'vision config')

    @classmethod
    def from_yaml(cls, path=None):
        """Config from a YAML file (default ``config/vision.yaml`` of the package)."""
        path = path or DEFAULT_VISION_YAML
        with open(path) as f:
            d = yaml.safe_load(f)
        try:
            return cls.from_dict(d)
        except (TypeError, ValueError) as error:
            raise ValueError(f'{path}: {error}') from None


def _dataclass_from_dict(cls, d, where):
    """``cls(**d)`` with the keys and the types of the scalar values checked against ``cls()``'s defaults."""
    if not isinstance(d, dict):
        raise ValueError(f'{where}: expected a mapping, got {type(d).__name__}')
    defaults = cls()
    known = [f.name for f in dataclasses.fields(cls)]
    unknown = sorted(set(d) - set(known))
    if unknown:
        raise ValueError(f'{where}: unknown key(s) {unknown}; known: {known}')
    kwargs = {}
    for key, value in d.items():
        default = getattr(defaults, key)
        if isinstance(default, bool) and not isinstance(value, bool):
            raise ValueError(f'{where}: {key} must be true or false, got {value!r}')
        if isinstance(default, (int, float)) and not isinstance(default, bool):
            if isinstance(value, bool) or not isinstance(value, (int, float)):
                raise ValueError(f'{where}: {key} must be a number, got {value!r}')
            if isinstance(default, int) and value != int(value):
                raise ValueError(f'{where}: {key} must be an integer, got {value!r}')
            value = type(default)(value)
        kwargs[key] = value
    return cls(**kwargs)


def _parse_colour_ranges(name, ranges):
    """Tuple of ``((h, s, v), (h, s, v))`` integer ranges, or ValueError naming the colour."""
    try:
        parsed = tuple((tuple(int(c) for c in low), tuple(int(c) for c in high)) for low, high in ranges)
    except (TypeError, ValueError):
        raise ValueError(f'vision config: colour {name!r} must be a list of [[h, s, v], [h, s, v]] ranges, '
                         f'got {ranges!r}') from None
    if not parsed:
        raise ValueError(f'vision config: colour {name!r} has no range')
    for low, high in parsed:
        if len(low) != 3 or len(high) != 3:
            raise ValueError(f'vision config: colour {name!r}: each bound needs 3 values (h, s, v)')
        if not all(0 <= lo <= hi <= top for lo, hi, top in zip(low, high, (179, 255, 255))):
            raise ValueError(f'vision config: colour {name!r}: range {low}-{high} must satisfy '
                             f'0 <= low <= high <= (179, 255, 255)')
    return parsed


# ================================================================================== thesis stages
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


def approximate_polygon(contour, epsilon_fraction):
    """(k, 2) float vertices of the Douglas-Peucker approximation (tolerance = fraction of the perimeter)."""
    epsilon = epsilon_fraction * cv2.arcLength(contour, True)
    return cv2.approxPolyDP(contour, epsilon, True).reshape(-1, 2).astype(float)


def remove_cut_corners(vertices, max_area_fraction):
    """Convex polygon (k, 2) with its cut corners restored, smallest first, down to a triangle.

    An edge is a cut corner (or a spurious vertex on a straight side) when its two neighbouring
    edges, extended beyond it, meet in a point that adds less than ``max_area_fraction`` of the
    polygon's area; the edge's two vertices are replaced by that point. Restoring a true corner of
    a regular polygon adds a sixth of its area (hexagon) or more in an affine view, still 8 % in the
    strongest perspective of the benchmark (a 54 mm hexagon 0.13 m away, tilted 29 deg), while a cut
    corner adds a few per cent at most. Morphology rounds acute corners and a side face can clip a
    corner of the top face; Douglas-Peucker then keeps both ends of the cut.
    """
    polygon = [tuple(v) for v in np.asarray(vertices, dtype=float).reshape(-1, 2)]
    while len(polygon) > 3:
        n = len(polygon)
        area = 0.5 * abs(sum(polygon[k - 1][0] * polygon[k][1] - polygon[k][0] * polygon[k - 1][1] for k in range(n)))
        best, best_added = None, max_area_fraction * area
        for k in range(n):
            (px, py), (ax, ay), (bx, by), (qx, qy) = (polygon[k - 1], polygon[k], polygon[(k + 1) % n],
                                                      polygon[(k + 2) % n])
            d_in, d_out, gap = (ax - px, ay - py), (bx - qx, by - qy), (bx - ax, by - ay)
            cross = d_in[0] * d_out[1] - d_in[1] * d_out[0]
            if abs(cross) < 1e-12:
                continue                                          # parallel neighbours: no apex
            t = (gap[0] * d_out[1] - gap[1] * d_out[0]) / cross   # apex = a + t d_in = b + u d_out
            u = (gap[0] * d_in[1] - gap[1] * d_in[0]) / cross
            if t < 0 or u < 0:
                continue                                          # diverging beyond the edge
            apex = (ax + t * d_in[0], ay + t * d_in[1])
            added = 0.5 * abs((apex[0] - ax) * gap[1] - (apex[1] - ay) * gap[0])
            if added < best_added:
                best, best_added = (k, apex), added
        if best is None:
            break
        k, apex = best
        polygon[k] = apex
        del polygon[(k + 1) % n]
    return np.array(polygon, dtype=float)


def merge_close_vertices(vertices, min_distance):
    """Closed polygon (k, 2) with each run of consecutive vertices closer than ``min_distance`` replaced by its mean.

    The closest pair of neighbouring clusters (by their means) is merged first, until none is closer.
    """
    clusters = [[tuple(v)] for v in np.asarray(vertices, dtype=float).reshape(-1, 2)]
    centres = [c[0] for c in clusters]
    while len(clusters) > 1:
        gaps = [math.dist(centres[i], centres[(i + 1) % len(centres)]) for i in range(len(centres))]
        i = min(range(len(gaps)), key=gaps.__getitem__)
        if gaps[i] >= min_distance:
            break
        j = (i + 1) % len(clusters)
        clusters[i] += clusters[j]
        centres[i] = tuple(sum(c) / len(clusters[i]) for c in zip(*clusters[i]))
        del clusters[j], centres[j]
    return np.array(centres, dtype=float).reshape(-1, 2)


def fit_polygon_sides(contour, vertices, end_fraction=0.2):
    """Vertices (k, 2) re-estimated as the intersections of lines fitted to the sides of ``contour``.

    ``vertices`` (k, 2) is a coarse polygon on ``contour`` (e.g. Douglas-Peucker's); each contour
    point is assigned to its nearest side, the points nearer a side's ends than ``end_fraction`` of
    its length are dropped (rounded or clipped corners), and a line is fitted to the rest (total
    least squares: through their mean, along their principal axis; a long contour is subsampled to
    about ``_MAX_SIDE_FIT_POINTS`` points). A vertex whose two lines are missing (fewer than 3
    points), nearly parallel, or meet farther than half a side from it is kept. Corrects corners cut
    off by morphology or by the top-face split by up to several pixels.
    """
    vertices = np.asarray(vertices, dtype=float).reshape(-1, 2)
    points = contour.reshape(-1, 2)
    points = points[::max(1, len(points) // _MAX_SIDE_FIT_POINTS)].astype(float)
    n = len(vertices)
    previous = np.arange(-1, n - 1)
    sides = vertices[np.arange(1, n + 1) % n] - vertices
    lengths_sq = np.maximum((sides ** 2).sum(axis=1), 1e-18)
    # (points, sides): position along each side (0..1) and squared distance to it (components written
    # out: numpy reduces slowly over a length-2 axis)
    dx, dy = points[:, :1] - vertices[:, 0], points[:, 1:] - vertices[:, 1]
    t = (dx * sides[:, 0] + dy * sides[:, 1]) / lengths_sq
    along = np.minimum(np.maximum(t, 0.0), 1.0)
    nearest = np.argmin((dx - along * sides[:, 0]) ** 2 + (dy - along * sides[:, 1]) ** 2, axis=1)
    chosen = (nearest[:, None] == np.arange(n)) & (t > end_fraction) & (t < 1.0 - end_fraction)
    counts = chosen.sum(axis=0)
    weights = chosen / np.maximum(counts, 1)
    means = weights.T @ points                                                   # (n, 2)
    second = weights.T @ (points[:, :, None] * points[:, None, :]).reshape(-1, 4)   # E[x x^T] per side
    cxx = second[:, 0] - means[:, 0] ** 2
    cxy = second[:, 1] - means[:, 0] * means[:, 1]
    cyy = second[:, 3] - means[:, 1] ** 2
    angle = 0.5 * np.arctan2(2.0 * cxy, cxx - cyy)
    directions = np.stack([np.cos(angle), np.sin(angle)], axis=1)
    corners = _intersect_lines(means[previous], directions[previous], means, directions)
    good = (counts >= 3) & (counts[previous] >= 3)
    good &= ((corners - vertices) ** 2).sum(axis=1) < 0.25 * np.minimum(lengths_sq[previous], lengths_sq)
    return np.where(good[:, None], corners, vertices)


_MAX_SIDE_FIT_POINTS = 240


def classify_shape(vertex_count):
    """Shape name of a polygon with ``vertex_count`` vertices (3 triangle .. 6 hexagon), else None."""
    return SHAPE_OF_VERTEX_COUNT.get(int(vertex_count))


def order_vertices(vertices):
    """Vertices sorted by increasing ``atan2(v - vc, u - uc)`` about their mean (clockwise on screen)."""
    vertices = np.asarray(vertices, dtype=float).reshape(-1, 2)
    centre = vertices.mean(axis=0)
    angles = np.arctan2(vertices[:, 1] - centre[1], vertices[:, 0] - centre[0])
    return vertices[np.argsort(angles, kind='stable')]


# ================================================================================== beyond the thesis
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


def refine_vertices(image_bgr, coarse_px, config):
    """Sub-pixel vertices of the polygon ``coarse_px`` (n, 2) seen in ``image_bgr`` (the original image).

    Along each edge, ``profiles_per_edge`` colour profiles are sampled (bilinearly) along the edge
    normal, ``+- profile_half_length_px`` about the current edge, spread evenly but not near the
    corners (where a profile would reach the next edge). Each profile gives the sub-pixel position
    of the top face's edge (``_edge_crossings``: the table's edge, moved inwards across a thin side
    face, or the step to a wide one); a line is fitted to the edge's points (least squares with one
    Huber reweighting) and consecutive lines are intersected. This is repeated ``passes`` times,
    each pass sampling about the previous pass's polygon. A vertex keeps its coarse position when
    either adjacent line failed (fewer than ``min_points`` edge points, contrast below
    ``min_contrast``, RMS above ``max_rms_px``), the lines are within ~10 deg of parallel, or the
    intersection is more than ``max_shift_px`` from the coarse vertex.

    Returns ``(vertices (n, 2), rms_px, fallback_count)`` of the last pass: ``rms_px`` is the RMS
    distance of the edge points to their lines over the fitted edges (NaN if none).
    """
    coarse = np.asarray(coarse_px, dtype=float).reshape(-1, 2)
    r, step = config.profile_half_length_px, config.profile_step_px
    offsets = np.arange(-r, r + 0.5 * step, step)
    previous = np.arange(-1, len(coarse) - 1)                   # vertex k joins edges k - 1 and k
    vertices, rms, fallbacks = coarse, float('nan'), len(coarse)
    for _ in range(config.passes):
        samples, points, directions, normals, usable = _sample_edge_profiles(image_bgr, vertices, offsets, config)
        crossings, contrasts = _edge_crossings(samples, offsets, config)
        crossings[~(usable & (contrasts >= config.min_contrast))] = np.nan
        anchors, line_directions, residuals = _fit_edge_lines(points, directions, normals, crossings,
                                                              config.min_points)
        used = np.isfinite(residuals)
        squared = np.where(used, residuals, 0.0) ** 2
        edge_rms = np.sqrt(_sum(squared, 1) / np.maximum(_sum(used, 1), 1))
        fitted = np.isfinite(anchors[:, 0]) & (edge_rms <= config.max_rms_px)
        corners = _intersect_lines(anchors[previous], line_directions[previous], anchors, line_directions)
        shift = corners - coarse
        good = fitted & fitted[previous] & (_sum(shift ** 2, 1) <= config.max_shift_px ** 2)
        vertices = np.where(good[:, None], corners, coarse)
        fallbacks = int(len(coarse) - good.sum())
        count = used[fitted].sum()
        rms = float(np.sqrt(squared[fitted].sum() / count)) if count else float('nan')
    return vertices, rms, fallbacks


def _sample_edge_profiles(image_bgr, polygon, offsets, config):
    """Colour profiles across the edges of ``polygon`` (n, 2); edge k runs from vertex k to k+1.

    Returns ``samples (n, M, K, 3)`` float32 (M = ``profiles_per_edge`` profiles of K = len(offsets)
    samples, from inside to outside), their centre ``points (n, M, 2)`` on the edge, the unit edge
    ``directions (n, 2)`` and outward ``normals (n, 2)``, and ``usable (n,)`` (False for an edge too
    short to hold the profiles clear of its corners). All profiles come from one ``cv2.remap`` of the
    image (bilinear, to 1/32 px and whole grey levels).
    """
    n, m = len(polygon), config.profiles_per_edge
    following = np.arange(1, n + 1) % n
    edges = polygon[following] - polygon
    lengths = np.maximum(np.sqrt(_sum(edges ** 2, 1)), 1e-9)
    directions = edges / lengths[:, None]
    area2 = float((polygon[:, 0] * polygon[following, 1] - polygon[following, 0] * polygon[:, 1]).sum())
    normals = (1.0 if area2 >= 0 else -1.0) * directions[:, ::-1] * (1.0, -1.0)
    # keep profiles away from the corners: reach / sin(corner angle) plus a margin
    before = directions[np.arange(-1, n - 1)]                   # edge k - 1
    sines = np.abs(before[:, 0] * directions[:, 1] - before[:, 1] * directions[:, 0])
    margins = config.corner_margin_px + offsets[-1] / np.maximum(sines, 0.3)
    first, last = margins, lengths - margins[following]
    usable = last - first >= config.min_edge_length_px
    t = first[:, None] + (last - first)[:, None] * ((np.arange(m) + 0.5) / m)
    points = polygon[:, None, :] + t[..., None] * directions[:, None, :]
    coords = (points[:, :, None, :] + offsets[:, None] * normals[:, None, None, :]).astype(np.float32)
    samples = cv2.remap(image_bgr, coords.reshape(n * m, len(offsets), 2), None, cv2.INTER_LINEAR,
                        borderMode=cv2.BORDER_REPLICATE)
    return samples.reshape(n, m, len(offsets), 3).astype(np.float32), points, directions, normals, usable


def _edge_crossings(samples, offsets, config):
    """Offset (px, along the outward normal) of the top face's edge in each profile, and each edge's contrast.

    ``samples`` (E, M, K, 3): colours along M profiles of each of E edges, from inside to outside.
    An edge's inside colour is the median of its profiles' first two samples (the top face), its far
    colour that of their last two. Beyond a top edge lies the table, or a side face (the top's
    colour, darker) and then the table. The table colour is the far colour least like a shade of the
    top's (largest part orthogonal to it), for the edges that end on a side face. Each sample is
    written ``a top + b table`` (least squares): ``b`` is the table's share, and the darkening
    ``d = 1 - a - b`` is 0 on the top, on the table and on any blur of the two, and ``1 - s`` on a
    side face ``s`` times as bright as the top. Per edge (medians over its profiles):

    - no side face (darkening mass, the integral of ``d`` up to 2 px beyond where ``b`` crosses 0.5,
      below ``min_strip_mass_px``): the 0.5 crossing of the step from the top's colour to the table's;
    - a thin side face (width below ``resolved_strip_px``): blur mixes it with both neighbours, so
      its darkness is never seen, but blur keeps the darkening mass, ``(1 - s) w``; with ``1 - s``
      the (median) deepest darkening seen, at least ``side_face_darkening``, the edge is ``w``
      inside the table's edge (where ``b`` crosses 0.5), ``w`` fitted linearly along the edge;
    - a wider side face, or one that fills the profile's outer end: the 0.5 crossing of the step
      from the top's colour to the side face's (the darkest sample's);
    - no table-like far colour on any edge, or a far colour that is neither table-like nor a shade of
      the top: the 0.5 crossing of the step to the far colour.

    Crossings are linearly interpolated, the one nearest the steepest part of the step, NaN where
    there is none. Returns ``(crossings (E, M), contrasts (E,))``, the contrast being the BGR
    distance between the inside and far colours.
    """
    step = offsets[1] - offsets[0]
    e, m, k = samples.shape[:3]
    ends = samples[:, :, [0, 1, k - 2, k - 1]].reshape(e, m, 2, 2, 3).transpose(2, 0, 4, 1, 3).reshape(2, e, 3, 2 * m)
    inside, far = _median(ends)                                                   # (E, 3) each
    g_ii, g_if, g_ff = _sum(inside * inside, 1), _sum(inside * far, 1), _sum(far * far, 1)
    contrasts = np.sqrt(np.maximum(g_ii - 2.0 * g_if + g_ff, 0.0))
    # share of the far colour orthogonal to the top's: 0 for a shade of the top, large for the grey table
    unlike = np.sqrt(np.maximum(1.0 - g_if ** 2 / np.maximum(g_ii * g_ff, 1e-9), 0.0))
    table = np.where((unlike >= _TABLE_LIKE * unlike.max())[:, None], far, far[np.argmax(unlike)])
    a, b = _two_colour_shares(samples, inside, table)
    darkening = 1.0 - a - b
    x_b = _crossing(b, offsets)
    reached = np.isfinite(x_b)
    window = offsets <= np.where(reached, x_b, np.inf)[..., None] + 2.0
    windowed = np.where(window, darkening, -np.inf)
    mass = _sum(darkening * window, 2) * step                                      # (E, M) px
    median_mass, median_peak = _median(np.stack([mass, windowed.max(axis=2)]))
    side_darkening = np.maximum(median_peak, config.side_face_darkening)
    table_seen = unlike.max() >= _MIN_TABLE_UNLIKENESS                            # else no basis
    side_face = table_seen & (median_mass >= config.min_strip_mass_px)
    thin = side_face & (median_mass < config.resolved_strip_px * side_darkening)
    table_beyond = table_seen & (_sum(reached, 1) >= 0.5 * m)
    to_side = side_face & (~thin | ~table_beyond)                 # a side face measured by the step to it
    # the step each edge is measured by: to the side face's colour (its darkest sample; what lies beyond
    # is ignored), to the table (no side face), or to the far colour (neither seen)
    darkest = np.argmax(windowed, axis=2)                                          # (E, M)
    side_colour = _median(samples[np.arange(e)[:, None], np.arange(m), darkest].transpose(0, 2, 1))
    target = np.where(to_side[:, None], side_colour, np.where(table_beyond[:, None], table, far))
    beyond = to_side[:, None, None] & (offsets > offsets[darkest][..., None])
    crossings = _crossing(np.where(beyond, 1.0, _step_share(samples, inside, target)), offsets)
    thin &= table_beyond
    if thin.any():
        width = _linear_along_edge(np.maximum(mass[thin], 0.0) / side_darkening[thin, None], reached[thin])
        crossings[thin] = x_b[thin] - width
    return crossings, contrasts


_TABLE_LIKE = 0.8              # _edge_crossings: a far colour this close to the most table-like one is the table
_MIN_TABLE_UNLIKENESS = 0.2    # ... and none is unless its part orthogonal to the top's colour is this large


def _step_share(samples, start, end):
    """(E, M, K) position of ``samples`` (E, M, K, 3) on each edge's colour step ``start`` -> ``end`` (E, 3), 0 to 1."""
    difference = end - start
    share = (samples @ difference[:, None, :, None])[..., 0] - _sum(start * difference, 1)[:, None, None]
    return share / np.maximum(_sum(difference ** 2, 1), 1e-9)[:, None, None]


def _linear_along_edge(values, valid):
    """(E, M) least-squares straight lines through each row of ``values`` (E, M) against the profile index.

    Only the ``valid`` entries count; a row with fewer than two is replaced by its mean (0 if none).
    """
    index = np.arange(values.shape[1], dtype=float)
    weights = valid.astype(float)
    count = np.maximum(_sum(weights, 1), 1.0)
    mean_index = _sum(weights * index, 1) / count
    mean_value = _sum(weights * np.where(valid, values, 0.0), 1) / count
    centred = index - mean_index[:, None]
    spread = _sum(weights * centred ** 2, 1)
    slope = _sum(weights * centred * np.where(valid, values, 0.0), 1) / np.where(spread > 0, spread, np.inf)
    return mean_value[:, None] + slope[:, None] * centred


def _median(values):
    """Median along the last axis (``np.median`` without its Python overhead, for tiny arrays)."""
    ordered = np.sort(values, axis=-1)
    count = ordered.shape[-1]
    return 0.5 * (ordered[..., (count - 1) // 2] + ordered[..., count // 2])


_sum = np.add.reduce   # sum along an axis, without ndarray.sum's Python wrapper (hot loops on tiny arrays)


def _two_colour_shares(samples, first, second):
    """``(a, b)`` (E, M, K): least-squares shares of ``samples`` (E, M, K, 3) = a first + b second, per edge."""
    g11, g12, g22 = _sum(first * first, 1), _sum(first * second, 1), _sum(second * second, 1)
    determinant = g11 * g22 - g12 ** 2
    determinant = np.where(np.abs(determinant) > 1e-9 * g11 * g22, determinant, np.inf)[:, None, None]
    p1 = samples @ first[:, None, :, None]
    p2 = samples @ second[:, None, :, None]
    a = (g22[:, None, None] * p1[..., 0] - g12[:, None, None] * p2[..., 0]) / determinant
    b = (g11[:, None, None] * p2[..., 0] - g12[:, None, None] * p1[..., 0]) / determinant
    return a, b


def _crossing(profile, offsets):
    """Offset (...,) where each profile (..., K) rises through 0.5 (linear interpolation), nearest its steepest rise.

    NaN where the profile never rises through 0.5.
    """
    shape, k = profile.shape[:-1], profile.shape[-1]
    profile = profile.reshape(-1, k)
    rows = np.arange(len(profile))
    slope = profile[:, 2:] - profile[:, :-2]                                     # centred, at samples 1..K-2
    steepest = np.argmax(slope, axis=1) + 0.5                                    # between samples j and j + 1
    above = profile >= 0.5
    rises = ~above[:, :-1] & above[:, 1:]                                        # between samples i and i + 1
    i = np.argmin(np.where(rises, np.abs(np.arange(k - 1) - steepest[:, None]), np.inf), axis=1)
    p0, p1 = profile[rows, i], profile[rows, i + 1]
    crossing = offsets[i] + (offsets[1] - offsets[0]) * (0.5 - p0) / np.where(p1 > p0, p1 - p0, 1.0)
    return np.where(rises[rows, i], crossing, np.nan).reshape(shape)


def _fit_edge_lines(points, directions, normals, crossings, min_points):
    """Lines through each edge's points ``points + crossings * normal`` (NaN crossings skipped).

    The offsets are fitted as a linear function of the position along the edge, by least squares
    then once more with Huber weights (threshold 1.345 times the RMS residual, at least 0.05 px). Returns
    ``(anchors (E, 2), directions (E, 2), residuals (E, M))``: a point and unit direction of each
    line (NaN with fewer than ``min_points`` points) and each point's distance to it (px, signed, NaN if unused).
    """
    valid = np.isfinite(crossings)
    offset = np.where(valid, crossings, 0.0)
    centre = points.mean(axis=1)                                                # (E, 2)
    t = ((points[..., 0] - centre[:, :1]) * directions[:, :1] + (points[..., 1] - centre[:, 1:]) * directions[:, 1:])
    weights = valid.astype(float)
    for _ in range(2):
        sw = _sum(weights, 1)
        swt, swc = _sum(weights * t, 1), _sum(weights * offset, 1)
        swtt, swtc = _sum(weights * t * t, 1), _sum(weights * t * offset, 1)
        denominator = sw * swtt - swt ** 2
        solvable = denominator > 1e-9
        slope = np.where(solvable, sw * swtc - swt * swc, 0.0) / np.where(solvable, denominator, 1.0)
        intercept = (swc - slope * swt) / np.maximum(sw, 1e-9)
        residuals = np.where(valid, offset - intercept[:, None] - slope[:, None] * t, 0.0)
        scale = np.maximum(np.sqrt(_sum(weights * residuals ** 2, 1) / np.maximum(sw, 1e-9)), 0.05)
        weights = valid * np.minimum(1.0, 1.345 * scale[:, None] / np.maximum(np.abs(residuals), 1e-12))
    residuals[~valid] = np.nan
    norm = np.sqrt(1.0 + slope ** 2)
    enough = _sum(valid, 1) >= max(min_points, 2)
    anchors = np.where(enough[:, None], centre + intercept[:, None] * normals, np.nan)
    line_directions = np.where(enough[:, None], (directions + slope[:, None] * normals) / norm[:, None], np.nan)
    return anchors, line_directions, residuals / norm[:, None]


def _intersect_lines(points_a, directions_a, points_b, directions_b):
    """(n, 2) intersections of lines a and b (point, unit direction); NaN where within ~10 deg of parallel."""
    cross = directions_a[:, 0] * directions_b[:, 1] - directions_a[:, 1] * directions_b[:, 0]
    crossing = np.abs(cross) >= 0.17                          # NaN directions compare False
    gap = points_b - points_a
    t = (gap[:, 0] * directions_b[:, 1] - gap[:, 1] * directions_b[:, 0]) / np.where(crossing, cross, 1.0)
    return np.where(crossing[:, None], points_a + t[:, None] * directions_a, np.nan)


# ================================================================================== detection
@dataclass
class Detection:
    """A polygon of one colour found in the image (pixels of the raw, distorted image).

    ``vertices_px`` (n, 2) ordered by increasing ``atan2(v - vc, u - uc)``; ``centroid_px`` (2,) and
    ``area_px`` (px^2) of that polygon; ``quality`` in 0..1 (1 = clean, convex polygon whose edges fit
    straight lines); ``touches_border``: a vertex within ``border_margin_px`` of the image border;
    ``contour`` (M, 1, 2) int32: the outline used (the top face), for drawing.
    """
    shape: str
    colour: str
    vertices_px: np.ndarray
    centroid_px: np.ndarray
    area_px: float
    quality: float
    touches_border: bool
    contour: np.ndarray


def validate_image(image_bgr):
    """``image_bgr`` if it is a non-empty uint8 (H, W, 3) array, else ValueError saying what is wrong.

    Single-channel (mono8) images are rejected, not converted: the pipeline segments by hue, so a grey
    image can never contain a detection and accepting it would hide a wrong topic or encoding.
    """
    if not isinstance(image_bgr, np.ndarray):
        raise ValueError(f'detect: expected a numpy array, got {type(image_bgr).__name__}')
    if image_bgr.dtype != np.uint8:
        raise ValueError(f'detect: expected a uint8 image, got dtype {image_bgr.dtype}')
    if image_bgr.ndim != 3 or image_bgr.shape[2] != 3:
        raise ValueError(f'detect: expected a BGR image of shape (H, W, 3), got shape {image_bgr.shape}'
                         + ('; mono8 images are not accepted (the pipeline segments by colour)'
                            if image_bgr.ndim == 2 else ''))
    if image_bgr.shape[0] == 0 or image_bgr.shape[1] == 0:
        raise ValueError(f'detect: empty image of shape {image_bgr.shape}')
    return image_bgr


def detect(image_bgr, config, colours=None, shapes=None):
    """Polygons of the configured colours in a BGR uint8 image, largest first.

    ``colours`` / ``shapes``: names to look for (None = every configured colour / every shape of
    ``models.SHAPES``); unknown names raise ValueError, as does a bad image (``validate_image``).
    """
    image_bgr = validate_image(image_bgr)
    colours = config.colour_names() if colours is None else list(colours)
    unknown = [c for c in colours if c not in config.colours]
    if unknown:
        raise ValueError(f'detect: unknown colour(s) {unknown}; configured: {config.colour_names()}')
    shapes = set(SHAPES) if shapes is None else set(shapes)
    if not shapes <= set(SHAPES):
        raise ValueError(f'detect: unknown shape(s) {sorted(shapes - set(SHAPES))}; known: {sorted(SHAPES)}')
    ranges = {name: config.colours[name] for name in colours}
    if config.roi.enabled:
        threshold, regions = _candidate_regions(image_bgr, ranges, config)
    else:
        hsv = cv2.cvtColor(image_bgr, cv2.COLOR_BGR2HSV)
        threshold = _dynamic_threshold(hsv, config)
        regions = [((0, 0, image_bgr.shape[1], image_bgr.shape[0]), set(ranges))]
    detections = []
    for region, region_colours in regions:
        region_ranges = {name: r for name, r in ranges.items() if name in region_colours}
        detections.extend(_detect_in_region(image_bgr, region, threshold, region_ranges, shapes, config))
    detections.sort(key=lambda d: -d.area_px)
    return detections


def _dynamic_threshold(hsv, config):
    """Eq. 3.14 on the gamma-corrected saturation of ``hsv``, floored at ``min_saturation_threshold``."""
    return saturation_threshold(cv2.LUT(hsv[..., 1], gamma_lut(config.gamma)), config.saturation_epsilon,
                                config.min_saturation_threshold)


def _oversaturated_hsv(hsv, threshold, config):
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


def _candidate_regions(image_bgr, ranges, config):
    """``(threshold, regions)``: eq. 3.14's threshold and the regions ``((x0, y0, x1, y1), colours)`` to search.

    Runs stages 1-6 on the image subsampled by ``roi.downsample`` (nearest pixel); each blob of a
    colour gives a box padded by ``roi.padding_px``; overlapping boxes are merged (with their
    colours) so that every blob lies whole inside exactly one region.
    """
    f = config.roi.downsample
    h, w = image_bgr.shape[:2]
    small = cv2.resize(image_bgr, (max(1, w // f), max(1, h // f)), interpolation=cv2.INTER_NEAREST)
    hsv = cv2.cvtColor(small, cv2.COLOR_BGR2HSV)
    threshold = _dynamic_threshold(hsv, config)
    oversaturated = _oversaturated_hsv(hsv, threshold, config)
    pad = config.roi.padding_px
    boxes = []
    for colour, colour_ranges in ranges.items():
        mask = colour_mask(oversaturated, colour_ranges)
        if not cv2.countNonZero(mask):
            continue
        _, _, stats, _ = cv2.connectedComponentsWithStats(mask, connectivity=8)
        for x, y, bw, bh, area in stats[1:]:
            if area * f * f >= 0.25 * config.min_area_px:
                boxes.append(((max(0, x * f - pad), max(0, y * f - pad),
                               min(w, (x + bw) * f + pad), min(h, (y + bh) * f + pad)), {colour}))
    return threshold, _merge_boxes(boxes)


def _merge_boxes(boxes):
    """Union of overlapping ``((x0, y0, x1, y1), colours)`` boxes (and of their colour sets) until none overlap."""
    boxes = list(boxes)
    merged = True
    while merged:
        merged = False
        for i in range(len(boxes)):
            for j in range(i + 1, len(boxes)):
                (a, colours_a), (b, colours_b) = boxes[i], boxes[j]
                if a[0] < b[2] and b[0] < a[2] and a[1] < b[3] and b[1] < a[3]:
                    boxes[i] = ((min(a[0], b[0]), min(a[1], b[1]), max(a[2], b[2]), max(a[3], b[3])),
                                colours_a | colours_b)
                    del boxes[j]
                    merged = True
                    break
            if merged:
                break
    return boxes


def _detect_in_region(image_bgr, region, threshold, ranges, shapes, config):
    """Detections of the colours in ``ranges`` whose blobs lie in ``region`` = (x0, y0, x1, y1) of the full image."""
    x0, y0, x1, y1 = region
    crop = image_bgr[y0:y1, x0:x1]
    hsv = cv2.cvtColor(crop, cv2.COLOR_BGR2HSV)
    oversaturated = _oversaturated_hsv(hsv, threshold, config)
    offset = np.array([x0, y0])
    detections = []
    for colour, colour_ranges in ranges.items():
        mask = colour_mask(oversaturated, colour_ranges)
        if not cv2.countNonZero(mask):
            continue
        mask = open_close(mask, config.morphology_kernel_px)
        binary = laplacian_sharpen(mask) if config.laplacian_sharpening else mask
        for blob in find_blobs(binary, config.min_area_px):
            outline = isolate_top_face(blob, hsv, config.top_face) if config.top_face.enabled else blob
            detection = None if outline is None else _polygon_detection(image_bgr, outline, offset, colour, config)
            if detection is not None and detection.shape in shapes:
                detections.append(detection)
    return detections


def _polygon_detection(image_bgr, outline, offset, colour, config):
    """Detection of the top-face ``outline`` (contour in region coordinates, ``offset`` = region origin), or None.

    ``quality`` = solidity of the outline x exp(-edge RMS / ``max_rms_px``) x (1 - fallbacks / (2 n)).
    """
    hull = cv2.convexHull(outline)
    coarse = approximate_polygon(hull, config.approx_epsilon_fraction)
    coarse = merge_close_vertices(coarse, config.merge_distance_fraction * cv2.arcLength(hull, True))
    coarse = remove_cut_corners(coarse, config.cut_corner_area_fraction)
    shape = classify_shape(len(coarse))
    if shape is None:
        return None
    coarse = fit_polygon_sides(outline, coarse)
    coarse = coarse + offset
    solidity = cv2.contourArea(outline) / max(cv2.contourArea(hull), 1e-9)
    if config.subpixel.enabled:
        vertices, rms, fallbacks = refine_vertices(image_bgr, coarse, config.subpixel)
        fit = math.exp(-rms / config.subpixel.max_rms_px) if np.isfinite(rms) else 0.5
        quality = solidity * fit * (1.0 - 0.5 * fallbacks / len(coarse))
    else:
        vertices, quality = coarse, solidity
    vertices = order_vertices(vertices)
    moments = cv2.moments(vertices.astype(np.float32))
    if moments['m00'] <= 0:
        return None
    h, w = image_bgr.shape[:2]
    margin = config.border_margin_px
    touches = bool(np.any((vertices < margin) | (vertices > np.array([w - 1, h - 1]) - margin)))
    return Detection(shape=shape, colour=colour, vertices_px=vertices,
                     centroid_px=np.array([moments['m10'], moments['m01']]) / moments['m00'],
                     area_px=float(moments['m00']), quality=float(np.clip(quality, 0.0, 1.0)),
                     touches_border=touches, contour=(outline + offset).astype(np.int32))


def select_target(detections, shape, colour, image_size):
    """The detection to servo to: of ``shape`` and ``colour`` (None = any), the largest; ties -> most central.

    Areas within 2 % of the largest count as a tie, broken by the distance of the centroid to the
    centre of the image of ``image_size`` = (width, height) pixels. None if nothing matches.
    """
    candidates = [d for d in detections
                  if (shape is None or d.shape == shape) and (colour is None or d.colour == colour)]
    if not candidates:
        return None
    largest = max(d.area_px for d in candidates)
    tied = [d for d in candidates if d.area_px >= (1.0 - _TIE_AREA_FRACTION) * largest]
    centre = (np.asarray(image_size, dtype=float) - 1.0) / 2.0
    return min(tied, key=lambda d: float(np.linalg.norm(d.centroid_px - centre)))


def draw_detections(image_bgr, detections):
    """Copy of ``image_bgr`` with each detection's contour, numbered vertices and ``shape colour`` label."""
    canvas = image_bgr.copy()
    for detection in detections:
        cv2.drawContours(canvas, [detection.contour], -1, (255, 0, 255), 1, cv2.LINE_AA)
        polygon = np.round(detection.vertices_px * 16).astype(np.int32)   # 4 fractional bits
        cv2.polylines(canvas, [polygon], True, (0, 0, 255), 1, cv2.LINE_AA, shift=4)
        for k, (u, v) in enumerate(detection.vertices_px):
            cv2.circle(canvas, (int(round(u * 16)), int(round(v * 16))), 3 * 16, (0, 0, 255), 1, cv2.LINE_AA, shift=4)
            cv2.putText(canvas, str(k), (int(round(u)) + 4, int(round(v)) - 4), cv2.FONT_HERSHEY_SIMPLEX,
                        0.4, (0, 0, 255), 1, cv2.LINE_AA)
        u, v = (int(round(c)) for c in detection.centroid_px)
        cv2.putText(canvas, f'{detection.shape} {detection.colour}', (u - 30, v), cv2.FONT_HERSHEY_SIMPLEX,
                    0.45, (0, 0, 0), 1, cv2.LINE_AA)
    return canvas
