"""A block's pose from its silhouette on a known table (beyond the thesis): position and yaw of a prism standing on
the table plane, fitted to the outline of its colour blob.

The polygon pose (``pose.estimate_pose``) takes the depth from the top face's size in the image: a 15-30 px face
fixes it to centimetres only (docs/perception.md, "How far off its height a far estimate may be"), and a side face
lit like the top (a die seen obliquely) turns the polygon into a hexagon or the wrong quadrilateral. With the
table's plane known (forward kinematics and the table's height), a block standing on it has three degrees of
freedom, and its image is the hull of its top face and of the side faces the camera sees. The blob's outline is
the colour mask's: a side face in shadow is too dark for its colour class and is not in it, so each subset of the
visible side faces is a hypothesis of its own, and the one that overlaps the outline best counts (session 15's
prism silhouette, which took the whole prism, shrank it to the lit faces). Fitted by Nelder-Mead on one minus the
intersection over union of that hull and the outline's, in ideal (undistorted) pixels, from yaws spread over the
shape's symmetry angle.

Frames and units: the camera optical frame, metres; the plane's normal points up, towards the camera
(``models.Plane``); pixels distorted as the camera delivers them unless said otherwise.
"""
import itertools
import math
from dataclasses import dataclass

import cv2
import numpy as np
from scipy.optimize import minimize

YAW_STARTS = 2              # initial yaws, spread evenly over the shape's symmetry angle
_STEP_FRACTION = 0.25       # the initial simplex: a quarter of a side in position, of the symmetry angle in yaw
_TOLERANCE = 1e-4           # Nelder-Mead's tolerances: m and rad on the parameters, 1e-4 on the overlap


@dataclass(frozen=True)
class SilhouetteFit:
    """A prism standing on the table fitted to an outline.

    ``T_camera_block``: 4x4 pose (top-face centre, z up along the table's normal); ``overlap``: intersection over
    union of its hull (the best subset of visible side faces) and the outline's, 0-1; ``gap_px``: the area between the
    two over their mean perimeter, the outlines' mean distance (ideal px); ``top_px``: (n, 2) its top-face vertices
    projected (distorted pixels, model order)."""
    T_camera_block: np.ndarray
    overlap: float
    gap_px: float
    top_px: np.ndarray


def fit_on_table(outline_px, camera, model, table_plane, yaw_starts=YAW_STARTS):
    """The ``SilhouetteFit`` of ``model`` (``models.PolygonModel``) standing on ``table_plane`` (camera frame) to the
    closed outline ``outline_px`` ((M, 2) or (M, 1, 2) distorted pixels, e.g. a blob's contour) seen by ``camera``;
    None when the outline is degenerate or its centre's ray does not meet the table in front of the camera;
    ValueError when the camera is not on the side of the table its normal points to."""
    if table_plane.signed_distance(np.zeros(3)) <= 0:
        raise ValueError('fit_on_table: the camera must be on the side the table plane\'s normal points to')
    outline = np.asarray(outline_px, dtype=float).reshape(-1, 2)
    if len(outline) < 3 or not np.isfinite(outline).all():
        return None
    observed = cv2.convexHull(camera.normalised_to_pixels(camera.undistort_points(outline)).astype(np.float32))
    moments = cv2.moments(observed)
    if moments['m00'] <= 1.0:
        return None
    problem = _Problem(camera, model, table_plane, np.array([moments['m10'], moments['m01']]) / moments['m00'],
                       observed)
    if problem.start is None:
        return None
    step, symmetry = _STEP_FRACTION * model.side, model.symmetry_angle
    best = None
    for yaw in symmetry * np.arange(yaw_starts) / yaw_starts:
        simplex = [[0.0, 0.0, yaw], [step, 0.0, yaw], [0.0, step, yaw], [0.0, 0.0, yaw + _STEP_FRACTION * symmetry]]
        result = minimize(problem.cost, simplex[0], method='Nelder-Mead',
                          options={'initial_simplex': simplex, 'xatol': _TOLERANCE, 'fatol': _TOLERANCE})
        if best is None or result.fun < best.fun:
            best = result
    return problem.fit(best.x)


class _Problem:
    """One outline's fit: parameters (u, v, yaw) = the top-face centre's offset (m) along two axes of the table
    plane from where the outline's centre ray meets the block's mid-height, and the yaw (rad) about the normal."""

    def __init__(self, camera, model, plane, centre_px, observed):
        self.camera, self.model, self.normal, self.observed = camera, model, plane.normal, observed
        self.observed_area, self.observed_perimeter = cv2.contourArea(observed), cv2.arcLength(observed, True)
        self.focal, self.principal = np.diag(camera.K)[:2], camera.K[:2, 2]
        self.e1, self.e2 = plane.axes()
        ray = np.append((centre_px - self.principal) / self.focal, 1.0)
        along = self.normal @ ray
        distance = (plane.offset + 0.5 * model.height) / along if along != 0.0 else -1.0
        self.start = ray * distance + 0.5 * model.height * self.normal if distance > 0 else None
        # a block-frame point (px, py, 0) at yaw t lies at centre + cos t (px e1 + py e2) + sin t (px e2 - py e1):
        # the vertices' and the side faces' (centres, outward normals) cosine and sine parts, computed once
        plane_xy = model.vertices[:, :2]
        middles = 0.5 * (plane_xy + np.roll(plane_xy, -1, axis=0))              # side face k: vertex k -> k + 1
        self._vertex_parts = self._parts(plane_xy)
        self._middle_parts = self._parts(middles)
        self._normal_parts = self._parts(middles / np.linalg.norm(middles, axis=1, keepdims=True))
        self.drop = model.height * self.normal
        self._subsets = {}

    def _parts(self, xy):
        """(cosine part, sine part), each (k, 3), of block-frame points ``xy`` (k, 2) on the top face's plane."""
        return (np.outer(xy[:, 0], self.e1) + np.outer(xy[:, 1], self.e2),
                np.outer(xy[:, 0], self.e2) - np.outer(xy[:, 1], self.e1))

    def pose(self, params):
        """(R, top-face centre) of the parameters."""
        u, v, yaw = params
        c, s = math.cos(yaw), math.sin(yaw)
        x, y = c * self.e1 + s * self.e2, c * self.e2 - s * self.e1
        return np.column_stack([x, y, self.normal]), self.start + u * self.e1 + v * self.e2

    def hulls(self, params):
        """The hulls (ideal px, float32) of the top face with each subset of the side faces that face the camera."""
        u, v, yaw = params
        c, s = math.cos(yaw), math.sin(yaw)
        centre = self.start + u * self.e1 + v * self.e2
        top = centre + c * self._vertex_parts[0] + s * self._vertex_parts[1]
        points = np.concatenate([top, top - self.drop])
        if points[:, 2].min() <= 1e-6:
            return []
        pixels = (points[:, :2] / points[:, 2:] * self.focal + self.principal).astype(np.float32)
        middles = centre - 0.5 * self.drop + c * self._middle_parts[0] + s * self._middle_parts[1]
        normals = c * self._normal_parts[0] + s * self._normal_parts[1]
        facing = (normals * middles).sum(axis=1) < 0.0             # the side faces turned to the camera (the origin)
        return [cv2.convexHull(pixels[index]) for index in self._subset_indices(tuple(np.flatnonzero(facing)))]

    def _subset_indices(self, visible):
        """Per subset of the side faces ``visible``: the indices of its hull's points (top, then bottom vertices)."""
        if visible not in self._subsets:
            n = self.model.n
            self._subsets[visible] = [np.array(list(range(n)) + [n + j for k in faces for j in (k, (k + 1) % n)])
                                      for count in range(len(visible) + 1)
                                      for faces in itertools.combinations(visible, count)]
        return self._subsets[visible]

    def overlaps(self, params):
        """[(intersection over union, hull)] of each of ``hulls(params)`` with the observed hull."""
        result = []
        for hull in self.hulls(params):
            inside, _ = cv2.intersectConvexConvex(hull, self.observed)
            union = cv2.contourArea(hull) + self.observed_area - inside
            result.append((inside / union if union > 0 else 0.0, hull))
        return result

    def cost(self, params):
        """One minus the best overlap (the objective)."""
        return 1.0 - max((overlap for overlap, _ in self.overlaps(params)), default=0.0)

    def fit(self, params):
        """The ``SilhouetteFit`` at ``params``; None when the prism is not in front of the camera."""
        overlaps = self.overlaps(params)
        if not overlaps:
            return None
        overlap, hull = max(overlaps, key=lambda pair: pair[0])
        union = (cv2.contourArea(hull) + self.observed_area) / (1.0 + overlap)
        gap = (1.0 - overlap) * union / (0.5 * (cv2.arcLength(hull, True) + self.observed_perimeter))
        R, centre = self.pose(params)
        T = np.eye(4)
        T[:3, :3], T[:3, 3] = R, centre
        return SilhouetteFit(T, float(overlap), float(gap), self.camera.project(self.model.vertices @ R.T + centre))
