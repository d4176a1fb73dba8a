"""Pose of a polygonal block from the image of its top face: our SQP constraint model and OpenCV baselines.

Input: the n top-face vertices in **distorted** pixels (as the detector gives them), the camera model
and the block model (``models.PolygonModel``). Output: ``T_camera_object``, the pose of the block frame
(origin at the top-face centre, +z up) in the camera optical frame (x right, y down, z forward), metres.

Vertex correspondence. The detector orders vertices by increasing ``atan2(v - vc, u - uc)``, i.e.
counter-clockwise about the camera's +z (the viewing direction). The model's vertices go
counter-clockwise about the block's +z, which points back towards the camera when the top face is
seen, so the model order appears *clockwise* in the image: a polygon given in the detector's order is
reversed. The orientation is taken from the sign of the polygon's area, so either order is accepted;
a cyclic shift is equivalent to a rotation by the symmetry angle ``2 pi / n``.

Yaw. ``yaw`` is the angle (rad) about the top-face normal from the reference axis ``x_ref`` (the
camera's x axis projected onto the face plane) to the block's x axis; looking down on the block with
the camera upright, yaw 0 puts the block's x axis along the image's +u and positive yaw turns it
towards image up. It is reported modulo ``2 pi / n`` in ``(-pi/n, pi/n]`` and ``T_camera_object`` uses
that representative.

Methods (``estimate_pose(method=...)``):

* ``'sqp'`` (ours, the thesis's approach): unknowns are the camera-frame 3D positions of the n
  vertices; the objective is the sum of squared reprojection errors in ideal (undistorted) pixels with
  an analytic gradient; equality constraints (analytic Jacobians) make the polygon the model: the n
  edge lengths and the n - 3 diagonals from vertex 0 (2n - 3 distances: rigid in the plane) and n - 3
  coplanarity triple products; solved by Gauss-Newton SQP (each step the KKT system of the objective's
  Gauss-Newton model under the linearised constraints; 3-5 steps to the optimum scipy's SLSQP found, without
  its overhead) from the best IPPE solution (or from the previous frame's pose), then the model is fitted
  rigidly to the solution (Kabsch). With a table plane, a strong prior ties the face normal to the table
  normal (see ``TABLE_NORMAL_SIGMA_RAD``).
* ``'ippe'``: ``cv2.solvePnPGeneric`` with SOLVEPNP_IPPE_SQUARE (squares) or SOLVEPNP_IPPE (pentagons,
  hexagons), or ``cv2.solveP3P`` (AP3P) for triangles (IPPE needs 4 points); of its solutions the one
  with the lowest reprojection error (plus table-normal prior, when given) is kept.
* ``'sqpnp'``: ``cv2.solvePnPGeneric`` with SOLVEPNP_SQPNP.

Every solver's output is checked (finite, every vertex in front of the camera, top face seen from
above, residual not absurd); when it fails the next one is tried in the order sqp -> ippe -> sqpnp,
and ``PoseEstimate.method`` says which one produced the pose.

Why the table plane is a prior on the normal and not a constraint on the whole plane: the normal
from forward kinematics is good to about a degree, much better than the orientation the image gives
for a small square seen straight on (several degrees at 0.5 px), and it removes the planar (two-fold)
ambiguity; the plane's offset, in contrast, carries the table height and hand-eye translation errors
(millimetres to centimetres), larger than the image's own depth error (about 1 mm at 161 mm), so
imposing it would degrade depth. A soft prior rather than a hard constraint keeps a tilted table or
an object resting on something from forcing a wrong normal when the image clearly disagrees. Where the image's
depth is the worse of the two (a small block far away), the task layer weighs the offset in afterwards, at each
one's uncertainty, for the target it believes (``task.target.on_the_table``).
"""
import functools
import math
from dataclasses import dataclass
from typing import NamedTuple, Optional

import cv2
import numpy as np
from scipy.spatial.transform import Rotation

METHODS = ('sqp', 'ippe', 'sqpnp')
# Assumed accuracy (rad) of the table normal from forward kinematics (hand-eye rotation, table level).
TABLE_NORMAL_SIGMA_RAD = 0.02
# Vertex noise (px) assumed for the prior's weight and used as the floor of the covariance's sigma.
PIXEL_SIGMA_FLOOR_PX = 0.5
# A pose whose RMS residual exceeds this fraction of the polygon's mean edge length (px) is rejected.
ABSURD_RESIDUAL_EDGE_FRACTION = 0.2
# A polygon whose area is below this fraction of its squared perimeter is degenerate (a regular
# polygon has 0.048 (triangle) to 0.072 (hexagon); a 60-degree tilt halves it).
MIN_AREA_PERIMETER_RATIO = 1e-3
# SQP: stop when a step moves no vertex's image point by more than this (px), nor its depth by more than this
# many focal lengths (relative).
SQP_STEP_TOL_PX = 1e-5
SQP_MAX_ITERATIONS = 30
# With a table plane, a pose whose top face is tilted more than this from the table's is refused: a block lying on
# the table is level with it (to the plane's own error, a few degrees), while a flat 2:1 brick fitted with a square
# model tilts it by 19-63 deg (the real cube photos).
MAX_TILT_FROM_TABLE_RAD = math.radians(15.0)


class PoseEstimationError(ValueError):
    """The vertices do not give a pose: degenerate polygon, or no solver produced a valid pose."""


@dataclass
class PoseEstimate:
    """A block pose in the camera optical frame.

    ``T_camera_object``: 4x4 pose of the block frame in the camera frame (m), yaw representative in
    ``(-pi/n, pi/n]``. ``residual_px``: RMS reprojection error of the model vertices (ideal pixels).
    ``method``: the solver that produced it. ``covariance``: 6x6 Gauss-Newton covariance of
    (translation (m), rotation vector (rad)), both in the camera frame, for the perturbation
    ``T = [exp(dtheta) R, t + dt]``; None if it could not be computed.
    """
    T_camera_object: np.ndarray
    residual_px: float
    method: str
    covariance: Optional[np.ndarray] = None

    @property
    def position_m(self):
        """(3,) block origin (top-face centre) in the camera frame (m)."""
        return self.T_camera_object[:3, 3].copy()

    @property
    def quaternion_xyzw(self):
        """(4,) orientation of the block frame in the camera frame, (x, y, z, w)."""
        return Rotation.from_matrix(self.T_camera_object[:3, :3]).as_quat()

    @property
    def depth_m(self):
        """Z of the block origin along the optical axis (m)."""
        return float(self.T_camera_object[2, 3])

    @property
    def yaw_rad(self):
        """Yaw (rad) about the top-face normal from the projected camera x axis (module docstring)."""
        return _yaw_about_normal(self.T_camera_object[:3, :3])[0]

    @property
    def position_std_m(self):
        """Standard deviation (m) of the block origin along its least certain direction (nearly the viewing ray:
        ``largest_std`` of the translation covariance); None without a covariance."""
        return None if self.covariance is None else largest_std(self.covariance[:3, :3])


def largest_std(covariance):
    """Square root of the largest eigenvalue of a covariance matrix: the std along its least certain direction."""
    return float(np.sqrt(max(np.linalg.eigvalsh(covariance)[-1], 0.0)))


def estimate_pose(vertices_px, camera, model, method='sqp', table_plane=None, initial=None):
    """Pose of ``model`` from its top-face vertices ``vertices_px`` ((n, 2) distorted pixels).

    ``camera``: ``CameraModel``; ``model``: ``PolygonModel``; ``method``: 'sqp' | 'ippe' | 'sqpnp'
    (module docstring); ``table_plane``: ``models.Plane`` of the table top in the camera frame, normal
    towards the camera (the top face lies ``model.height`` above it; only its normal is used);
    ``initial``: previous pose (``PoseEstimate`` or 4x4 ``T_camera_object``) to start 'sqp' from.
    Returns a ``PoseEstimate``; raises ``PoseEstimationError`` for degenerate vertices or when no
    solver gives a valid pose (with a table plane: none level with it within ``MAX_TILT_FROM_TABLE_RAD``).
    """
    if method not in METHODS:
        raise ValueError(f'unknown pose method {method!r}; expected one of {METHODS}')
    table_normal = None
    if table_plane is not None:
        if table_plane.signed_distance(np.zeros(3)) <= 0:
            raise ValueError('table_plane: the camera must be on the side its normal points to')
        table_normal = table_plane.normal
    if initial is not None:
        initial = np.asarray(getattr(initial, 'T_camera_object', initial), dtype=float)
        if initial.shape != (4, 4) or not np.all(np.isfinite(initial)):
            raise ValueError('initial must be a PoseEstimate or a finite 4x4 T_camera_object')
    observation = _Observation.from_pixels(vertices_px, camera, model)

    failures = []
    for name in (method,) + tuple(m for m in METHODS if m != method):
        try:
            R, t = _SOLVERS[name](observation, model, table_normal, initial)
        except (cv2.error, np.linalg.LinAlgError, ValueError) as exc:
            failures.append(f'{name}: {exc}')
            continue
        problem = _invalidity(R, t, observation, model) or _off_the_table(R, table_normal)
        if problem is None:
            return _make_estimate(R, t, observation, model, name, table_normal if name == 'sqp' else None)
        failures.append(f'{name}: {problem}')
    raise PoseEstimationError(f'no valid pose for the {model.shape}: ' + '; '.join(failures))


# ----------------------------------------------------------------------------------------- input
@dataclass
class _Observation:
    """Undistorted vertices in model order (up to a cyclic shift): normalised and ideal pixels."""
    normalised: np.ndarray     # (n, 2) X/Z, Y/Z
    ideal_px: np.ndarray       # (n, 2) undistorted pixels
    K: np.ndarray              # (3, 3)
    focal_px: np.ndarray       # (2,) fx, fy (px)
    mean_edge_px: float

    @classmethod
    def from_pixels(cls, vertices_px, camera, model):
        expected = f'a {model.shape} needs ({model.n}, 2) pixel vertices'
        try:
            vertices_px = np.asarray(vertices_px, dtype=float)
        except (TypeError, ValueError):
            raise PoseEstimationError(f'{expected}, got {vertices_px!r}') from None
        if vertices_px.shape != (model.n, 2):
            raise PoseEstimationError(f'{expected}, got shape {vertices_px.shape}')
        if not np.isfinite(vertices_px).all():
            raise PoseEstimationError('vertices contain non-finite values')
        normalised = camera.undistort_points(vertices_px)
        if not np.isfinite(normalised).all():
            raise PoseEstimationError('vertices could not be undistorted')
        ideal_px = camera.normalised_to_pixels(normalised)
        corners = ideal_px.tolist()
        _check_simple_polygon(corners)
        perimeter = sum(math.dist(a, b) for a, b in zip(corners, corners[1:] + corners[:1]))
        area = _signed_area(corners)
        if abs(area) <= MIN_AREA_PERIMETER_RATIO * perimeter ** 2:
            raise PoseEstimationError(f'degenerate polygon: area {abs(area):.3g} px^2 for a perimeter of '
                                      f'{perimeter:.3g} px (collinear or coincident vertices)')
        if area > 0:   # counter-clockwise about the camera's z: detector order, reverse to model order
            normalised, ideal_px = normalised[::-1].copy(), ideal_px[::-1].copy()
        K = camera.K.copy()
        return cls(normalised, ideal_px, K, K.diagonal()[:2].copy(), perimeter / model.n)


def _signed_area(corners):
    """Shoelace area of a polygon, a list of (x, y) (units of xy squared); > 0 when counter-clockwise in (u, v)."""
    return 0.5 * sum(x0 * y1 - x1 * y0 for (x0, y0), (x1, y1) in zip(corners, corners[1:] + corners[:1]))


def _check_simple_polygon(corners):
    """Raise PoseEstimationError when two non-adjacent edges of the closed polygon ``corners`` ((x, y) list) cross."""
    n = len(corners)

    def orientation(a, b, c):
        turn = (b[0] - a[0]) * (c[1] - a[1]) - (b[1] - a[1]) * (c[0] - a[0])
        return (turn > 0) - (turn < 0)

    for i in range(n):
        for j in range(i + 2, n):
            if i == 0 and j == n - 1:
                continue   # adjacent through the closing edge
            p, q, r, s = corners[i], corners[(i + 1) % n], corners[j], corners[(j + 1) % n]
            if (orientation(p, q, r) != orientation(p, q, s)
                    and orientation(r, s, p) != orientation(r, s, q)):
                raise PoseEstimationError(f'self-intersecting vertex order: edges {i}-{(i + 1) % n} '
                                          f'and {j}-{(j + 1) % n} cross')


# ----------------------------------------------------------------------------------------- solvers
def _solve_sqp(observation, model, table_normal, initial):
    """'sqp': constraint model fitted by Gauss-Newton SQP, then rigid (Kabsch) fit of the model; returns (R, t)."""
    if initial is not None:
        R0, t0 = _matched_initial(initial, observation, model)
    else:
        candidates = _closed_form_candidates(observation, model)
        if not candidates:     # e.g. IPPE's garbage for a centred fronto-parallel square with integer corners
            candidates = [candidate for candidate in [_solve_sqpnp(observation, model)]
                          if _invalidity(*candidate, observation, model) is None]
        if not candidates:
            raise ValueError('no valid initial pose from IPPE or SQPnP')
        R0, t0 = _best_candidate(candidates, observation, model, table_normal)
    fit = _PolygonFit(observation, model, table_normal, R0, t0)
    X = fit.positions(fit.solve()) * model.side
    centre = X.sum(axis=0) / len(X)      # X.mean(axis=0), without its overhead
    return _kabsch_rotation(X - centre, model.vertices), centre


def _solve_ippe(observation, model, table_normal, initial):
    """'ippe': the best of IPPE's (or AP3P's, for triangles) solutions; returns (R, t)."""
    candidates = _closed_form_candidates(observation, model)
    if not candidates:
        raise ValueError('no valid solution (non-finite, behind the camera, seen from below or absurd residual)')
    return _best_candidate(candidates, observation, model, table_normal)


def _solve_sqpnp(observation, model, table_normal=None, initial=None):
    """'sqpnp': OpenCV's SQPnP (Terzakis & Lourakis 2020); returns (R, t)."""
    _, rvecs, tvecs, _ = cv2.solvePnPGeneric(model.vertices * _FLIP, observation.ideal_px, observation.K, None,
                                             flags=cv2.SOLVEPNP_SQPNP)
    if not rvecs:
        raise ValueError('SQPnP returned no solution')
    return _from_opencv(rvecs[0], tvecs[0])


_SOLVERS = {'sqp': _solve_sqp, 'ippe': _solve_ippe, 'sqpnp': _solve_sqpnp}

# OpenCV's solvers get the model in the block frame turned by pi about x (y and z negated): looking
# down on a block, R_camera_block is close to a half turn, where rotation vectors are singular (IPPE
# returned |rvec| = 45 rad and a wrong pose for a square seen straight on); turned, it is near identity.
_FLIP = np.array([1.0, -1.0, -1.0])
# Flipped-model vertex order of OpenCV's IPPE_SQUARE object points (-L/2, L/2), (L/2, L/2), (L/2, -L/2), (-L/2, -L/2).
_IPPE_SQUARE_ORDER = np.array([2, 3, 0, 1])


def _closed_form_candidates(observation, model):
    """The valid (``_invalidity``) (R, t) solutions of IPPE (n >= 4) or AP3P (triangles)."""
    K, image, flipped = observation.K, observation.ideal_px, model.vertices * _FLIP
    if model.n == 3:
        _, rvecs, tvecs = cv2.solveP3P(flipped, image, K, None, flags=cv2.SOLVEPNP_AP3P)
    elif model.n == 4:
        _, rvecs, tvecs, _ = cv2.solvePnPGeneric(flipped[_IPPE_SQUARE_ORDER], image[_IPPE_SQUARE_ORDER],
                                                 K, None, flags=cv2.SOLVEPNP_IPPE_SQUARE)
    else:
        _, rvecs, tvecs, _ = cv2.solvePnPGeneric(flipped, image, K, None, flags=cv2.SOLVEPNP_IPPE)
    candidates = []
    for rvec, tvec in zip(rvecs, tvecs):
        if np.isfinite(rvec).all() and np.isfinite(tvec).all():
            R, t = _from_opencv(rvec, tvec)
            if _invalidity(R, t, observation, model) is None:
                candidates.append((R, t))
    return candidates


def _best_candidate(candidates, observation, model, table_normal):
    """The candidate (R, t) with the lowest reprojection cost (px^2) plus table-normal prior cost.

    Triangles give exact P3P solutions (zero error each); without a table normal the one whose face
    is most nearly facing the camera (smallest angle between its normal and the line of sight) wins.
    """
    def cost(candidate):
        R, t = candidate
        if table_normal is not None:    # the same weighting as the SQP objective's prior
            prior = (PIXEL_SIGMA_FLOOR_PX * _angle_between(R[:, 2], table_normal) / TABLE_NORMAL_SIGMA_RAD) ** 2
            return _squared_error_px(_vertices_in_camera(R, t, model), observation) + prior
        if model.n == 3:
            return _angle_between(R[:, 2], -t)
        return _squared_error_px(_vertices_in_camera(R, t, model), observation)
    return min(candidates, key=cost)


def _matched_initial(T_initial, observation, model):
    """(R, t) of ``T_initial`` rotated by the symmetry that best matches the observed vertex order."""
    R, t = T_initial[:3, :3], T_initial[:3, 3]
    predicted = _vertices_in_camera(R, t, model)
    predicted = predicted[:, :2] / predicted[:, 2:]
    errors = [np.sum((observation.normalised - np.roll(predicted, -shift, axis=0)) ** 2) for shift in range(model.n)]
    shift = int(np.argmin(errors))
    return R @ _rotz(shift * model.symmetry_angle), t


class _FitPoint(NamedTuple):
    """What the SQP callbacks need at one point ``v`` (see ``_PolygonFit``)."""
    q: np.ndarray               # (3n,) chart coordinates
    X: np.ndarray               # (n, 3) positions in side units
    d_position: np.ndarray      # (3n, 3n) dX/dv
    differences: np.ndarray     # (3n - 4, 3) pair differences, then edges from vertex 0 (``_PolygonGeometry``)
    e1_skew: Optional[np.ndarray]    # [X_1 - X_0]x (n > 3)
    face_normal: Optional[np.ndarray]   # (X_1 - X_0) x (X_2 - X_0) (n > 3)
    image_error: np.ndarray     # (3n,) ideal pixel errors (u, v) of each vertex, 0 for its depth w
    mismatch: Optional[np.ndarray]      # Newell normal / model double area - table normal (with the prior)


class _PolygonFit:
    """The SQP problem of one observation: chart, objective and equality constraints, all analytic, and its solver.

    Chart of the vertex positions: ``q_i = (fx x_i / z_i, fy y_i / z_i, z_i / Z0)``, each vertex's
    ideal image point (px, relative to the principal point) and its depth relative to the initial
    depth Z0. The reprojection objective is then exactly half the sum of squared pixel errors: its
    Hessian is the identity on the image coordinates and 0 on the depths, which the constraints alone
    move. The constraints are written on the positions in side units ``X = (x, y, z) / side``: the n
    edges and the n - 3 diagonals from vertex 0 (2n - 3 squared distances: rigid in the plane), and the
    n - 3 triple products ``(X_k - X_0) . ((X_1 - X_0) x (X_2 - X_0))`` (coplanarity). With a table
    normal, the prior ``0.5 w |N / 2A - n_table|^2`` on the Newell normal N is added (w:
    ``(PIXEL_SIGMA_FLOOR_PX / TABLE_NORMAL_SIGMA_RAD)^2``).

    ``solve`` runs Gauss-Newton SQP (module docstring). What the objective, the constraints and their
    derivatives share at a point is computed once (``_at``); derivatives are taken with respect to the
    flattened positions ``X`` and carried to ``q`` by one product with the chart's derivative ``dX/dq``.
    """

    def __init__(self, observation, model, table_normal, R0, t0):
        self.n, self.side, self.table_normal = model.n, model.side, table_normal
        fx, fy = observation.focal_px
        self.geometry = g = _polygon_geometry(model.n)
        self.prior_weight = (PIXEL_SIGMA_FLOOR_PX / TABLE_NORMAL_SIGMA_RAD) ** 2
        depth_unit = t0[2]
        sx, sy, sz = depth_unit / (fx * model.side), depth_unit / (fy * model.side), depth_unit / model.side
        self._scale = np.array([sx, sy, sz])      # X = (u w sx, v w sy, w sz)
        # Q @ this: the chart derivative's variable entries dX_x/du, dX_y/dv, dX_x/dw, dX_y/dw = w sx, w sy, u sx, v sy
        self._d_position_entries = np.array([[0.0, 0.0, sx, 0.0], [0.0, 0.0, 0.0, sy], [sx, sy, 0.0, 0.0]])
        self._d_position = np.zeros((3 * model.n, 3 * model.n))   # dX/dq with its constant entries dX_z/dw
        self._d_position[g.depth_diagonal, g.depth_diagonal] = sz
        observed_q = np.zeros((model.n, 3))
        observed_q[:, :2] = observation.normalised * observation.focal_px
        self._observed_q = observed_q.ravel()
        X0 = _vertices_in_camera(R0, t0, model)
        Q0 = X0 / X0[:, 2:]
        Q0[:, :2] *= observation.focal_px
        Q0[:, 2] = X0[:, 2] / depth_unit
        self.q0 = Q0.ravel()
        self._memo_key, self._memo = None, None

    def _at(self, q):
        """The ``_FitPoint`` at ``q`` (memoised for the last ``q``)."""
        key = q.tobytes()
        if key == self._memo_key:
            return self._memo
        g = self.geometry
        Q = q.reshape(-1, 3)
        X = Q * self._scale
        X[:, :2] *= Q[:, 2:]
        d_position = self._d_position.copy()
        d_position.reshape(-1)[g.chart_entries] = (Q @ self._d_position_entries).ravel()
        image_error = q - self._observed_q
        image_error[2::3] = 0.0            # the objective does not depend on the depths
        differences = g.differences @ X
        e1_skew = face_normal = mismatch = None
        if self.n > 3:
            e1_skew = _skew(differences[g.distance_count])
            face_normal = e1_skew @ differences[g.distance_count + 1]
        if self.table_normal is not None:
            # Newell normal: sum_i X_i x X_{i+1} = 2 * area * unit normal on the constraint manifold.
            outer = X.T @ X[g.next]                 # sum_i X_i X_{i+1}^T: its antisymmetric part is N
            newell = np.array([outer[1, 2] - outer[2, 1], outer[2, 0] - outer[0, 2], outer[0, 1] - outer[1, 0]])
            mismatch = newell / g.double_area - self.table_normal
        self._memo_key = key
        self._memo = _FitPoint(q, X, d_position, differences, e1_skew, face_normal, image_error, mismatch)
        return self._memo

    def positions(self, q):
        """(n, 3) vertex positions in side units."""
        return self._at(q).X

    def solve(self):
        """The chart point ``q`` (3n,) of the constrained optimum, by Gauss-Newton SQP from the initial pose.

        Each iteration solves the equality-constrained QP of the objective's Gauss-Newton model (identity on
        the pixel coordinates, 0 on the depths, plus ``w J_n^T J_n`` for the prior, ``J_n`` the normal
        mismatch's Jacobian) under the linearised constraints, through its KKT system, and takes the full
        step: quadratic convergence from a closed-form start, 2-4 iterations. Stops once a step moves no
        image coordinate by more than ``SQP_STEP_TOL_PX`` and no depth by more than that many focal lengths;
        ValueError if that takes more than ``SQP_MAX_ITERATIONS`` or the KKT system is singular.
        """
        g, size = self.geometry, 3 * self.n
        count = size + 3 * self.n - 6
        kkt, rhs = np.zeros((count, count)), np.empty(count)
        image_hessian = np.ones(size)
        image_hessian[g.depth_diagonal] = 0.0
        tolerance = np.full(size, SQP_STEP_TOL_PX)
        tolerance[g.depth_diagonal] = SQP_STEP_TOL_PX / max(self._scale[2] / self._scale[0], 1.0)
        q = self.q0.copy()
        for _ in range(SQP_MAX_ITERATIONS):
            point = self._at(q)
            hessian, gradient = np.diag(image_hessian), point.image_error
            if point.mismatch is not None:
                # rows c: dN_c / dX_i = (X_{i+1} - X_{i-1}) x e_c, carried to q
                d_newell = (point.X[g.next] - point.X[g.previous]) @ _UNIT_SKEWS
                J_normal = d_newell.reshape(3, -1) @ point.d_position / g.double_area
                hessian = hessian + self.prior_weight * J_normal.T @ J_normal
                gradient = gradient + self.prior_weight * point.mismatch @ J_normal
            A = self.constraints_jacobian(q)
            kkt[:size, :size], kkt[:size, size:], kkt[size:, :size] = hessian, A.T, A
            rhs[:size], rhs[size:] = -gradient, -self.constraints(q)
            try:
                step = np.linalg.solve(kkt, rhs)[:size]
            except np.linalg.LinAlgError:
                raise ValueError('SQP: singular KKT system') from None
            if not np.isfinite(step).all():
                raise ValueError('SQP: non-finite step')
            q = q + step
            if np.all(np.abs(step) <= tolerance):
                return q
        raise ValueError(f'SQP did not converge in {SQP_MAX_ITERATIONS} iterations')

    def constraints(self, q):
        """(3n - 6,) constraint values (side units): squared distances minus the model's, triple products."""
        point, g = self._at(q), self.geometry
        pairs = point.differences[:g.distance_count]
        values = np.einsum('ij,ij->i', pairs, pairs) - g.squared_lengths
        if self.n == 3:
            return values
        return np.concatenate([values, point.differences[g.distance_count + 2:] @ point.face_normal])

    def constraints_jacobian(self, q):
        """(3n - 6, 3n) Jacobian of ``constraints`` with respect to ``q``."""
        point, g = self._at(q), self.geometry
        J = np.zeros((3 * self.n - 6, self.n, 3))
        J[:g.distance_count] = g.distance_pattern * point.differences[:g.distance_count, None, :]
        if self.n > 3:
            # derivatives of (X_k - X_0) . (e1 x e2), e1 = X_1 - X_0, e2 = X_2 - X_0, as rows
            ek = point.differences[g.distance_count + 2:]
            d1 = ek @ _skew(point.differences[g.distance_count + 1]).T      # e2 x ek
            d2 = ek @ point.e1_skew                                          # ek x e1
            rows = g.coplanar_rows
            J[rows, 1], J[rows, 2], J[rows, g.coplanar_last] = d1, d2, point.face_normal
            J[rows, 0] = -(d1 + d2 + point.face_normal)
        return J.reshape(len(J), -1) @ point.d_position


@dataclass(frozen=True)
class _PolygonGeometry:
    """Constant structure of the unit-side regular n-gon's constraints and chart (see ``_PolygonFit``)."""
    differences: np.ndarray        # (2n - 3 + n - 1, n): X -> the 2n - 3 constrained pair differences
    distance_count: int            # X_first - X_second, then the n - 1 edges X_k - X_0 (k = 1..n-1)
    squared_lengths: np.ndarray    # (2n - 3,) the pairs' squared lengths (side units^2)
    distance_pattern: np.ndarray   # (2n - 3, n, 1) d|X_first - X_second|^2 / dX_i = pattern[i] (X_first - X_second)
    double_area: float             # twice the polygon's area (side units^2)
    next: np.ndarray               # (n,) index of the following / preceding vertex
    previous: np.ndarray
    coplanar_rows: np.ndarray      # (n - 3,) rows of the coplanarity constraints (k = 3..n-1)
    coplanar_last: np.ndarray      # (n - 3,) their vertex k
    chart_entries: np.ndarray      # (4n,) flat indices in dX/dq (3n, 3n) of the entries that depend on q:
                                   # per vertex (x, u), (y, v), (x, w), (y, w)
    depth_diagonal: np.ndarray     # (n,) index of each vertex's z (and w) in the flattened X (and q)


@functools.lru_cache(maxsize=None)
def _polygon_geometry(n):
    """``_PolygonGeometry`` of the regular n-gon of side 1."""
    pairs = [(k, (k + 1) % n) for k in range(n)] + [(0, k) for k in range(2, n - 1)]
    first, second = (np.array(index) for index in zip(*pairs))
    # chord between vertices i and j of a unit-side regular polygon: sin(pi |i-j| / n) / sin(pi / n)
    lengths = np.sin(np.pi * np.abs(first - second) / n) / np.sin(np.pi / n)
    differences = np.zeros((len(pairs) + n - 1, n))
    differences[np.arange(len(pairs)), first] = 1.0
    differences[np.arange(len(pairs)), second] = -1.0
    differences[np.arange(len(pairs), len(pairs) + n - 1), np.arange(1, n)] = 1.0
    differences[len(pairs):, 0] = -1.0
    index = np.arange(n)
    vertex_offsets = 3 * index[:, None]
    return _PolygonGeometry(differences, len(pairs), lengths ** 2, 2.0 * differences[:len(pairs), :, None],
                            n / (2.0 * math.tan(math.pi / n)), np.roll(index, -1), np.roll(index, 1),
                            np.arange(len(pairs), 3 * n - 6), np.arange(3, n),
                            ((vertex_offsets + [0, 1, 0, 1]) * 3 * n + vertex_offsets + [0, 1, 2, 2]).ravel(),
                            3 * index + 2)


# ----------------------------------------------------------------------------------------- output
def _invalidity(R, t, observation, model):
    """Why (R, t) is not an acceptable pose, or None if it is."""
    if not (np.isfinite(R).all() and np.isfinite(t).all()):
        return 'non-finite pose'
    points = _vertices_in_camera(R, t, model)
    if points[:, 2].min() <= 0:
        return f'object behind the camera (z = {t[2]:.4g} m)'
    if R[:, 2] @ t >= 0:
        return 'top face seen from below'
    residual = math.sqrt(_squared_error_px(points, observation) / model.n)
    limit = ABSURD_RESIDUAL_EDGE_FRACTION * observation.mean_edge_px
    if residual > limit:
        return f'residual {residual:.3g} px exceeds {limit:.3g} px (polygon does not fit the model)'
    return None


def _off_the_table(R, table_normal):
    """Why the top face of rotation R cannot be lying on the table of normal ``table_normal`` (None: no table), or None."""
    if table_normal is None:
        return None
    tilt = _angle_between(R[:, 2], table_normal)
    if tilt <= MAX_TILT_FROM_TABLE_RAD:
        return None
    return (f'top face tilted {math.degrees(tilt):.0f} deg from the table (more than '
            f'{math.degrees(MAX_TILT_FROM_TABLE_RAD):.0f}): not this block lying on the table')


def _make_estimate(R, t, observation, model, method, table_normal):
    """``PoseEstimate`` with the yaw representative, RMS residual and Gauss-Newton covariance."""
    points = _vertices_in_camera(R, t, model)      # in the observed order (before the symmetry turn)
    squared_error = _squared_error_px(points, observation)
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = canonical_rotation(R, model), t
    return PoseEstimate(T, math.sqrt(squared_error / model.n), method,
                        _covariance(points, R[:, 2], t, observation, squared_error, table_normal))


def _covariance(points, normal, t, observation, squared_error, table_normal):
    """(J^T J / sigma^2 + prior)^-1 for (dt, dtheta) in the camera frame; sigma from the residual, floored.

    ``points``: (n, 3) model vertices in the camera frame (m); ``normal``: the top face's normal.
    """
    n = len(points)
    inverse_depth = 1.0 / points[:, 2:]
    # d(ideal px)/d(point) = [fx/z, 0, -fx x/z^2; 0, fy/z, -fy y/z^2]; d(point)/d(dt, dtheta) = [I, -[R p]x]
    d_point = _AXES[:2] - (points[:, :2] * inverse_depth)[:, :, None] * _AXES[2]     # rows e_k - (x_k / z) e_z
    d_point *= (observation.focal_px * inverse_depth)[:, :, None]
    J = np.concatenate([d_point, d_point @ _skew(t - points)], axis=2).reshape(-1, 6)   # d_point @ -[R p]x
    redundancy = 2 * n - 6
    sigma2 = max(squared_error / redundancy if redundancy > 0 else 0.0, PIXEL_SIGMA_FLOOR_PX ** 2)
    information = J.T @ J / sigma2
    if table_normal is not None:
        d_normal = -_skew(normal) / TABLE_NORMAL_SIGMA_RAD       # d(R e_z)/d(dtheta) = -[R e_z]x
        information[3:, 3:] += d_normal.T @ d_normal
    try:
        covariance = np.linalg.inv(information)
    except np.linalg.LinAlgError:
        return None
    return covariance if np.isfinite(covariance).all() else None


def canonical_rotation(R, model):
    """R turned about the face normal by a symmetry multiple so its yaw lies in (-pi/n, pi/n] (``PoseEstimate``)."""
    yaw, reference = _yaw_about_normal(R)
    half = model.symmetry_angle / 2.0
    yaw = (yaw + half) % model.symmetry_angle - half        # [-pi/n, pi/n)
    if yaw <= -half + 1e-12:
        yaw += model.symmetry_angle
    return reference @ _rotz(yaw)


def _reference_frame(normal):
    """Rotation [x_ref, y_ref, normal]: x_ref = camera x projected onto the plane normal to ``normal``."""
    axis = _AXES[0] if abs(normal[0]) < 0.9 else _AXES[1]
    x_ref = axis - (axis @ normal) * normal
    x_ref /= math.sqrt(x_ref @ x_ref)
    return np.array([x_ref, _skew(normal) @ x_ref, normal]).T


def _yaw_about_normal(R):
    """(angle (rad) about R's z axis from the reference x axis to R's x axis, the reference frame)."""
    reference = _reference_frame(R[:, 2])
    cosine, sine = (R[:, 0] @ reference[:, :2]).tolist()
    return math.atan2(sine, cosine), reference


# ----------------------------------------------------------------------------------------- helpers
def _vertices_in_camera(R, t, model):
    """(n, 3) model vertices in the camera frame (m) for the pose (R, t)."""
    return model.vertices @ R.T + t


def _squared_error_px(points, observation):
    """Sum of squared reprojection errors (ideal px^2) of the (n, 3) model vertices in the camera frame (m)."""
    error = ((points[:, :2] / points[:, 2:] - observation.normalised) * observation.focal_px).ravel()
    return float(error @ error)


def _angle_between(a, b):
    """Angle (rad) between two 3-vectors."""
    cross = _skew(a) @ b
    return math.atan2(math.sqrt(cross @ cross), a @ b)


def _from_opencv(rvec, tvec):
    """(R_camera_block, t) from an OpenCV pose (rvec, tvec) of the flipped model (see ``_FLIP``)."""
    R_flipped, _ = cv2.Rodrigues(np.asarray(rvec, dtype=float).reshape(3, 1))
    return R_flipped * _FLIP, np.asarray(tvec, dtype=float).ravel()


def _kabsch_rotation(points, model_points):
    """Rotation R minimising sum |points_i - R model_points_i|^2 ((n, 3) arrays, both centred on the origin).

    The SVD solution of ``Rotation.align_vectors`` without its per-call overhead (about 60 us, against
    12 us): ``H = sum p_i m_i^T = U S V^T``, ``R = U diag(1, 1, det(U V^T)) V^T``.
    """
    u, _, vt = np.linalg.svd(points.T @ model_points)
    rotation = u @ vt
    if np.linalg.det(rotation) < 0:
        u[:, 2] = -u[:, 2]
        rotation = u @ vt
    return rotation


def _rotz(angle):
    c, s = math.cos(angle), math.sin(angle)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


_AXES = np.eye(3)   # e_x, e_y, e_z
# [e_c]x for c = x, y, z: [v]x = sum_c v_c [e_c]x
_UNIT_SKEWS = np.array([[[0.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]],
                        [[0.0, 0.0, 1.0], [0.0, 0.0, 0.0], [-1.0, 0.0, 0.0]],
                        [[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 0.0]]])


def _skew(v):
    """(..., 3, 3) cross-product matrices [v]x of (..., 3) vectors: [v]x @ w = v x w, and rows a @ [v]x = a x v."""
    return (v @ _UNIT_SKEWS.reshape(3, 9)).reshape(v.shape + (3,))
