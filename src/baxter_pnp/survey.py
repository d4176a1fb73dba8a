"""Table survey, pure: which part of the table the left gripper can reach looking straight down, and a short
tour of viewpoints whose hand-camera views together see it (issue 14).

Geometry (docs/survey.md). The table top is the level plane ``z = table_z`` (base, m) over the rectangle
``TableRect``; a *survey pose* is the gripper ``height`` m above the table top, pointing straight down
(``down_pose``: orientation ``Rz(yaw) Ry(pi)``, hand z = -base z; yaw 0 is config/start_poses.yaml's ``down``
orientation). A table point is *seen* from a pose when it projects into the camera image at least ``margin_px``
inside the border and more than ``margin_px`` from the pixels the open fingers hide (``view.hand_clearance_px``);
the margin is the *overlap*: ``overlap`` m on the table (about a block's half diagonal) converted to pixels at
the survey depth, so a block whose centre is seen is seen whole, and a block cut by one view's edge lies whole
in a neighbour's. Frames: ``T_base_gripper``, ``T_base_camera`` (camera optical frame in base),
``T_gripper_camera``; 4x4, metres, radians.

``reachable_table`` grids the table and keeps the cells over which a survey pose is IK-solvable;
``plan_survey`` chooses viewpoints greedily (largest newly seen reachable area first, among every reachable
gripper position and four yaws: the fingers' hidden region then falls where it costs least);
``order_viewpoints`` orders them for short travel (nearest neighbour + 2-opt); ``coverage`` measures, on a
finer grid than the planner's, the fraction of the reachable table seen; ``draw_coverage`` draws it.
"""
from typing import Callable, NamedTuple, Union

import numpy as np
from scipy.spatial.distance import cdist
from scipy.spatial.transform import Rotation

from baxter_pnp.transforms import invert, transform_points

SURVEY_HEIGHT = 0.29        # m, gripper tip above the table top: the 'down' start pose's (camera ~0.43 m up)
OVERLAP = 0.03              # m on the table: a 5 cm block's half diagonal is 0.035 m, a 4 cm one's 0.028 m
YAWS = (0.0, 0.5 * np.pi, np.pi, -0.5 * np.pi)      # rad: the survey poses' candidate yaws about base +z


class TableRect(NamedTuple):
    """The table top's rectangle in base (m): ``x_min`` .. ``x_max`` by ``y_min`` .. ``y_max``."""
    x_min: float
    y_min: float
    x_max: float
    y_max: float

    @classmethod
    def of(cls, center, size):
        """The rectangle of centre ``center`` (x, y) and ``size`` (x, y), m (as ``sim.scene.Table``)."""
        (cx, cy), (sx, sy) = center, size
        return cls(cx - sx / 2.0, cy - sy / 2.0, cx + sx / 2.0, cy + sy / 2.0)

    @property
    def area(self):
        """m^2."""
        return (self.x_max - self.x_min) * (self.y_max - self.y_min)

    def grid(self, cell):
        """(xs, ys): centres (m) of the square cells of side about ``cell`` m tiling the rectangle."""
        nx = max(1, int(round((self.x_max - self.x_min) / cell)))
        ny = max(1, int(round((self.y_max - self.y_min) / cell)))
        xs = self.x_min + (np.arange(nx) + 0.5) * (self.x_max - self.x_min) / nx
        ys = self.y_min + (np.arange(ny) + 0.5) * (self.y_max - self.y_min) / ny
        return xs, ys

    def expanded(self, pad):
        """The rectangle grown by ``pad`` m on every side."""
        return TableRect(self.x_min - pad, self.y_min - pad, self.x_max + pad, self.y_max + pad)


DEFAULT_TABLE = TableRect.of((0.75, 0.0), (0.9, 1.5))    # sim.scene.Table's defaults
DEFAULT_TABLE_Z = -0.15                                   # m, its top


class ReachableGrid(NamedTuple):
    """Grid cells (centres ``xs`` (nx,), ``ys`` (ny,), m in base) and ``mask`` (ny, nx) bool: a survey pose
    ``height`` m above ``table_z`` over the cell centre is IK-solvable; ``joints`` (ny, nx, 7) rad (NaN where
    not, or where the reachability came from a predicate)."""
    xs: np.ndarray
    ys: np.ndarray
    mask: np.ndarray
    joints: np.ndarray
    height: float
    table_z: float

    @property
    def cell(self):
        """Cell pitch (m) along x (and y)."""
        return float(self.xs[1] - self.xs[0]) if len(self.xs) > 1 else float('nan')

    def points(self):
        """(M, 2) centres (m) of the reachable cells."""
        X, Y = np.meshgrid(self.xs, self.ys)
        return np.column_stack([X[self.mask], Y[self.mask]])

    def contains(self, xy):
        """(N,) bool: the points ``xy`` (N, 2) fall in a reachable cell (nearest cell; outside the grid: False)."""
        xy = np.atleast_2d(np.asarray(xy, dtype=float))
        half_x = 0.5 * (self.xs[1] - self.xs[0]) if len(self.xs) > 1 else np.inf
        half_y = 0.5 * (self.ys[1] - self.ys[0]) if len(self.ys) > 1 else np.inf
        i = np.clip(np.searchsorted(self.xs - half_x, xy[:, 0]) - 1, 0, len(self.xs) - 1)
        j = np.clip(np.searchsorted(self.ys - half_y, xy[:, 1]) - 1, 0, len(self.ys) - 1)
        inside = ((xy[:, 0] >= self.xs[0] - half_x) & (xy[:, 0] <= self.xs[-1] + half_x)
                  & (xy[:, 1] >= self.ys[0] - half_y) & (xy[:, 1] <= self.ys[-1] + half_y))
        return inside & self.mask[j, i]


def down_pose(xy, z, yaw=0.0):
    """T_base_gripper (4x4): gripper tip at (x, y, z) m pointing straight down, turned ``yaw`` rad about base +z
    (yaw 0: hand y = base y, as config/start_poses.yaml's ``down``)."""
    T = np.eye(4)
    T[:3, :3] = (Rotation.from_euler('z', yaw) * Rotation.from_euler('y', np.pi)).as_matrix()
    T[:3, 3] = [xy[0], xy[1], z]
    return T


def pose_yaw(T_base_gripper):
    """Yaw (rad) of a straight-down gripper pose (inverse of ``down_pose``)."""
    R = T_base_gripper[:3, :3] @ Rotation.from_euler('y', np.pi).as_matrix().T
    return float(np.arctan2(R[1, 0], R[0, 0]))


Reach = Union[Callable[[np.ndarray], bool], object]      # a predicate on T_base_gripper, or an ArmKinematics


def reachable_table(table_rect, kinematics, height=SURVEY_HEIGHT, table_z=DEFAULT_TABLE_Z, cell=0.05, yaw=0.0,
                    start_xy=(0.65, 0.25), n_random_seeds=2):
    """The ``ReachableGrid`` of ``table_rect`` (a ``TableRect``; pass ``.expanded(pad)`` for gripper positions
    beside the table) at cell pitch ``cell`` m: cells over which ``down_pose(centre, table_z + height, yaw)`` is
    reachable.

    ``kinematics`` is an ``ArmKinematics`` (IK-solvable: a flood fill from the cell nearest ``start_xy``, each
    cell's IK seeded with a solved neighbour's angles, so the result is one connected region of continuous
    solutions; ``n_random_seeds`` random restarts per cell besides) or a predicate ``reachable(T_base_gripper)``.
    The wrist's w2 turns about +-175 deg, so reachability at one ``yaw`` is, but for a sliver, reachability at all.
    """
    xs, ys = table_rect.grid(cell)
    z = table_z + height
    mask = np.zeros((len(ys), len(xs)), dtype=bool)
    joints = np.full((len(ys), len(xs), 7), np.nan)
    if callable(kinematics):
        for j, y in enumerate(ys):
            for i, x in enumerate(xs):
                mask[j, i] = bool(kinematics(down_pose((x, y), z, yaw)))
        return ReachableGrid(xs, ys, mask, joints, float(height), float(table_z))
    tried = np.zeros_like(mask)
    start = (int(np.argmin(np.abs(ys - start_xy[1]))), int(np.argmin(np.abs(xs - start_xy[0]))))
    frontier = [(start, None)]
    while frontier:
        (j, i), seed = frontier.pop()
        if tried[j, i]:
            continue
        tried[j, i] = True
        q = kinematics.ik(down_pose((xs[i], ys[j]), z, yaw), seed=seed, n_random_seeds=n_random_seeds)
        if q is None:
            continue
        mask[j, i], joints[j, i] = True, q
        for dj, di in ((1, 0), (-1, 0), (0, 1), (0, -1)):
            jj, ii = j + dj, i + di
            if 0 <= jj < len(ys) and 0 <= ii < len(xs) and not tried[jj, ii]:
                frontier.append(((jj, ii), q))
    return ReachableGrid(xs, ys, mask, joints, float(height), float(table_z))


def margin_px(camera, depth, overlap=OVERLAP):
    """The image margin (px) of ``overlap`` m on a plane ``depth`` m in front of ``camera`` (mean focal length)."""
    return float(overlap * 0.5 * (camera.fx + camera.fy) / depth)


def seen(T_base_camera, points_base, camera, clearance_px, margin=0.0):
    """(N,) bool: the points (N, 3) in base project into ``camera``'s image (``CameraModel``, distorted pixels) at
    least ``margin`` px inside the border, in front of the camera, at a pixel more than ``margin`` px from the
    pixels the fingers hide (``clearance_px``, ``view.hand_clearance_px``; None: no hand)."""
    points_camera = transform_points(invert(T_base_camera), np.asarray(points_base, dtype=float))
    front = points_camera[:, 2] > 1e-6
    result = np.zeros(len(points_camera), dtype=bool)
    if not np.any(front):
        return result
    normalised = points_camera[front, :2] / points_camera[front, 2:3]
    pixels = camera.project(points_camera[front])
    inside = ((pixels[:, 0] >= margin) & (pixels[:, 0] <= camera.width - 1 - margin)
              & (pixels[:, 1] >= margin) & (pixels[:, 1] <= camera.height - 1 - margin))
    if clearance_px is not None:
        u = np.clip(np.round(pixels[:, 0]).astype(int), 0, camera.width - 1)
        v = np.clip(np.round(pixels[:, 1]).astype(int), 0, camera.height - 1)
        inside &= clearance_px[v, u] > margin
    # far outside the image the distortion polynomial folds back: keep only the pixels that undistort to the point
    round_trip = camera.undistort_points(pixels[inside])
    inside[np.flatnonzero(inside)] = np.linalg.norm(round_trip - normalised[inside], axis=1) < 1e-4
    result[np.flatnonzero(front)] = inside
    return result


def _plane_points(xy, z):
    xy = np.atleast_2d(np.asarray(xy, dtype=float))
    return np.column_stack([xy, np.full(len(xy), z)])


def _table_cells(table_rect, reachable, cell):
    """(M, 2) centres (m) of the cells of pitch ``cell`` of ``table_rect`` inside the reachable region."""
    xs, ys = table_rect.grid(cell)
    X, Y = np.meshgrid(xs, ys)
    xy = np.column_stack([X.ravel(), Y.ravel()])
    return xy[reachable.contains(xy)]


def plan_survey(table_rect, table_z, camera, T_gripper_camera, clearance_px, reach, height=SURVEY_HEIGHT,
                overlap=OVERLAP, goal=0.98, max_views=12, plan_cell=0.02, reach_cell=0.05, reach_pad=0.15,
                yaws=YAWS, table_reach=None):
    """Viewpoints (a list of ``T_base_gripper``, in the greedy order: most new area first) looking straight down
    from ``height`` m above the table top whose views together see a fraction ``goal`` of the reachable table.

    ``table_rect`` (``TableRect``) at ``table_z`` (m); ``camera`` the hand camera's ``CameraModel``,
    ``T_gripper_camera`` its pose in the gripper frame, ``clearance_px`` the fingers' map in its image
    (``view.hand_clearance_px``); ``reach`` an ``ArmKinematics`` or a predicate on ``T_base_gripper``. The
    reachable table (``table_reach``: a ``ReachableGrid`` of ``table_rect``, computed at ``reach_cell`` when
    None) is sampled at ``plan_cell`` m; candidates are every gripper position reachable over the table grown
    by ``reach_pad`` m, times ``yaws``; each step takes the candidate seeing the most unseen reachable points
    (its yaw puts the fingers' blind spot where it costs least) whose pose is IK-solvable, until ``goal`` or
    ``max_views`` or no gain. Seen: ``seen`` with a margin of ``overlap`` m on the table.
    """
    if table_reach is None:
        table_reach = reachable_table(table_rect, reach, height, table_z, reach_cell)
    targets = _plane_points(_table_cells(table_rect, table_reach, plan_cell), table_z)
    positions = reachable_table(table_rect.expanded(reach_pad), reach, height, table_z, reach_cell).points() \
        if reach_pad > 0 else table_reach.points()
    z = table_z + height
    depth = float((down_pose((0.0, 0.0), z) @ T_gripper_camera)[2, 3] - table_z)    # camera above the table, m
    margin = margin_px(camera, depth, overlap)
    candidates = [down_pose(xy, z, yaw) for xy in positions for yaw in yaws]
    views = np.array([seen(T @ T_gripper_camera, targets, camera, clearance_px, margin) for T in candidates])
    covered = np.zeros(len(targets), dtype=bool)
    usable = np.ones(len(candidates), dtype=bool)
    chosen, seed = [], None
    while len(chosen) < max_views and covered.mean() < goal and usable.any():
        gains = np.where(usable, (views & ~covered).sum(axis=1), -1)
        best = int(np.argmax(gains))
        if gains[best] <= 0:
            break
        usable[best] = False
        T = candidates[best]
        if not callable(reach):
            q = reach.ik(T, seed=seed)
            if q is None:
                continue
            seed = q
        elif not reach(T):
            continue
        chosen.append(T)
        covered |= views[best]
    return chosen


def path_length(viewpoints, start=None):
    """Travel (m) of the gripper tip through ``viewpoints`` (4x4 poses) in order, from ``start`` (3,) if given."""
    points = [np.asarray(start, dtype=float)] if start is not None else []
    points += [T[:3, 3] for T in viewpoints]
    if len(points) < 2:
        return 0.0
    return float(np.sum(np.linalg.norm(np.diff(points, axis=0), axis=1)))


def order_viewpoints(viewpoints, start=None):
    """``viewpoints`` reordered for a short open path from ``start`` ((3,) m, e.g. the current gripper position;
    None: free start): nearest neighbour, then 2-opt until no reversal shortens it."""
    n = len(viewpoints)
    if n < 2:
        return list(viewpoints)
    points = np.array([T[:3, 3] for T in viewpoints])
    anchored = start is not None
    if anchored:
        points = np.vstack([np.asarray(start, dtype=float), points])
    D = cdist(points, points)
    first = 0 if anchored else int(np.argmin(D.sum(axis=1)))
    order, left = [first], set(range(len(points))) - {first}
    while left:
        nxt = min(left, key=lambda k: D[order[-1], k])
        order.append(nxt)
        left.remove(nxt)
    improved = True
    fixed = 1 if anchored else 0
    while improved:
        improved = False
        for a in range(fixed, len(order) - 1):
            for b in range(a + 1, len(order)):
                # reverse order[a..b]: edges (a-1, a) and (b, b+1) become (a-1, b) and (a, b+1)
                before = (D[order[a - 1], order[a]] if a > 0 else 0.0) + \
                         (D[order[b], order[b + 1]] if b + 1 < len(order) else 0.0)
                after = (D[order[a - 1], order[b]] if a > 0 else 0.0) + \
                        (D[order[a], order[b + 1]] if b + 1 < len(order) else 0.0)
                if after < before - 1e-12:
                    order[a:b + 1] = order[a:b + 1][::-1]
                    improved = True
    if anchored:
        return [viewpoints[k - 1] for k in order[1:]]
    return [viewpoints[k] for k in order]


def coverage(viewpoints, table_rect, table_z, camera, T_gripper_camera, clearance_px, table_reach,
             overlap=OVERLAP, cell=0.005, return_masks=False):
    """Fraction of the reachable table (``table_reach``, a ``ReachableGrid`` of ``table_rect``) seen from the
    ``viewpoints`` (``T_base_gripper`` s), on a grid of pitch ``cell`` m (finer than the planner's): a point is
    seen when ``seen`` (margin ``overlap`` m on the table at each view's own depth) holds from one view.
    With ``return_masks``: (fraction, xs, ys, reachable (ny, nx), seen (ny, nx), per-view seen (V, ny, nx))."""
    xs, ys = table_rect.grid(cell)
    X, Y = np.meshgrid(xs, ys)
    xy = np.column_stack([X.ravel(), Y.ravel()])
    reachable = table_reach.contains(xy)
    points = _plane_points(xy, table_z)
    per_view = []
    for T in viewpoints:
        T_base_camera = T @ T_gripper_camera
        depth = float(T_base_camera[2, 3] - table_z)
        per_view.append(seen(T_base_camera, points, camera, clearance_px, margin_px(camera, depth, overlap)))
    per_view = np.array(per_view).reshape(len(viewpoints), len(xy))
    seen_any = per_view.any(axis=0) if len(viewpoints) else np.zeros(len(xy), dtype=bool)
    fraction = float((seen_any & reachable).sum() / max(1, reachable.sum()))
    if not return_masks:
        return fraction
    shape = X.shape
    return (fraction, xs, ys, reachable.reshape(shape), seen_any.reshape(shape),
            per_view.reshape((len(viewpoints),) + shape))


def draw_coverage(path, viewpoints, table_rect, table_z, camera, T_gripper_camera, clearance_px, table_reach,
                  overlap=OVERLAP, cell=0.005, start=None, title=None):
    """Draw the survey into the image file ``path`` (matplotlib, top view of base, x up the page as seen from
    behind the robot: base y to the left): the table, the reachable area, each view's seen footprint (outline),
    what no view sees (red), the viewpoints in order, an arrow toward each image's top (the fingers' side) and
    the path. Returns the coverage fraction."""
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt

    fraction, xs, ys, reachable, seen_any, per_view = coverage(
        viewpoints, table_rect, table_z, camera, T_gripper_camera, clearance_px, table_reach, overlap, cell,
        return_masks=True)
    # image rows = x (far at the top), columns = y (flipped by the axis limits: base +y to the left)
    extent = (table_rect.y_min, table_rect.y_max, table_rect.x_min, table_rect.x_max)
    rgb = np.ones(reachable.shape + (3,))
    rgb[reachable & seen_any] = (0.70, 0.88, 0.70)
    rgb[reachable & ~seen_any] = (0.95, 0.35, 0.30)
    rgb[~reachable & seen_any] = (0.88, 0.88, 0.88)
    rgb[~reachable & ~seen_any] = (0.97, 0.97, 0.97)
    fig, ax = plt.subplots(figsize=(7.5, 5.6), dpi=110)
    ax.imshow(rgb.transpose(1, 0, 2), origin='lower', extent=extent, interpolation='nearest')
    colours = plt.cm.tab10(np.linspace(0, 1, 10))
    for k, mask in enumerate(per_view):
        ax.contour(ys, xs, mask.T.astype(float), levels=[0.5], colors=[colours[k % 10]], linewidths=1.2)
    points = np.array([T[:3, 3] for T in viewpoints]).reshape(-1, 3)
    path_points = points if start is None else np.vstack([start, points])
    ax.plot(path_points[:, 1], path_points[:, 0], '-', color='0.25', linewidth=1.0)
    for k, (T, p) in enumerate(zip(viewpoints, points)):
        up = -(T @ T_gripper_camera)[:3, 1]         # the image's top (where the fingers are) on the table
        ax.plot(p[1], p[0], 'o', color=colours[k % 10], markersize=5)
        ax.annotate(str(k + 1), (p[1], p[0]), textcoords='offset points', xytext=(4, 4), fontsize=8)
        ax.arrow(p[1], p[0], 0.05 * up[1], 0.05 * up[0], width=0.002, color=colours[k % 10])
    if start is not None:
        ax.plot(start[1], start[0], 's', color='k', markersize=5)
    ax.set_xlim(table_rect.y_max + 0.05, table_rect.y_min - 0.05)
    ax.set_ylim(table_rect.x_min - 0.25, table_rect.x_max + 0.05)
    ax.set_xlabel('base y (m)')
    ax.set_ylabel('base x (m)')
    ax.set_aspect('equal')
    ax.set_title(title or '%d views, %.1f %% of the reachable table seen, path %.2f m'
                 % (len(viewpoints), 100 * fraction, path_length(viewpoints, start)), fontsize=9)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)
    return fraction


def hand_camera_setup(kinematics, camera):
    """(T_gripper_camera, clearance_px) of ``camera`` (e.g. the robot's 640x400 hand camera model) on the arm of
    ``kinematics``: the URDF's camera mount and ``view.hand_clearance_px`` of its open fingers."""
    from baxter_pnp import view
    T_gripper_camera = kinematics.relative(f'{kinematics.side}_gripper', f'{kinematics.side}_hand_camera')
    return T_gripper_camera, view.hand_clearance_of(kinematics, T_gripper_camera, camera)
