"""Top-face isolation (beyond the thesis): the brightest face, in V of the original image, inside a blob whose
side faces (same hue, darker) joined it in oblique views. Contours (M, 1, 2) int32 in the pixels of the HSV image."""
import functools

import cv2
import numpy as np

_SQUARE3 = np.ones((3, 3), np.uint8)
_SQUARE5 = np.ones((5, 5), np.uint8)
_CROSS3 = cv2.getStructuringElement(cv2.MORPH_CROSS, (3, 3))
_LEVELS = np.arange(256)
_MIN_RIM_SHARE = 0.3       # a face's outline lies at least this much on the blob's outline ...
_RIM_DEPTH_PX = 3.5         # ... its rim, this deep (the face's own edge, blurred into the table, lies 1-2 px in)
_SUPPORT_DIRECTIONS = 32    # _reaches_a_half_turn: directions sampled over the full turn (a multiple of 2) ...
_DIRECTIONS = np.stack([np.cos(np.arange(_SUPPORT_DIRECTIONS) * 2.0 * np.pi / _SUPPORT_DIRECTIONS),
                        np.sin(np.arange(_SUPPORT_DIRECTIONS) * 2.0 * np.pi / _SUPPORT_DIRECTIONS)])   # (2, K)
_HALF_TURNS = (np.arange(_SUPPORT_DIRECTIONS)[:, None]       # ... and the indices of each closed half-turn of them
               + np.arange(_SUPPORT_DIRECTIONS // 2 + 1)) % _SUPPORT_DIRECTIONS
_RIM_SHADE_FRACTION = 0.03  # ... beyond _RIM_DEPTH_PX, this fraction of the face's size: its rounded rim's shaded band
_CONVEX_SOLIDITY = 0.95     # a bright region less solid than this may be two faces (_larger_of_two_faces) ...
_HEXAGON_EPSILONS = (0.02, 0.03, 0.04)   # _larger_of_two_faces: the outline's hexagon at the first of these
#                                         (fractions of its length) that gives one
_MIN_PART_SHARE = 0.1       # ... each face at least this share of the two
# ... and the hexagon's edges (numbered from its reflex corner) parallel in pairs as a cube's are, within this angle:
# the edge from the corner and the one two on (side face), the one before it and three on, one on and four on (top)
_PARALLEL_EDGES = ((0, 2), (5, 3), (1, 4))
_MAX_PARALLEL_DEG = 15.0
_GRADIENT_MIN_PIXELS = 2000  # a blob's interior with no split: from this size (45 px across) again without its V ramp


def isolate_top_face(blob, hsv, config):
    """Outline (M, 1, 2) int32 of the block's top face within the contour ``blob`` (the blob itself if no face
    can be split off).

    ``hsv``: the original image in HSV (uint8, OpenCV scales), in the coordinates of ``blob``. A
    block's faces share its colour; under light from above the table the top face is the most
    brightly lit, so it is the brightest face in V and its side faces are darker. The V of the
    blob's interior (the blob eroded by 2 px, clear of the pixels it shares with the table) is split
    in two by Otsu's threshold; while the split is significant (the classes' means differ by at
    least ``min_contrast`` of the bright one's, and the bright class holds at least
    ``min_face_fraction`` of the interior) the bright class is split again, so that a side face lit
    nearly as brightly as the top goes too. At each level the candidate face is the largest connected
    region of the blob above the threshold whose saturation is at least half the bright interior's
    mean (the pixels a side face shares with the paler but brighter table are as bright as the top, not
    as saturated), its holes filled (pips, a printed label). A split is kept only while its face is a
    face: solid (area / convex-hull area at least ``min_solidity``) and part of the blob's outline (at
    least 30 % of its own outline within 3.5 px of the blob's: whatever the view, the top face's edges with no
    side face below them are silhouette), and reaching the blob's silhouette over a half-turn of directions
    (``_reaches_a_half_turn``: within 3.5 px plus 3 % of the face's size, the shaded band of a rounded rim).
    A specular highlight, a glare, white pips, a lighter patch of grain or the flat middle of a face whose
    rounded rim is shaded lie inside the face and stop the splitting; the last face kept (or the whole blob,
    one face: the lighting gradient across a face changes its V by a few per cent, a face edge by tens) is
    returned. A bright region with a reflex corner that is a cube's top and one side face lit alike (a hexagon,
    ``_larger_of_two_faces``) is cut along their shared edge, and its larger part is the last face. A blob of at
    least ``_GRADIENT_MIN_PIXELS`` interior pixels where no split holds is tried once more
    with its V's linear gradient taken out (``_without_gradient``): on a close block vignetting and the light's
    fall-off change the top face's V as much as a side face lit almost as well differs from it.
    """
    x, y, w, h = cv2.boundingRect(blob)
    box = (slice(y, y + h), slice(x, x + w))
    inside = np.zeros((h, w), np.uint8)
    cv2.drawContours(inside, [blob], -1, 255, cv2.FILLED, offset=(-x, -y))
    value, saturation = hsv[box][..., 2].copy(), hsv[box][..., 1].copy()
    interior = cv2.erode(inside, _SQUARE5, borderType=cv2.BORDER_CONSTANT, borderValue=0)    # eroded by 2 px
    rim = _rim(inside)
    rim_share = functools.partial(_rim_share, rim=rim, unknown=_on_the_frame(hsv.shape[:2], (x, y, w, h)))
    face = _split_off_sides(blob, value, saturation, inside, interior, rim_share, (x, y), config)
    if face is None and cv2.countNonZero(interior) >= _GRADIENT_MIN_PIXELS:
        face = _split_off_sides(blob, _without_gradient(value, interior), saturation, inside, interior, rim_share,
                                (x, y), config)
    return blob if face is None else face


def _split_off_sides(blob, value, saturation, inside, interior, rim_share, origin, config):
    """The top face's outline (full-image contour) split off ``blob`` by ``isolate_top_face``'s rules on the crop's
    V ``value``, or None when no split holds."""
    x, y = origin
    values = value[interior > 0]
    histogram = np.bincount(values, minlength=256)       # of ``values``: the class means without indexing them
    minimum_count = max(config.min_face_fraction * len(values), 1)
    face = blob_hull = None
    while len(values) >= 2:
        cut, _ = cv2.threshold(values, 0, 255, cv2.THRESH_BINARY | cv2.THRESH_OTSU)
        split = int(cut) + 1
        bright_count = int(histogram[split:].sum())
        if bright_count < minimum_count or bright_count == len(values):
            break
        bright_mean = float(histogram[split:] @ _LEVELS[split:]) / bright_count
        dark_mean = float(histogram[:split] @ _LEVELS[:split]) / (len(values) - bright_count)
        if bright_mean - dark_mean < config.min_contrast * bright_mean:
            break
        region = _bright_region(value, saturation, inside, interior, cut)
        if region is None or rim_share(region) < _MIN_RIM_SHARE:
            break                  # a highlight, pips or a label inside the face, not a face: stop splitting
        outline, area, hull = _outline(region, (x, y))
        hull_area = cv2.contourArea(hull)
        top = None
        if area < _CONVEX_SOLIDITY * hull_area:     # a reflex corner: two faces lit alike, or no face
            top = _larger_of_two_faces(region, outline - (x, y), config)
        if top is not None:
            if rim_share(top) < _MIN_RIM_SHARE:
                break
            outline, area, hull = _outline(top, (x, y))
        elif area < config.min_solidity * hull_area:
            break                  # not a face's shape (a split along shading or marks): keep the previous one
        blob_hull = cv2.convexHull(blob) if blob_hull is None else blob_hull
        if not _reaches_a_half_turn(hull, blob_hull, _RIM_DEPTH_PX + _RIM_SHADE_FRACTION * np.sqrt(area)):
            break                  # blob all around it: a highlight, glare or the shaded rim of the face, not a side
        face, values = outline, values[values > cut]
        if top is not None:
            break                  # the two faces' split is the last one
        histogram[:split] = 0
    return face


def _outline(region, origin):
    """(outline (M, 1, 2) int32 of the largest part of the mask ``region``, moved by ``origin``; its area; hull)."""
    contours, _ = cv2.findContours(region, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE, offset=origin)
    outline = max(contours, key=cv2.contourArea)
    return outline, cv2.contourArea(outline), cv2.convexHull(outline)


def _larger_of_two_faces(region, outline, config):
    """The larger face (mask) of the bright ``region`` (mask, crop px; ``outline`` its contour) when it is two
    faces of a block lit alike, else None: seen from a corner, a cube's top face and one side face joined make a
    hexagon with one reflex corner (where the third, darker face meets them); the edge they share runs from it to
    the opposite corner. Cut along that edge, both parts must be solid (``config.min_solidity``) and each at least
    ``_MIN_PART_SHARE`` of the region. The larger part is the top face: a camera looking down within 45 deg of a
    cube's top sees it larger than any side face (their V, lit alike, does not tell them apart)."""
    length = cv2.arcLength(outline, True)
    polygon = next((p for p in (cv2.approxPolyDP(outline, e * length, True).reshape(-1, 2) for e in _HEXAGON_EPSILONS)
                    if len(p) == 6), None)
    if polygon is None:
        return None
    incoming, outgoing = polygon - np.roll(polygon, 1, axis=0), np.roll(polygon, -1, axis=0) - polygon
    turns = incoming[:, 0] * outgoing[:, 1] - incoming[:, 1] * outgoing[:, 0]
    reflex = np.flatnonzero(np.sign(turns) != np.sign(turns.sum()))
    if len(reflex) != 1:
        return None
    corner = int(reflex[0])
    edges = np.roll(outgoing, -corner, axis=0).astype(np.float64)      # edges[k]: from the hexagon's corner + k
    if max(_angle_deg(edges[a], edges[b]) for a, b in _PARALLEL_EDGES) > _MAX_PARALLEL_DEG:
        return None                # not two parallelograms sharing an edge: a face with a notch (a shadow's corner)
    parts = region.copy()
    # one 8-connected pixel wide: it parts the region's 4-connected components and takes the least off the top face
    cv2.line(parts, tuple(int(c) for c in polygon[corner]), tuple(int(c) for c in polygon[(corner + 3) % 6]), 0, 1)
    count, labels, stats, _ = cv2.connectedComponentsWithStats(parts, connectivity=4)
    if count < 3:
        return None
    total = cv2.countNonZero(region)
    faces = []
    for label in 1 + np.argsort(stats[1:, cv2.CC_STAT_AREA])[::-1][:2]:
        mask = np.where(labels == label, 255, 0).astype(np.uint8)
        _, area, hull = _outline(mask, (0, 0))
        if area < _MIN_PART_SHARE * total or area < config.min_solidity * cv2.contourArea(hull):
            return None
        faces.append(mask)
    return faces[0]


def _reaches_a_half_turn(face, blob, depth_px):
    """True when the contour ``face`` reaches the contour ``blob``'s silhouette, within ``depth_px``, over a
    half-turn of directions: its support ``h_F(v) = max over its points of p . v`` (px) is within that depth of
    the blob's, ``h_B(v)``, for every unit ``v`` of some 180 deg arc (``_SUPPORT_DIRECTIONS`` sampled).

    A block's silhouette is the hull of its top face F and its bottom face B (the side faces lie between them);
    B is F moved by the projected height ``t`` and, farther from the camera, no larger (a homothety ``s F + t``,
    0 < s <= 1, about a point of F): ``h_B(v) = s h_F(v) + t . v <= h_F(v)`` wherever ``t . v <= 0``, a half-turn
    at least. So wherever the side faces are, F is silhouette on the other half-turn. A bright patch inside the
    face (a specular highlight, a glare, the flat part of a face whose rounded rim is shaded) has blob beyond it
    in every direction.
    """
    gap = _support(blob) - _support(face)
    return bool(gap[_HALF_TURNS].max(axis=1).min() <= depth_px)


def _support(contour):
    """(K,) support function (px) of the points of ``contour`` (M, 1, 2) along ``_DIRECTIONS`` (element-wise: as a
    matrix product it goes through BLAS, whose threads can take longer to wake than the product takes)."""
    points = contour.reshape(-1, 2).astype(np.float64)
    return (points[:, :1] * _DIRECTIONS[0] + points[:, 1:] * _DIRECTIONS[1]).max(axis=0)


def _without_gradient(value, interior):
    """``value`` (uint8, the crop's V) less the linear gradient fitted over the ``interior`` pixels (least squares,
    then twice more without the pixels darker than the fit by more than the residuals' spread: side faces), its
    mean level kept. Vignetting and the light's fall-off brighten a close block's top face from one side to the
    other by as much as a side face lit almost as well differs from it (15 % over 100 px): Otsu's threshold then
    cuts the top face along the gradient, and the side face stays in the polygon."""
    rows, columns = np.nonzero(interior[::2, ::2])          # every 2nd pixel each way: a plane needs no more
    rows, columns = 2 * rows, 2 * columns
    samples = value[rows, columns].astype(np.float64)
    du, dv = columns - columns.mean(), rows - rows.mean()
    keep = np.ones(len(rows))
    for _ in range(3):      # weighted normal equations (weights 0 / 1, centred columns: well conditioned)
        ku, kv, count = keep * du, keep * dv, keep.sum()
        normal = np.array([[count, ku.sum(), kv.sum()], [0.0, ku @ du, ku @ dv], [0.0, 0.0, kv @ dv]])
        normal += np.triu(normal, 1).T
        try:
            coefficients = np.linalg.solve(normal, np.array([keep @ samples, ku @ samples, kv @ samples]))
        except np.linalg.LinAlgError:      # the kept pixels on one line: no gradient to take out
            return value
        residual = samples - coefficients[0] - coefficients[1] * du - coefficients[2] * dv
        kept_residual = keep * residual
        spread = np.sqrt(max(kept_residual @ residual / count - (kept_residual.sum() / count) ** 2, 0.0))
        keep = (residual > -spread).astype(np.float64)
    h, w = value.shape
    trend = (coefficients[1] * (np.arange(w) - columns.mean())[None, :]
             + coefficients[2] * (np.arange(h) - rows.mean())[:, None])
    return np.clip(value - trend + 0.5, 0, 255).astype(np.uint8)


def _angle_deg(a, b):
    """Angle (deg, 0-90) between the lines along the 2-vectors ``a`` and ``b``."""
    cosine = abs(a @ b) / max(np.sqrt((a @ a) * (b @ b)), 1e-12)
    return float(np.degrees(np.arccos(min(cosine, 1.0))))


def _rim(inside):
    """uint8 mask of the pixels of ``inside`` within ``_RIM_DEPTH_PX`` (3.5) of the nearest pixel outside it, the
    crop's border counting as outside, in the chamfer metric of OpenCV's 3x3 L2 distance transform (steps 0.955 and
    1.3693): the offsets within 3.5 of a pixel are a diamond of radius 2 grown by a 3x3 square, so the pixels deeper
    than that are the erosion by a cross twice and a square once (the same pixels as the transform's, at a tenth of
    its time on a 250 px blob)."""
    deep = cv2.erode(inside, _CROSS3, borderType=cv2.BORDER_CONSTANT, borderValue=0, iterations=2)
    return cv2.subtract(inside, cv2.erode(deep, _SQUARE3, borderType=cv2.BORDER_CONSTANT, borderValue=0))


def _bright_region(value, saturation, inside, interior, threshold):
    """uint8 mask of the largest connected region of the blob ``inside`` brighter than ``threshold`` and at
    least half as saturated as the bright interior, its holes filled; None if there is none."""
    _, bright = cv2.threshold(value, threshold, 255, cv2.THRESH_BINARY)
    top_saturation = cv2.mean(saturation, cv2.bitwise_and(bright, interior))[0]
    _, saturated = cv2.threshold(saturation, 0.5 * top_saturation, 255, cv2.THRESH_BINARY)
    top = cv2.bitwise_and(cv2.bitwise_and(bright, saturated), inside)
    contours, _ = cv2.findContours(top, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
    if not contours:
        return None
    region = np.zeros_like(inside)
    cv2.drawContours(region, [max(contours, key=cv2.contourArea)], -1, 255, cv2.FILLED)
    return region


def _rim_share(region, rim, unknown):
    """Fraction of the outline pixels of ``region`` that lie on the blob's ``rim``: a top face is part of the
    block's silhouette (whatever the view, at least the edges with no side face below them), a highlight, a
    pip or a printed mark lies inside it. The crop's border is outside (the blob touches it), but its pixels on
    the image's border (``unknown``) are not counted: the block may go on beyond it."""
    outline = cv2.subtract(region, cv2.erode(region, _SQUARE3, borderType=cv2.BORDER_CONSTANT, borderValue=0))
    outline = cv2.subtract(outline, unknown)
    count = cv2.countNonZero(outline)
    return cv2.countNonZero(cv2.bitwise_and(outline, rim)) / count if count else 0.0


def _on_the_frame(image_shape, box):
    """uint8 mask (the ``box`` = (x, y, w, h) crop's size) of its rows and columns on the border of an image of
    ``image_shape`` (h, w)."""
    x, y, w, h = box
    mask = np.zeros((h, w), np.uint8)
    if x == 0:
        mask[:, 0] = 255
    if y == 0:
        mask[0, :] = 255
    if x + w == image_shape[1]:
        mask[:, -1] = 255
    if y + h == image_shape[0]:
        mask[-1, :] = 255
    return mask
