"""Sub-pixel vertices (beyond the thesis): each edge of a coarse polygon re-measured on the original BGR image
along its normal, lines fitted to the edge points, consecutive lines intersected. Pixels (u, v) = (column, row)
of the full image, origin at the centre of the top-left pixel; offsets in pixels along the outward edge normal."""
import cv2
import numpy as np

from baxter_pnp.vision.polygon import intersect_lines

_TABLE_LIKE = 0.8              # _edge_crossings: a far colour this close to the most table-like one is the table
_MIN_TABLE_UNLIKENESS = 0.2    # ... and none is unless its part orthogonal to the top's colour is this large
_sum = np.add.reduce   # sum along an axis, without ndarray.sum's Python wrapper (hot loops on tiny arrays)


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

    Returns ``(vertices (n, 2), rms_px, fallback_count, straightest_px)`` of the last pass: ``rms_px`` is
    the RMS distance of the edge points to their lines over the fitted edges (NaN if none), ``straightest_px``
    the least RMS of one edge's points to its line over the edges with a line, whatever its RMS (NaN if none).
    """
    coarse = np.asarray(coarse_px, dtype=float).reshape(-1, 2)
    r, step = config.profile_half_length_px, config.profile_step_px
    offsets = np.arange(-r, r + 0.5 * step, step)
    previous = np.arange(-1, len(coarse) - 1)                   # vertex k joins edges k - 1 and k
    vertices, rms, fallbacks, straightest = coarse, float('nan'), len(coarse), float('nan')
    for _ in range(config.passes):
        samples, points, directions, normals, usable, seen = _sample_edge_profiles(image_bgr, vertices, offsets,
                                                                                   config)
        crossings, contrasts = _edge_crossings(samples, offsets, config)
        crossings[~(usable & (contrasts >= config.min_contrast))[:, None] | ~seen] = np.nan
        anchors, line_directions, residuals = _fit_edge_lines(points, directions, normals, crossings,
                                                              config.min_points)
        used = np.isfinite(residuals)
        squared = np.where(used, residuals, 0.0) ** 2
        edge_rms = np.sqrt(_sum(squared, 1) / np.maximum(_sum(used, 1), 1))
        fitted = np.isfinite(anchors[:, 0]) & (edge_rms <= config.max_rms_px)
        corners = intersect_lines(anchors[previous], line_directions[previous], anchors, line_directions)
        shift = corners - coarse
        good = fitted & fitted[previous] & (_sum(shift ** 2, 1) <= config.max_shift_px ** 2)
        vertices = np.where(good[:, None], corners, coarse)
        fallbacks = int(len(coarse) - good.sum())
        count = used[fitted].sum()
        rms = float(np.sqrt(squared[fitted].sum() / count)) if count else float('nan')
        lined = np.isfinite(anchors[:, 0])
        straightest = float(edge_rms[lined].min()) if lined.any() else float('nan')
    return vertices, rms, fallbacks, straightest


def _sample_edge_profiles(image_bgr, polygon, offsets, config):
    """Colour profiles across the edges of ``polygon`` (n, 2); edge k runs from vertex k to k+1.

    Returns ``samples (n, M, K, 3)`` float32 (M = ``profiles_per_edge`` profiles of K = len(offsets)
    samples, from inside to outside), their centre ``points (n, M, 2)`` on the edge, the unit edge
    ``directions (n, 2)`` and outward ``normals (n, 2)``, ``usable (n,)`` (False for an edge too
    short to hold the profiles clear of its corners) and ``seen (n, M)`` (False for a profile reaching past the
    image border, whose samples there are the border's repeated). All profiles come from one ``cv2.remap`` of the
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
    h, w = image_bgr.shape[:2]
    ends = coords[:, :, [0, -1]]                 # a profile is straight: its two ends are its extremes
    u, v = ends[..., 0], ends[..., 1]
    seen = ((u >= 0.0) & (u <= w - 1) & (v >= 0.0) & (v <= h - 1)).all(axis=2)
    return samples.reshape(n, m, len(offsets), 3).astype(np.float32), points, directions, normals, usable, seen


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

