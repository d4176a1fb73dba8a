"""Detection: a BGR uint8 image in -> the polygons (``Detection``) of the configured colours out, the stages of
``colour``, ``topface``, ``polygon`` and ``subpixel`` composed; the search regions; the target's choice; drawing.
Pixels (u, v) = (column, row) of the raw (distorted) image, origin at the centre of the top-left pixel."""
import dataclasses
import math
from dataclasses import dataclass
from typing import Optional

import cv2
import numpy as np

from baxter_pnp.models import SHAPES
from baxter_pnp.vision import chroma
from baxter_pnp.vision.colour import (colour_mask, dynamic_threshold, find_blobs, laplacian_sharpen, open_close,
                                      oversaturated_hsv)
from baxter_pnp.vision.polygon import (approximate_polygon, classify_shape, fit_polygon_sides, hull_polygon,
                                       looks_round, merge_close_vertices, order_vertices, remove_cut_corners,
                                       remove_flat_vertices, shape_harmonics)
from baxter_pnp.vision.sideface import cut_side_faces
from baxter_pnp.vision.subpixel import refine_vertices
from baxter_pnp.vision.topface import isolate_top_face

_TIE_AREA_FRACTION = 0.02   # select_target: areas within 2 % of the largest count as a tie
_RING_INNER = np.ones((5, 5), np.uint8)     # _with_weak_detections: a blob's colour is compared with a ring
_RING_OUTER = np.ones((13, 13), np.uint8)   # 3-6 px around it (between dilations by these kernels)
_SQUARE3 = np.ones((3, 3), np.uint8)        # stands_out: the band 1-5 px inside the polygon, between erosions
_BAND_INNER = np.ones((11, 11), np.uint8)   # by these kernels; its box reaches the ring's outer edge
_RING_REACH_PX = 7


@dataclass
class Detection:
    """A polygon of one colour found in the image (pixels of the raw, distorted image).

    ``vertices_px`` (n, 2) ordered by increasing ``atan2(v - vc, u - uc)``; ``centroid_px`` (2,) and
    ``area_px`` (px^2) of that polygon; ``quality`` in 0..1 (1 = clean, convex polygon whose edges fit
    straight lines); ``touches_border``: a vertex within ``border_margin_px`` of the image border;
    ``contour`` (M, 1, 2) int32: the outline used (the top face), for drawing; ``blob_contour``: the whole blob's
    outline when the top face was split off it (else None), for ``blob_detection`` when the face's polygon has
    no pose (a shadow's edge across the face taken for a side face's).
    """
    shape: str
    colour: str
    vertices_px: np.ndarray
    centroid_px: np.ndarray
    area_px: float
    quality: float
    touches_border: bool
    contour: np.ndarray
    blob_contour: Optional[np.ndarray] = None


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
    unknown = [c for c in colours if c not in config.colour_names()]
    if unknown:
        raise ValueError(f'detect: unknown colour(s) {unknown}; configured: {config.colour_names()}')
    shapes = set(SHAPES) if shapes is None else set(shapes)
    if not shapes <= set(SHAPES):
        raise ValueError(f'detect: unknown shape(s) {sorted(shapes - set(SHAPES))}; known: {sorted(SHAPES)}')
    segmenter = ColourSegmenter(config, colours)
    if config.roi.enabled:
        regions = _candidate_regions(image_bgr, segmenter, config)
    else:
        segmenter.adapt(_subsampled(image_bgr, config.roi.downsample))     # the same adaptation as with the ROI
        regions = [((0, 0, image_bgr.shape[1], image_bgr.shape[0]), {colour: math.inf for colour in colours})]
    detections = []
    for region, region_colours in regions:
        detections.extend(_detect_in_region(image_bgr, region, segmenter, region_colours, shapes, config))
    detections.sort(key=lambda d: -d.area_px)
    return detections


class ColourSegmenter:
    """The colour stage of the configured pipeline: per-image adaptation, then binary masks of image regions.

    ``thesis``: eq. 3.14's dynamic saturation threshold (``adapt``) and Algorithm 1's over-saturated HSV
    ranges; ``chroma``: white-balance gains (``adapt``) and CIELAB colour classes (``vision.chroma``).
    """

    def __init__(self, config, colours):
        self.config = config
        self.colours = list(colours)
        self._threshold = None
        self._gains = None
        self._extra_chroma = 0.0

    def adapt(self, image_bgr):
        """Take the image-wide quantities (threshold or white balance) from ``image_bgr`` (any scale)."""
        if self.config.pipeline == 'chroma':
            self._gains, cast = chroma.white_balance(image_bgr, self.config.chroma)
            self._extra_chroma = max(0.0, cast - self.config.chroma.max_residual_cast)
        else:
            self._threshold = dynamic_threshold(cv2.cvtColor(image_bgr, cv2.COLOR_BGR2HSV), self.config)

    @property
    def balanced(self):
        """True when the white balance left no cast beyond ``max_residual_cast`` (chroma pipeline, once adapted)."""
        return self._extra_chroma == 0.0

    @property
    def weak_tier(self):
        """True when ``_with_weak_detections`` runs: the chroma pipeline, its weaker floor on, the image balanced."""
        return self.config.pipeline == 'chroma' and self.config.chroma.weak_floor_fraction < 1.0 and self.balanced

    def lab(self, image_bgr):
        """``image_bgr`` (a region of the adapted image) white-balanced, in 8-bit CIELAB (chroma pipeline)."""
        return chroma.balanced_lab(image_bgr, self._gains)

    def masks(self, image_bgr, colours=None, floor_fraction=1.0, lab=None):
        """{colour: uint8 mask (255 inside)} of ``image_bgr`` (a region of the adapted image) for ``colours``
        (chroma floors times ``floor_fraction``); ``lab``: its ``lab(image_bgr)``, if at hand."""
        colours = self.colours if colours is None else [c for c in self.colours if c in colours]
        if self.config.pipeline == 'chroma':
            return chroma.class_masks(self.lab(image_bgr) if lab is None else lab,
                                      {c: self.config.chroma.classes[c] for c in colours}, self._extra_chroma,
                                      floor_fraction)
        oversaturated = oversaturated_hsv(cv2.cvtColor(image_bgr, cv2.COLOR_BGR2HSV), self._threshold, self.config)
        return {c: colour_mask(oversaturated, self.config.colours[c]) for c in colours}


def _candidate_regions(image_bgr, segmenter, config):
    """The regions ``((x0, y0, x1, y1), {colour: blob count})`` to search, ``segmenter`` adapted to the image on the
    way.

    Runs the colour stage on the image subsampled by ``roi.downsample`` (nearest pixel; at the weaker floor when
    ``segmenter.weak_tier``); each blob of a colour gives a box padded by ``roi.padding_px``; overlapping boxes are
    merged (their colours' blob counts added) so that every blob lies whole inside exactly one region.
    """
    f = config.roi.downsample
    h, w = image_bgr.shape[:2]
    small = _subsampled(image_bgr, f)
    segmenter.adapt(small)
    pad = config.roi.padding_px
    boxes = []
    floor_fraction = config.chroma.weak_floor_fraction if segmenter.weak_tier else 1.0
    for colour, mask in segmenter.masks(small, floor_fraction=floor_fraction).items():
        if not cv2.countNonZero(mask):
            continue
        _, _, stats, _ = cv2.connectedComponentsWithStats(mask, connectivity=8)
        for x, y, bw, bh, area in stats[1:]:
            if area * f * f >= 0.25 * config.min_area_px:
                boxes.append(((max(0, x * f - pad), max(0, y * f - pad),
                               min(w, (x + bw) * f + pad), min(h, (y + bh) * f + pad)), {colour: 1}))
    return _merge_boxes(boxes)


def _subsampled(image_bgr, factor):
    """``image_bgr`` subsampled by ``factor`` (nearest pixel), at least 1x1."""
    h, w = image_bgr.shape[:2]
    return cv2.resize(image_bgr, (max(1, w // factor), max(1, h // factor)), interpolation=cv2.INTER_NEAREST)


def _merge_boxes(boxes):
    """Union of overlapping ``((x0, y0, x1, y1), {colour: count})`` boxes (their counts added) until none overlap."""
    boxes = list(boxes)
    merged = True
    while merged:
        merged = False
        for i in range(len(boxes)):
            for j in range(i + 1, len(boxes)):
                (a, colours_a), (b, colours_b) = boxes[i], boxes[j]
                if a[0] < b[2] and b[0] < a[2] and a[1] < b[3] and b[1] < a[3]:
                    boxes[i] = ((min(a[0], b[0]), min(a[1], b[1]), max(a[2], b[2]), max(a[3], b[3])),
                                {c: colours_a.get(c, 0) + colours_b.get(c, 0) for c in {**colours_a, **colours_b}})
                    del boxes[j]
                    merged = True
                    break
            if merged:
                break
    return boxes


def _detect_in_region(image_bgr, region, segmenter, colours, shapes, config):
    """Detections of ``colours`` whose blobs lie in ``region`` = (x0, y0, x1, y1) of the full image; ``colours``:
    {colour: the candidate search's blobs of it in the region (inf: not counted)}. The weaker floor runs for a colour
    with fewer good detections than blobs (``_with_weak_detections``: a dim block beside one the floor found)."""
    x0, y0, x1, y1 = region
    crop = image_bgr[y0:y1, x0:x1]
    hsv = cv2.cvtColor(crop, cv2.COLOR_BGR2HSV)
    offset = np.array([x0, y0])
    detections = []
    discs = []
    lab = segmenter.lab(crop) if config.pipeline == 'chroma' else None
    for colour, raw_mask in segmenter.masks(crop, colours, lab=lab).items():
        if not cv2.countNonZero(raw_mask):
            continue
        mask = open_close(raw_mask, config.morphology_kernel_px)
        binary = laplacian_sharpen(mask) if config.laplacian_sharpening else mask
        for blob in find_blobs(binary, config.min_blob_area_px):
            detection = _blob_polygon(image_bgr, blob, offset, colour, config, hsv, shapes, discs)
            if detection is None or (config.pipeline == 'chroma' and (
                    colour_fill(raw_mask, detection.vertices_px - offset) < config.chroma.min_fill
                    or not stands_out(lab, detection, offset, config.chroma))):
                continue
            detections.append(detection)
    if segmenter.weak_tier:      # the weaker floor for the blobs where the class's own found nothing good
        for colour in [c for c in segmenter.colours if c in colours]:
            good = sum(d.colour == colour and d.quality >= config.chroma.weak_min_quality for d in detections)
            if good < colours[colour]:
                detections = _with_weak_detections(image_bgr, lab, colour, offset, hsv, detections, discs, shapes,
                                                   config)
    return detections


def _with_weak_detections(image_bgr, lab, colour, offset, hsv, found, discs, shapes, config):
    """``found`` (the region's detections) with those of ``colour`` at the weaker floor: a face too dim for its
    class's floor (a dark die on a dark table) is segmented at ``weak_floor_fraction`` of it (``ChromaConfig``).

    A blob of that weaker mask counts when it holds no detection of ``colour`` of ``weak_min_quality`` (a face the
    class's floor found; a dim block beside it is a blob of its own), overlaps no detection of another colour, no
    refused disc (``discs``, region coordinates) and only detections of ``colour`` of lower quality (the fragments
    of a face the floor cut up), which it then replaces; when its median chroma along the class's hue exceeds that
    of a ring 3-6 px around it by ``weak_min_contrast`` (a dim block on a grey table stands 16-27 above it; the
    tinted black print and chessboard squares of the real frames 2-14 above theirs); when its polygon has
    ``weak_min_quality`` (cables, tinted shadows: 0.08-0.34), the usual colour fill on the weaker mask and stands
    out (``stands_out``). ``lab``: the region's balanced CIELAB image (``ColourSegmenter.lab``); ``hsv``: its HSV;
    ``offset``: its origin in the image."""
    colour_class = config.chroma.classes[colour]
    weak = chroma.class_masks(lab, {colour: colour_class}, floor_fraction=config.chroma.weak_floor_fraction)[colour]
    if not cv2.countNonZero(weak):
        return found
    claimed = np.zeros(weak.shape, np.uint8)
    cv2.drawContours(claimed, discs, -1, 255, cv2.FILLED)
    for d in found:
        if d.colour != colour:
            cv2.fillPoly(claimed, [np.round(d.vertices_px - offset).astype(np.int32)], 255)
    mask = open_close(weak, config.morphology_kernel_px)
    binary = laplacian_sharpen(mask) if config.laplacian_sharpening else mask
    good = [tuple(map(float, d.centroid_px - offset)) for d in found
            if d.colour == colour and d.quality >= config.chroma.weak_min_quality]
    for blob in find_blobs(binary, config.min_blob_area_px):
        if any(cv2.pointPolygonTest(blob, centre, False) >= 0 for centre in good):
            continue
        inside = np.zeros(weak.shape, np.uint8)
        cv2.drawContours(inside, [blob], -1, 255, cv2.FILLED)
        if cv2.countNonZero(cv2.bitwise_and(inside, claimed)):
            continue
        fragments = [d for d in found if d.colour == colour and inside[_pixel(d.centroid_px - offset, inside)]]
        around = cv2.subtract(cv2.dilate(inside, _RING_OUTER), cv2.dilate(inside, _RING_INNER))
        if chroma.hue_contrast(lab, inside, around, colour_class.hue_deg) < config.chroma.weak_min_contrast:
            continue
        detection = _blob_polygon(image_bgr, blob, offset, colour, config, hsv, shapes)
        least_quality = max([config.chroma.weak_min_quality] + [d.quality for d in fragments])
        if (detection is None or detection.quality < least_quality
                or colour_fill(weak, detection.vertices_px - offset) < config.chroma.min_fill
                or not stands_out(lab, detection, offset, config.chroma)):
            continue
        found = [d for d in found if all(d is not f for f in fragments)] + [detection]
    return found


def _blob_polygon(image_bgr, blob, offset, colour, config, hsv, shapes, discs=None):
    """The detection of ``blob`` (a contour in the region whose origin is ``offset`` and whose HSV is ``hsv``): its
    top face's polygon (``_polygon_detection``), with the blob's outline when the face was split off it; None when
    there is none, its shape is not in ``shapes``, or the blob is under ``min_area_px`` and no triangle of
    ``min_triangle_quality`` (blobs from ``min_triangle_area_px`` are looked at: a 15 px triangle's)."""
    outline = isolate_top_face(blob, hsv, config.top_face) if config.top_face.enabled else blob
    detection = _polygon_detection(image_bgr, outline, offset, colour, config, hsv[..., 2], discs)
    if (detection is None or detection.shape not in shapes
            or (cv2.contourArea(blob) < config.min_area_px
                and (detection.shape != 'triangle' or detection.quality < config.min_triangle_quality))):
        return None
    if outline is not blob:
        detection = dataclasses.replace(detection, blob_contour=(blob + offset).astype(np.int32))
    return detection


def _pixel(point_px, image):
    """(row, column) of the pixel of ``image`` nearest ``point_px`` (u, v), clipped to the image."""
    h, w = image.shape[:2]
    return min(max(int(round(point_px[1])), 0), h - 1), min(max(int(round(point_px[0])), 0), w - 1)


def blob_detection(image_bgr, detection, config, shape=None):
    """The detection of the whole blob ``detection`` was split from (its ``blob_contour``: top face and side faces
    together, as the thesis's pipeline sees a block), or None when there was no split or the blob is no ``shape``
    polygon (default: ``detection``'s shape). A fallback for when the top face's polygon gets no pose or has
    another shape: a shadow across the top face makes its lit part look like the top face and the rest like a
    side face."""
    if detection.blob_contour is None:
        return None
    whole = _polygon_detection(image_bgr, detection.blob_contour, np.zeros(2, int), detection.colour, config)
    return whole if whole is not None and whole.shape == (shape or detection.shape) else None


def _off_the_border(contour, offset, image_shape):
    """The points (M', 1, 2) of ``contour`` (region coordinates, region origin ``offset``) not on the border of the
    image of ``image_shape``: where a blob is cut by the border, the border is not its outline."""
    points = contour.reshape(-1, 2) + offset
    h, w = image_shape[:2]
    inside = (points[:, 0] > 0) & (points[:, 1] > 0) & (points[:, 0] < w - 1) & (points[:, 1] < h - 1)
    return contour if inside.all() else contour[inside]


def stands_out(lab, detection, offset, config):
    """True when ``detection`` stands out from its surroundings in the 8-bit CIELAB image ``lab`` (a region whose
    origin is ``offset`` in the image; ``config``: ``ChromaConfig``): along its outline, the median chroma along its
    class's hue of a band 1-5 px inside it exceeds that of a ring 3-6 px outside it by ``surround_min_contrast``
    times the class's chroma floor, and, unless it touches the image border, at most ``surround_max_share`` of the
    ring reaches ``surround_share_floor`` of that floor. A block on the table is an island of its colour (whatever
    the view, its side faces lie along at most about half its outline, as in ``topface._reaches_a_half_turn``; a
    block cut by the border may show only them); a polygon cut out of a larger area of the colour (a threshold's
    contour across a button's cap, a tinted print, a glow) has the colour beyond it too (docs/perception.md,
    "Fragments of larger coloured areas")."""
    if config.surround_min_contrast == 0.0 and config.surround_max_share == 1.0:
        return True
    vertices_px = detection.vertices_px - offset
    h, w = lab.shape[:2]
    x0, y0 = np.maximum(np.floor(vertices_px.min(axis=0)).astype(int) - _RING_REACH_PX, 0)
    x1, y1 = np.minimum(np.ceil(vertices_px.max(axis=0)).astype(int) + _RING_REACH_PX + 1, (w, h))
    box = lab[y0:y1, x0:x1]
    inside = np.zeros(box.shape[:2], np.uint8)
    cv2.fillPoly(inside, [np.round((vertices_px - (x0, y0)) * 16).astype(np.int32)], 255, cv2.LINE_8, shift=4)
    around = cv2.subtract(cv2.dilate(inside, _RING_OUTER), cv2.dilate(inside, _RING_INNER))
    band = cv2.subtract(cv2.erode(inside, _SQUARE3), cv2.erode(inside, _BAND_INNER))
    colour_class = config.classes[detection.colour]
    along = chroma.along_hue_image(box, colour_class.hue_deg)
    ring = cv2.calcHist([along], [0], around, [256], [0, 256]).ravel()
    if not ring.sum():
        return True          # nothing around it to compare with (the polygon fills the image)
    edge = cv2.calcHist([along], [0], band, [256], [0, 256]).ravel()
    contrast = _histogram_median(edge) - _histogram_median(ring)
    if contrast < config.surround_min_contrast * colour_class.min_chroma:
        return False
    return detection.touches_border or (
        ring[128 + math.ceil(config.surround_share_floor * colour_class.min_chroma):].sum()
        <= config.surround_max_share * ring.sum())


def _histogram_median(histogram):
    """The median bin (its index) of a non-empty (256,) histogram; 0 if it is empty."""
    cumulative = np.cumsum(histogram)
    return int(np.searchsorted(cumulative, 0.5 * cumulative[-1])) if cumulative[-1] else 0


def colour_fill(mask, vertices_px):
    """Fraction of the polygon ``vertices_px`` (n, 2), shrunk by one pixel, that ``mask`` covers (0 if empty)."""
    inside = np.zeros(mask.shape, np.uint8)
    cv2.fillPoly(inside, [np.round(vertices_px * 16).astype(np.int32)], 255, cv2.LINE_8, shift=4)
    inside = cv2.erode(inside, np.ones((3, 3), np.uint8))
    total = cv2.countNonZero(inside)
    return cv2.countNonZero(cv2.bitwise_and(mask, inside)) / total if total else 0.0


def _polygon_detection(image_bgr, outline, offset, colour, config, value=None, discs=None):
    """Detection of the top-face ``outline`` (contour in region coordinates, ``offset`` = region origin), or None;
    ``value``: the region's V (HSV), if at hand (``sideface.cut_side_faces``).

    With the chroma pipeline a disc (``looks_round``, on the outline off the image border) is None, unless the
    outline's harmonics say it has corners (``_harmonics``, ``harmonic_shape.min_strength``); it is judged on the
    polygon before the corners that ``cut_corner_clear_area_fraction`` restores are (a disc's pentagon would become
    a square). A polygon up to ``harmonic_shape.max_size_px`` takes the harmonics' vertex count where they are
    believed (the hull reduced to it, ``polygon.hull_polygon``). ``quality`` = solidity of the outline x exp(-edge
    RMS / ``max_rms_px``) x (1 - fallbacks / (2 n)). A polygon cut by the image border with no edge of its own along
    a straight image edge (the sub-pixel stage's line within ``border_edge_max_rms_px``) is None: its straight side
    is the border's, nothing says it is a block's (a button cut by the border, docs/perception.md "Border-cut
    fragments"). A coarse polygon narrower than ``min_aspect`` (``_aspect``) is None: a sliver of tape or of a
    board's edge.
    """
    hull = cv2.convexHull(outline)
    coarse = approximate_polygon(hull, config.approx_epsilon_fraction)
    coarse = merge_close_vertices(coarse, config.merge_distance_fraction * cv2.arcLength(hull, True))
    coarse = remove_cut_corners(coarse, config.cut_corner_area_fraction)
    coarse = remove_flat_vertices(coarse, config.flat_vertex_area_fraction)
    harmonics = _harmonics(outline, hull, offset, image_bgr.shape, config.harmonic_shape)
    if (config.pipeline == 'chroma' and looks_round(_off_the_border(outline, offset, image_bgr.shape), coarse)
            and (harmonics is None or harmonics.strength < config.harmonic_shape.min_strength)):
        if discs is not None:
            discs.append(outline)
        return None
    coarse = remove_cut_corners(coarse, config.cut_corner_area_fraction, config.cut_corner_clear_area_fraction,
                                config.cut_corner_clear_max_size_px)
    if harmonics is not None and harmonics.count != len(coarse):
        coarse = hull_polygon(hull, harmonics.count)
    shape = classify_shape(len(coarse))
    if shape is None or _aspect(coarse) < config.min_aspect:
        return None
    coarse = fit_polygon_sides(outline, coarse) + offset
    if config.side_face_cut.enabled:
        coarse = cut_side_faces(image_bgr, coarse, config.side_face_cut, value, offset)
    solidity = cv2.contourArea(outline) / max(cv2.contourArea(hull), 1e-9)
    h, w = image_bgr.shape[:2]
    margin = config.border_margin_px
    if config.subpixel.enabled:
        vertices, rms, fallbacks, straightest = refine_vertices(image_bgr, coarse, config.subpixel)
        fit = math.exp(-rms / config.subpixel.max_rms_px) if np.isfinite(rms) else 0.5
        quality = solidity * fit * (1.0 - 0.5 * fallbacks / len(coarse))
    else:
        vertices, quality, straightest = coarse, solidity, 0.0
    touches = bool(np.any((vertices < margin) | (vertices > np.array([w - 1, h - 1]) - margin)))
    if touches and not straightest <= config.border_edge_max_rms_px:
        return None
    vertices = order_vertices(vertices)
    moments = cv2.moments(vertices.astype(np.float32))
    if moments['m00'] <= 0:
        return None
    return Detection(shape=shape, colour=colour, vertices_px=vertices,
                     centroid_px=np.array([moments['m10'], moments['m01']]) / moments['m00'],
                     area_px=float(moments['m00']), quality=float(np.clip(quality, 0.0, 1.0)),
                     touches_border=touches, contour=(outline + offset).astype(np.int32))


def _harmonics(outline, hull, offset, image_shape, config):
    """The outline's ``polygon.Harmonics`` when they are to be believed (``HarmonicShapeConfig``): harmonic_shape on,
    the ``hull`` at most ``max_size_px``, the outline not cut by the image border (the border is no part of it), a
    ``min_margin`` over the runner-up; else None. They then count the polygon's vertices and, at ``min_strength``,
    overrule the disc test."""
    if (not config.enabled or cv2.contourArea(hull) > config.max_size_px ** 2
            or _off_the_border(outline, offset, image_shape) is not outline):
        return None
    harmonics = shape_harmonics(outline)
    return harmonics if harmonics.count is not None and harmonics.margin >= config.min_margin else None


def _aspect(polygon):
    """Short over long side of the least-area rectangle around ``polygon`` (n, 1, 2) or (n, 2) (0 for a degenerate
    one): 0.87-1 for a regular polygon seen along its normal, times the cosine of the angle off it."""
    (_, _), (width, height), _ = cv2.minAreaRect(np.asarray(polygon, np.float32).reshape(-1, 2))
    return min(width, height) / max(width, height) if max(width, height) > 0 else 0.0


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
