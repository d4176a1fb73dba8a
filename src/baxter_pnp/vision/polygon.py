"""Polygon stages: a blob's outline (contour, pixels) -> the vertices (k, 2) of a convex polygon, and its shape.

Douglas-Peucker, the merge of close vertices (the thesis's "high pass filter"), restored cut corners, side-line
fitting, shape from the vertex count or, for a small blurred polygon, from its outline's harmonics, vertex order.
Pixels are (u, v) = (column, row), floats.
"""
import math
from typing import NamedTuple, Optional

import cv2
import numpy as np

from baxter_pnp.models import SHAPES

SHAPE_OF_VERTEX_COUNT = {n: shape for shape, n in SHAPES.items()}
SHORT_EDGE_RATIO = 0.4       # remove_cut_corners: an edge this much shorter than both neighbours is no polygon side
ROUND_RESIDUAL_RATIO = 0.8    # looks_round: an ellipse must fit the outline this much better than the polygon
_MAX_SIDE_FIT_POINTS = 240     # fit_polygon_sides: a longer contour is subsampled to about this many points
_HARMONIC_ANGLES = np.linspace(-np.pi, np.pi, 360, endpoint=False)   # shape_harmonics: the profile's angles


def approximate_polygon(contour, epsilon_fraction):
    """(k, 2) float vertices of the Douglas-Peucker approximation (tolerance = fraction of the perimeter)."""
    epsilon = epsilon_fraction * cv2.arcLength(contour, True)
    return cv2.approxPolyDP(contour, epsilon, True).reshape(-1, 2).astype(float)


def remove_cut_corners(vertices, max_area_fraction, clear_area_fraction=None, clear_max_size_px=math.inf):
    """Convex polygon (k, 2) with its cut corners restored, smallest first, down to a triangle.

    An edge is a cut corner (or a spurious vertex on a straight side) when its two neighbouring
    edges, extended beyond it, meet in a point that adds less than ``max_area_fraction`` of the
    polygon's area; the edge's two vertices are replaced by that point. Restoring a true corner of
    a regular polygon adds a sixth of its area (hexagon) or more in an affine view, still 8 % in the
    strongest perspective of the benchmark (a 54 mm hexagon 0.13 m away, tilted 29 deg), while a cut
    corner adds a few per cent at most. Morphology rounds acute corners and a side face can clip a
    corner of the top face; Douglas-Peucker then keeps both ends of the cut.

    On a polygon small enough to be seen in a nearly affine view (the square root of its area at most
    ``clear_max_size_px``), where no hexagon's corner can be at stake, the allowance is ``clear_area_fraction``
    (default: the same): when the restored polygon would have four vertices or fewer (a pentagon's corner adds
    45 % in an affine view, a square's two neighbours never meet), and for an edge shorter than
    ``SHORT_EDGE_RATIO`` of both its neighbours (a regular polygon's edges are alike). Blur and morphology cut
    a fixed depth in pixels off a corner, and of a small block's top face that is a large share (a 60 deg
    corner of an 18 px triangle cut 3.5 px deep: 4.3 %). Large polygons are near and in perspective, where a
    pentagon's corner can add less than 20 % (a 58 mm pentagon 0.10 m away, tilted 29 deg).
    """
    clear_area_fraction = max_area_fraction if clear_area_fraction is None else clear_area_fraction
    polygon = [tuple(v) for v in np.asarray(vertices, dtype=float).reshape(-1, 2)]
    while len(polygon) > 3:
        n = len(polygon)
        area = 0.5 * abs(sum(polygon[k - 1][0] * polygon[k][1] - polygon[k][0] * polygon[k - 1][1] for k in range(n)))
        clear = clear_area_fraction if area <= clear_max_size_px ** 2 else max_area_fraction
        allowance = (clear if n <= 5 else max_area_fraction) * area
        best, best_share = None, 1.0
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
            short = math.hypot(*gap) < SHORT_EDGE_RATIO * min(math.hypot(*d_in), math.hypot(*d_out))
            share = added / (clear * area if short else allowance)   # < 1: a cut corner
            if share < best_share:
                best, best_share = (k, apex), share
        if best is None:
            break
        k, apex = best
        polygon[k] = apex
        del polygon[(k + 1) % n]
    return np.array(polygon, dtype=float)


def remove_flat_vertices(vertices, max_area_fraction):
    """Convex polygon (k, 2) without its flat vertices, flattest first, down to a triangle.

    A vertex is flat when the triangle it makes with its two neighbours is less than ``max_area_fraction``
    of the polygon's area: a bend in a side, where the outline follows a sliver of side face (or a grid line
    of the table) along part of it. Removing a true corner of a regular polygon loses a sixth of its area
    (hexagon) or more in an affine view; a side bent by 15 deg halfway loses about 3 %.
    """
    polygon = np.asarray(vertices, dtype=float).reshape(-1, 2)
    while len(polygon) > 3:
        previous, following = np.roll(polygon, 1, axis=0), np.roll(polygon, -1, axis=0)
        a, b = polygon - previous, following - previous
        triangles = 0.5 * np.abs(a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0])
        area = 0.5 * abs(float(np.sum(previous[:, 0] * polygon[:, 1] - polygon[:, 0] * previous[:, 1])))
        k = int(np.argmin(triangles))
        if triangles[k] >= max_area_fraction * area:
            break
        polygon = np.delete(polygon, k, axis=0)
    return polygon


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
    corners = intersect_lines(means[previous], directions[previous], means, directions)
    good = (counts >= 3) & (counts[previous] >= 3)
    good &= ((corners - vertices) ** 2).sum(axis=1) < 0.25 * np.minimum(lengths_sq[previous], lengths_sq)
    return np.where(good[:, None], corners, vertices)


def classify_shape(vertex_count):
    """Shape name of a polygon with ``vertex_count`` vertices (3 triangle .. 6 hexagon), else None."""
    return SHAPE_OF_VERTEX_COUNT.get(int(vertex_count))


def order_vertices(vertices):
    """Vertices sorted by increasing ``atan2(v - vc, u - uc)`` about their mean (clockwise on screen)."""
    vertices = np.asarray(vertices, dtype=float).reshape(-1, 2)
    centre = vertices.mean(axis=0)
    angles = np.arctan2(vertices[:, 1] - centre[1], vertices[:, 0] - centre[0])
    return vertices[np.argsort(angles, kind='stable')]


def intersect_lines(points_a, directions_a, points_b, directions_b):
    """(n, 2) intersections of lines a and b (point, unit direction); NaN where within ~10 deg of parallel."""
    cross = directions_a[:, 0] * directions_b[:, 1] - directions_a[:, 1] * directions_b[:, 0]
    crossing = np.abs(cross) >= 0.17                          # NaN directions compare False
    gap = points_b - points_a
    t = (gap[:, 0] * directions_b[:, 1] - gap[:, 1] * directions_b[:, 0]) / np.where(crossing, cross, 1.0)
    return np.where(crossing[:, None], points_a + t[:, None] * directions_a, np.nan)



class Harmonics(NamedTuple):
    """What ``shape_harmonics`` reads off an outline: the vertex ``count`` (3-6, None for a degenerate outline),
    its harmonic's weighted amplitude over the runner-up's (``margin``) and over a sharp regular polygon's
    (``strength``: about 0.5-0.8 for a blurred 15-25 px block, under 0.4 for a round button's bumpy outline)."""
    count: Optional[int]
    margin: float
    strength: float


def shape_harmonics(contour):
    """The ``Harmonics`` of the outline ``contour`` (M, 1, 2): the vertex count whose harmonic dominates its radial
    profile, affine-normalised.

    A regular n-gon's distance from its centroid, as a function of the angle, repeats n times a turn, so its
    spectrum peaks at harmonic n (a triangle's 6th is a fraction of its 3rd). Seen tilted, in a nearly affine
    view, a regular polygon keeps second moments proportional to its image's: whitening the outline by its own
    (a circle's in the end) turns it back into a regular polygon, rotated, whose spectrum's magnitudes the
    rotation leaves alone. Blur and the pixel grid damp harmonic k more the higher k is; amplitude times k
    undoes that on blocks of 15-25 px (a triangle's 6th harmonic, its second peak, is not counted against it).
    Where Douglas-Peucker and the cut-corner rules count a small blurred polygon's corners, or the disc test
    finds an ellipse fitting as well as the polygon, the spectrum sees the whole outline: a pentagon's blunt
    corners looked like a square's, a small triangle's tip was cut off, a 20 px hexagon was taken for a disc.
    """
    spectrum = _radial_spectrum(contour.reshape(-1, 2).astype(float))
    if spectrum is None:
        return Harmonics(None, 0.0, 0.0)
    weighted = spectrum * np.arange(3, 7)
    count = int(np.argmax(weighted)) + 3
    rivals = weighted[1:3] if count == 3 else np.delete(weighted, count - 3)   # a triangle's own 6th is no rival
    runner_up = float(rivals.max())
    margin = float(weighted[count - 3]) / runner_up if runner_up > 0 else math.inf
    return Harmonics(count, margin, float(spectrum[count - 3] / _REGULAR_SPECTRA[count]))


def _radial_spectrum(points):
    """(4,) amplitudes of harmonics 3-6 of the closed outline ``points`` (M, 2) as a radius against the angle about
    its centroid, once whitened by its second moments, relative to the mean radius; None if degenerate."""
    moments = cv2.moments(points.astype(np.float32))
    if len(points) < 5 or moments['m00'] <= 0:
        return None
    centroid = np.array([moments['m10'], moments['m01']]) / moments['m00']
    covariance = np.array([[moments['mu20'], moments['mu11']], [moments['mu11'], moments['mu02']]]) / moments['m00']
    eigenvalues, axes = np.linalg.eigh(covariance)
    if eigenvalues[0] <= 1e-9 * eigenvalues[1]:
        return None
    whitened = (points - centroid) @ (axes / np.sqrt(eigenvalues)) @ axes.T
    angles = np.arctan2(whitened[:, 1], whitened[:, 0])
    order = np.argsort(angles)
    angles, radii = angles[order], np.hypot(whitened[order, 0], whitened[order, 1])
    angles = np.concatenate([angles[-1:] - 2.0 * np.pi, angles, angles[:1] + 2.0 * np.pi])    # the turn closed
    radius = np.interp(_HARMONIC_ANGLES, angles, np.concatenate([radii[-1:], radii, radii[:1]]))
    return np.abs(np.fft.rfft(radius))[3:7] / (len(radius) * radius.mean())


def _regular_outline(n, points_per_side=100):
    """(n * points_per_side, 2) points along a sharp regular n-gon's sides (circumradius 1)."""
    corners = np.column_stack([np.cos(2 * np.pi * np.arange(n) / n), np.sin(2 * np.pi * np.arange(n) / n)])
    t = np.linspace(0.0, 1.0, points_per_side, endpoint=False)[:, None]
    return np.concatenate([corners[k] + t * (corners[(k + 1) % n] - corners[k]) for k in range(n)])


_REGULAR_SPECTRA = {n: _radial_spectrum(_regular_outline(n))[n - 3] for n in (3, 4, 5, 6)}   # shape_harmonics


def hull_polygon(hull, count):
    """(``count``, 2) vertices of the convex ``hull`` (M, 1, 2) reduced to ``count``: the vertex whose triangle with
    its neighbours is the smallest is dropped, one at a time (a rounded corner's points go before any corner);
    the hull itself (M, 2) when it has ``count`` vertices or fewer."""
    vertices = hull.reshape(-1, 2).astype(float)
    while len(vertices) > count:
        before, after = np.roll(vertices, 1, axis=0), np.roll(vertices, -1, axis=0)
        areas = np.abs((vertices[:, 0] - before[:, 0]) * (after[:, 1] - before[:, 1])
                       - (vertices[:, 1] - before[:, 1]) * (after[:, 0] - before[:, 0]))
        vertices = np.delete(vertices, int(np.argmin(areas)), axis=0)
    return vertices


def looks_round(contour, vertices):
    """True when an ellipse explains the outline ``contour`` (M, 1, 2) better than the polygon ``vertices`` (k, 2).

    A disc (a button, a cylinder's end) is cut into five or six sides by the polygon stages; its outline then
    bulges between the vertices, while an ellipse fits it to the pixel grid. Compares the mean distance (px)
    of the outline points to the fitted ellipse and to the polygon's boundary; round when the ellipse's is
    below ``ROUND_RESIDUAL_RATIO`` of the polygon's. False for fewer than 5 vertices or outline points.
    """
    points = contour.reshape(-1, 2).astype(np.float32)
    if len(vertices) < 5 or len(points) < 5:
        return False
    (cu, cv), (width, height), angle = cv2.fitEllipse(points)
    if min(width, height) <= 0:
        return False
    polygon_residual = float(np.mean(_distance_to_boundary(points.astype(float), np.asarray(vertices, float))))
    # distance to the ellipse, to first order: radial offset in the unit-circle frame x the local semi-axis
    c, s = math.cos(math.radians(angle)), math.sin(math.radians(angle))
    du, dv = points[:, 0] - cu, points[:, 1] - cv
    x, y = (c * du + s * dv) / (width / 2.0), (-s * du + c * dv) / (height / 2.0)
    radius = np.hypot(x, y)
    local_axis = np.hypot(x * width / 2.0, y * height / 2.0) / np.maximum(radius, 1e-9)
    ellipse_residual = float(np.mean(np.abs(radius - 1.0) * local_axis))
    return ellipse_residual < ROUND_RESIDUAL_RATIO * polygon_residual


def _distance_to_boundary(points, vertices):
    """(M,) distance (px) of each of ``points`` (M, 2) to the closed polygon ``vertices`` (k, 2)'s nearest edge."""
    ex = np.roll(vertices[:, 0], -1) - vertices[:, 0]          # components written out: numpy reduces slowly
    ey = np.roll(vertices[:, 1], -1) - vertices[:, 1]          # over a length-2 axis
    ox, oy = points[:, :1] - vertices[:, 0], points[:, 1:] - vertices[:, 1]                     # (M, k)
    t = np.clip((ox * ex + oy * ey) / np.maximum(ex * ex + ey * ey, 1e-12), 0.0, 1.0)
    return np.sqrt(np.min((ox - t * ex) ** 2 + (oy - t * ey) ** 2, axis=1))
