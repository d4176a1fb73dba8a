"""The pick-and-place task, pure: block pose and arm pose in -> next arm target (or camera twist) out.

No ROS here (``pick_app.py`` sequences it on the task layer, ``baxter_pnp.task``). Frames: ``base``
(Baxter's), ``gripper`` (the ``<side>_gripper`` tip frame: z along the fingers, fingers close along y), ``camera`` (the hand
camera's optical frame), ``block`` (docs/ARCHITECTURE.md: origin at the top-face centre, z up).
Metres, radians, pixels.

The approach ends at the *hover* pose: the gripper centred over the block, fingers pointing down,
aligned to the block's faces, ``hover_height`` above the *grasp* pose (fingertips ``grasp_depth``
below the top face), to which the arm then descends and closes.
"""
import math
from dataclasses import asdict, dataclass, field
from typing import List, NamedTuple, Optional

import numpy as np
from scipy.spatial.transform import Rotation

from baxter_pnp import models, servo, view
from baxter_pnp.params import Parameters
from baxter_pnp.transforms import invert, make_transform, pose_error, transform_points

MODES = ('pbvs', 'ibvs', 'hybrid')


@dataclass
class PickConfig(Parameters):
    """What to pick and how (metres, radians, pixels): the pure task's parameters. The robot session's (arm,
    camera mode, table height, timeouts, outputs) are ``task.settings.SessionConfig``; one YAML holds both:
    config/pick_square.yaml."""

    shape: str = 'square'                   # target shape (triangle, square, pentagon, hexagon)
    side_length: float = 0.04               # block side (m)
    block_height: float = 0.02              # block height (m)
    edge_radius: float = 0.0                # radius the blocks' top edges are rounded over (m; dice, worn cubes)
    colour: str = 'green'                   # a colour name of config/vision.yaml
    mode: str = 'pbvs'                      # pbvs (thesis look-and-move) | ibvs | hybrid (2.5D)
    step_fraction: float = 0.35             # PBVS: fraction of the remaining displacement per step (thesis 0.35, 0.12)
    start_pose: str = 'down'                # a name in config/start_poses.yaml (down, angled, neutral)
    hover_height: float = 0.06              # the pre-grasp (hover) pose is this far above the grasp pose (m)
    grasp_depth: float = 0.012              # fingertips below the top face when closing (m)
    position_tolerance: float = 0.002       # pre-grasp reached when the estimated error is below this (m) ...
    yaw_tolerance: float = math.radians(2.0)    # ... and the orientation error below this (rad)
    snap_distance: float = 0.01             # PBVS: below this remaining error (m) the last step goes all the way
    max_step_translation: float = 0.10      # PBVS: bound on one step (m), keeps the block in view
    max_step_rotation: float = math.radians(30.0)   # PBVS: bound on one step (rad)
    view_margin_px: float = 15.0            # the block's vertices stay this far inside the image after a step
    max_steps: int = 40                     # PBVS steps / IBVS-hybrid iterations x 10 before giving up
    backoff_height: float = 0.05            # re-acquisition: move up this much when the block is lost (m)
    max_lost: int = 4                       # consecutive looks without the block before giving up
    survey: bool = True                     # a block never seen, or lost and not re-acquired: survey the table
                                            # (task.survey) and approach it from the map; false: the thesis's way
    lift_height: float = 0.10               # lift after the grasp (m)
    place_xy: Optional[List[float]] = None  # put the block down at this table position (base x, y; m)
    place_clearance: float = 0.004          # release the block this far above the table (m)
    max_grasp_attempts: int = 2             # re-servo and regrasp after a miss
    estimator: str = 'sqp'                  # pose estimator: sqp | ippe | sqpnp
    gain: List[float] = field(default_factory=lambda: [1.5, 0.4, 10.0])  # IBVS/hybrid adaptive gain (l0, linf, l0')
    max_linear_speed: float = 0.08          # IBVS/hybrid: camera speed bound (m/s)
    max_angular_speed: float = 0.5          # IBVS/hybrid: camera angular speed bound (rad/s)
    feature_tolerance_px: float = 2.0       # IBVS/hybrid: converged when the RMS feature error is below this (px)
    view_depth: float = 0.30                # IBVS/hybrid first goal: the block centre this far from the camera (m) ...
    view_row_fraction: float = 0.75         # ... at this fraction of the image height (below the fingers' image)
    view_tolerance_px: float = 8.0          # ... reached when the RMS feature error is below this (px)
    stall_time: float = 3.0                 # IBVS/hybrid: a feature error not down by stall_progress within this
    stall_progress: float = 0.1             # robot time (s) is a stall, followed by one PBVS step (0: never)
    max_predicted_looks: int = 10           # IBVS/hybrid: looks in a row without the block believably in view that
                                            # the law goes on through, on its last estimate (0: re-acquire at once)
    max_residual_px: float = 2.0            # estimates with a larger RMS reprojection error are not trusted (occlusion)
    max_height_error: float = 0.02          # ... nor those putting a block on the table this far off its height (m)
    far_height_error: float = 0.08          # ... or, for an estimate uncertain along z, 3 of its std up to this (m):
                                            # a 15-25 px block's size fixes its depth to 1-3 cm (task.target)
    table_height_sigma: float = 0.005       # how well the table top's height is known (m; table_top_z, hand-eye): a
                                            # believed target's position is updated with it (task.target.on_the_table;
                                            # 0: off)
    gripper_gap: List[float] = field(default_factory=lambda: list(ELECTRIC_GRIPPER_GAP))   # the electric gripper's
                                            # jaw gap closed and fully open (m): its fingers' slot (grasp_width)

    def validate(self):
        require = self.require
        require(self.shape in models.SHAPES, 'shape', 'must be one of %s' % sorted(models.SHAPES))
        require(self.mode in MODES, 'mode', 'must be one of %s' % (MODES,))
        self.require_positive('side_length', 'block_height', 'hover_height', 'position_tolerance', 'yaw_tolerance',
                              'max_step_translation', 'max_step_rotation', 'lift_height', 'backoff_height',
                              'max_linear_speed', 'max_angular_speed', 'feature_tolerance_px', 'view_depth',
                              'view_tolerance_px', 'max_residual_px', 'max_height_error', 'max_steps', 'stall_time',
                              'max_grasp_attempts')
        require(0.0 < self.step_fraction <= 1.0, 'step_fraction', 'must be in (0, 1]')
        require(0.0 < self.view_row_fraction < 1.0, 'view_row_fraction', 'must be in (0, 1)')
        require(0.0 <= self.stall_progress < 1.0, 'stall_progress', 'must be in [0, 1)')
        require(0.0 <= self.grasp_depth < self.block_height, 'grasp_depth', 'must be in [0, block_height)')
        try:                                    # every shape: the table task's looks pose any of them
            models.check_edge_radius(self.side_length, self.block_height, self.edge_radius)
        except ValueError as exc:
            require(False, 'edge_radius', str(exc))
        require(self.far_height_error >= self.max_height_error, 'far_height_error', 'must be >= max_height_error')
        require(self.max_lost >= 0, 'max_lost', 'must be >= 0')
        require(self.max_predicted_looks >= 0, 'max_predicted_looks', 'must be >= 0')
        require(math.isfinite(self.table_height_sigma) and self.table_height_sigma >= 0.0, 'table_height_sigma',
                'must be >= 0 m (0: off)')
        require(self.place_xy is None or (len(self.place_xy) == 2 and all(map(math.isfinite, self.place_xy))),
                'place_xy', 'must be [x, y] in metres or null')
        require(len(self.gain) == 3 and self.gain[0] >= self.gain[1] > 0, 'gain',
                'must be [gain at 0, gain at infinity, slope at 0] with gain at 0 >= gain at infinity > 0')
        require(self.estimator in ('sqp', 'ippe', 'sqpnp'), 'estimator', 'must be sqp, ippe or sqpnp')
        require(len(self.gripper_gap) == 2 and all(map(math.isfinite, self.gripper_gap))
                and 0.0 <= self.gripper_gap[0] < self.gripper_gap[1], 'gripper_gap',
                'must be [closed, open] jaw gaps in metres, 0 <= closed < open')
        width = grasp_width(self.side_length, self.model.symmetry_angle)
        closed, opened = self.gripper_gap
        require(width >= closed + GRIP_SQUEEZE_M, 'side_length',
                'a %s of side %.4f m is %.4f m across the fingers, less than the gripper closed (%.4f m) plus the '
                '%.0f mm the pads need to grip: the fingers would close past it (move them to a narrower slot and '
                'set gripper_gap, README "On a real Baxter")' % (self.shape, self.side_length, width, closed,
                                                                  1000 * GRIP_SQUEEZE_M))
        require(width <= opened, 'side_length', 'a %s of side %.4f m is %.4f m across the fingers, more than the '
                'gripper opens (%.4f m)' % (self.shape, self.side_length, width, opened))

    @property
    def model(self):
        """The block's model (``models.PolygonModel``): its sharp geometry, for grasps and places."""
        return models.model_for(self.shape, self.side_length, self.block_height)

    @property
    def seen_model(self):
        """The block's top face as the camera sees it (``models.seen_model``: inset for a rounded top rim), for the
        image features the servo laws and the predictions compare with detections."""
        return models.seen_model(self.shape, self.side_length, self.block_height, self.edge_radius)


@dataclass
class StepRecord:
    """One servo step or iteration, for the log line, the result JSON and the plots."""

    step: int
    time_s: float                 # robot time since the approach started (s)
    error_mm: float               # estimated distance of the gripper to the hover pose (mm)
    error_deg: float              # estimated orientation error to the hover pose (deg)
    error_px: float               # image distance of the block's centre to where it is at the hover pose (px)
    depth_m: float                # estimated depth of the block's top face (m)
    block_base_xyz: List[float]   # estimated block position in base (m)
    block_in_gripper_mm: List[float]  # estimated block centre in the gripper frame (mm): the thesis's x, y errors
    position_std_mm: Optional[float] = None   # the estimate's std along its least certain direction (mm)
    pose_method: Optional[str] = None         # what posed it: sqp | ippe | sqpnp | on_table | silhouette | predicted


@dataclass
class PickResult:
    """Outcome of a run (the ``--result-json`` content)."""

    success: bool
    mode: str
    time_s: float = 0.0                         # robot time from the first look to the verified grasp (s)
    steps: int = 0
    final_error_mm_est: Optional[float] = None  # estimated gripper-to-hover error when the descent started (mm)
    failure_reason: Optional[str] = None
    grasp_attempts: int = 0
    placed: Optional[bool] = None
    place_error_mm_est: Optional[float] = None  # block's distance from place_xy seen after placing (mm)
    total_time_s: float = 0.0                   # robot time of the whole run, place included (s)
    history: List[StepRecord] = field(default_factory=list)

    def to_json(self):
        d = asdict(self)
        d['history'] = [asdict(h) for h in self.history]
        return d


# ----------------------------------------------------------------------------------------------- geometry

# Jaw gap (m) of the electric gripper with the simulator's fingers (extended_narrow, slot 2, paddle tips), closed and
# fully open: 0.016 + 2 q, q the finger joint's 0-0.020833 m (shared/reference/baxter_kinematics.md section 3); each
# slot nearer the middle closes 19 mm narrower (slot 1: 0-0.0387 m).
ELECTRIC_GRIPPER_GAP = (0.016, 0.0577)
ELECTRIC_GRIPPER_MAX_OPENING = ELECTRIC_GRIPPER_GAP[1]
# m: a block must hold the pads this much wider apart than closed to be gripped: their compliance (2 mm over both in
# the fake, urdf/baxter.urdf's contact stiffness) and the gripper's closed reading (2 % of the travel: 0.8 mm). In the
# fake a 19 mm square grips, an 18.4 mm one does not (docs/trials.md, session 27).
GRIP_SQUEEZE_M = 0.003
MIN_GRIP_DEPTH = 0.003   # m: a grasp raised to the table's safety floor still closes this far below the top face


def grasp_width(side_length, symmetry_angle):
    """Jaw gap (m) needed to grasp a regular polygonal prism across the block's x axis.

    Even n: across two parallel faces, ``2 * apothem``; odd n: from a face to the opposite vertex,
    ``apothem + circumradius``. ``n = 2 pi / symmetry_angle``.
    """
    n = int(round(2.0 * np.pi / symmetry_angle))
    apothem = side_length / (2.0 * np.tan(np.pi / n))
    circumradius = side_length / (2.0 * np.sin(np.pi / n))
    return 2.0 * apothem if n % 2 == 0 else apothem + circumradius


def grasp_goal(T_base_block, side_length, grasp_depth, approach_height, symmetry_angle, T_base_gripper_current,
               max_opening=ELECTRIC_GRIPPER_MAX_OPENING):
    """Gripper pose (``left_gripper`` in base) to grasp the block, or to hover above it.

    - Gripper z = -block z (fingers pointing down, toward the table).
    - Fingers close along the block's x axis (the normal of the face perpendicular to +x, see the
      block frame in docs/ARCHITECTURE.md) or one of its symmetric copies: the block is invariant under
      rotations by ``symmetry_angle`` (2 pi / n, rad) about its z and a parallel-jaw gripper under
      pi about its own z, so the candidate yaws are ``k * symmetry_angle`` and ``k * symmetry_angle + pi``.
      The candidate with the smallest rotation from ``T_base_gripper_current`` is chosen (the thesis
      kept the start orientation instead, which caused occlusion and collisions).
    - Origin (fingertip plane) ``grasp_depth`` (m) below the top face's centre, then raised by
      ``approach_height`` (m) along the block's z (0 for the grasp itself, > 0 for a pre-grasp pose).

    ``side_length`` (m) gives the jaw gap needed (``grasp_width``); a ``ValueError`` is raised if it
    exceeds ``max_opening`` (m; None disables the check).
    """
    width = grasp_width(side_length, symmetry_angle)
    if max_opening is not None and width > max_opening:
        raise ValueError('block of side %.3f m needs a %.3f m jaw gap, more than the gripper opening %.3f m'
                         % (side_length, width, max_opening))
    best = grasp_orientations(T_base_block, symmetry_angle, T_base_gripper_current)[0]
    position = T_base_block[:3, 3] + T_base_block[:3, 2] * (approach_height - grasp_depth)
    return make_transform(best, position)


def grasp_orientations(T_base_block, symmetry_angle, T_base_gripper_current):
    """The distinct gripper orientations (``Rotation`` s, base) that grasp the block across a pair of faces
    (see :func:`grasp_goal`), the smallest rotation from ``T_base_gripper_current`` first."""
    R_base_block = Rotation.from_matrix(T_base_block[:3, :3])
    # gripper x = block y, gripper y = block x (closing axis), gripper z = -block z
    R_block_gripper = Rotation.from_euler('z', np.pi / 2) * Rotation.from_euler('x', np.pi)
    n = int(round(2.0 * np.pi / symmetry_angle))
    yaws = np.concatenate([np.arange(n) * symmetry_angle, np.arange(n) * symmetry_angle + np.pi])
    R_current = Rotation.from_matrix(T_base_gripper_current[:3, :3])
    candidates = []
    for R in sorted((R_base_block * Rotation.from_euler('z', yaw) * R_block_gripper for yaw in yaws),
                    key=lambda R: (R_current.inv() * R).magnitude()):
        if all((R.inv() * other).magnitude() > 1e-6 for other in candidates):
            candidates.append(R)
    return candidates


def hover_pose(T_base_block, config, T_base_gripper):
    """Pre-grasp gripper pose: centred ``hover_height`` above the block, faces aligned (grasp_goal)."""
    model = config.model
    return grasp_goal(T_base_block, config.side_length, config.grasp_depth, config.hover_height,
                            model.symmetry_angle, T_base_gripper)


def grasp_pose(T_base_block, config, T_base_gripper, floor_z=None):
    """Gripper pose to close at: fingertips ``grasp_depth`` below the top face, faces aligned; raised to ``floor_z``
    (m, base z; None: no floor) where that is lower and still ``MIN_GRIP_DEPTH`` below the top face: a block
    estimated a few millimetres lower than it stands is still gripped above the table's safety margin instead of
    refused (the fingers close on its sides); deeper, the pose stays below the floor, for the safety check to refuse."""
    T_grasp = grasp_goal(T_base_block, config.side_length, config.grasp_depth, 0.0,
                         config.model.symmetry_angle, T_base_gripper, max_opening=config.gripper_gap[1])
    if floor_z is not None and T_grasp[2, 3] < floor_z <= T_base_block[2, 3] - MIN_GRIP_DEPTH:
        T_grasp[2, 3] = floor_z
    return T_grasp


def converged(T_current, T_goal, config):
    translation, rotation = pose_error(T_current, T_goal)
    return translation <= config.position_tolerance and rotation <= config.yaw_tolerance


BLOCKED_STEP_FRACTION = 0.05     # a PBVS step toward the view pose kept this short by the view is blocked


def pbvs_target(T_base_gripper, T_base_hover, T_base_block, config, camera, T_gripper_camera, clearance_px=None,
                view_depth=None, position_std=None, reachable=None):
    """Next gripper pose of the look-and-move PBVS (the thesis's law, with its failures fixed), and the goal
    it steps toward.

    Moves ``step_fraction`` of the remaining displacement toward the goal, bounded in translation and
    rotation, and shortened so that the block's vertices stay ``view_margin_px`` inside the image and,
    given the hand's ``clearance_px`` map (``view.hand_clearance_px``), clear of the fingers after the move
    (``view.keep_in_view_step``). Within ``snap_distance`` of the goal the step goes all the way, which
    ends the exponential tail, unless the block's position is uncertain: ``position_std`` (m, the estimate's
    ``PoseEstimate.position_std_m``; None: unknown, trusted) above ``position_tolerance``. The goal is the hover
    pose ``T_base_hover``, unless the straight path there would take the block behind a finger (at the hover pose
    the block sits between the fingers, at the top of the image): then it is :func:`view_pose` (at ``view_depth``,
    default ``config.view_depth``), from where the path up between the fingers is clear. When the block's staying in
    view leaves less than ``BLOCKED_STEP_FRACTION`` of the step toward the view pose (a block near an image corner
    that the turn toward the view pose would swing out or behind a finger), the next pose is the view pose itself,
    which sees the block, if ``reachable`` (a predicate on a gripper pose; None: any) says the arm gets there.
    Returns ``(T_base_gripper_next, T_base_goal)``.
    """
    vertices_base = transform_points(T_base_block, config.model.vertices)
    T_base_goal = T_base_hover
    if clearance_px is not None and not view.path_in_view(T_base_gripper, T_base_hover, vertices_base, camera,
                                                           T_gripper_camera, config.view_margin_px, clearance_px):
        T_base_goal = view_pose(T_base_block, T_base_hover, T_gripper_camera, camera, config, view_depth)
    translation, _ = pose_error(T_base_gripper, T_base_goal)
    certain = position_std is None or position_std <= config.position_tolerance
    fraction = 1.0 if translation <= config.snap_distance and certain else config.step_fraction
    T_next = view.keep_in_view_step(T_base_gripper, T_base_goal, fraction, vertices_base, camera, T_gripper_camera,
                                     margin_px=config.view_margin_px, max_translation=config.max_step_translation,
                                     max_rotation=config.max_step_rotation, clearance_px=clearance_px)
    if T_base_goal is not T_base_hover:
        free_step = servo.look_and_move_step(T_base_gripper, T_base_goal, fraction, config.max_step_translation,
                                             config.max_step_rotation)
        blocked = pose_error(T_base_gripper, T_next)[0] < BLOCKED_STEP_FRACTION * pose_error(T_base_gripper,
                                                                                             free_step)[0]
        if blocked and (reachable is None or reachable(T_base_goal)):
            return T_base_goal, T_base_goal
    return T_next, T_base_goal


def view_pose(T_base_block, T_base_hover, T_gripper_camera, camera, config, depth=None):
    """First goal of the velocity laws: the gripper with the hover pose's orientation, placed so that the
    camera sees the block's centre ``depth`` (default ``config.view_depth``, m) away, in the image column
    it has at the hover pose and at ``view_row_fraction`` of the image height.

    At the hover pose the block appears between the fingers, which hide the top of the hand camera's
    image; a straight image path from a start near the top would pass behind a finger. Going first to
    this view (block low in the image) and then up to the hover view keeps the block in sight.
    """
    R_base_camera = T_base_hover[:3, :3] @ T_gripper_camera[:3, :3]
    block_at_hover = camera_goal(T_base_hover, T_base_block, T_gripper_camera)[:3, 3]
    column = camera.project(block_at_hover[None])[0, 0]
    x, y = camera.undistort_points(np.array([[column, config.view_row_fraction * (camera.height - 1)]]))[0]
    block_in_camera = (config.view_depth if depth is None else depth) * np.array([x, y, 1.0])
    T_base_camera = np.eye(4)
    T_base_camera[:3, :3] = R_base_camera
    T_base_camera[:3, 3] = T_base_block[:3, 3] - R_base_camera @ block_in_camera
    return T_base_camera @ invert(T_gripper_camera)


class Approach(NamedTuple):
    """How the arm approaches the block, chosen once per approach (:func:`plan_approach`)."""
    T_reference: np.ndarray     # 4x4 whose rotation picks the grasp orientation among the block's symmetric ones
    view_depth: float           # camera-to-block distance of the view pose (m)
    rank: int                   # which grasp orientation (0: the least rotation from the gripper's); -1: none reachable


def plan_approach(T_base_block, T_base_gripper, config, camera, T_gripper_camera, reachable, shrink=0.85, tries=5):
    """The grasp orientation and view depth of an approach (an :class:`Approach`).

    The block's symmetric grasp orientations (``grasp_orientations``) are tried from the smallest
    rotation of the gripper up, with the view pose's camera-to-block distance ``config.view_depth`` or
    shorter (by ``shrink``, ``tries`` times): the first whose hover pose and view pose pass ``reachable``
    (a predicate on a gripper pose in base, e.g. IK from the current angles) wins. At the view pose the
    camera looks down at the block low in its image, so the gripper is ~0.1 m beyond the block along its own
    x: for a far block a turned gripper brings that back into reach. If nothing is reachable, the smallest
    rotation and ``view_depth`` with ``rank`` -1.
    """
    orientations = grasp_orientations(T_base_block, config.model.symmetry_angle, T_base_gripper)
    for rank, R in enumerate(orientations):
        T_reference = make_transform(R)
        T_hover = hover_pose(T_base_block, config, T_reference)
        if not reachable(T_hover):
            continue
        depth = config.view_depth
        for _ in range(tries):
            if reachable(view_pose(T_base_block, T_hover, T_gripper_camera, camera, config, depth)):
                return Approach(T_reference, depth, rank)
            depth *= shrink
    return Approach(make_transform(orientations[0]), config.view_depth, -1)


def place_pose(T_base_gripper_holding, T_gripper_block, place_xy, config, table_top_z, height_above_table):
    """Gripper pose that puts the held block's bottom ``height_above_table`` (m) above the table (its top at
    ``table_top_z`` in base, m) at ``place_xy``.

    The block keeps its current orientation in the hand (``T_gripper_block``); the gripper keeps its
    orientation and only translates.
    """
    T_base_block = T_base_gripper_holding @ T_gripper_block
    target_block_z = table_top_z + config.block_height + height_above_table
    shift = np.array([place_xy[0] - T_base_block[0, 3], place_xy[1] - T_base_block[1, 3],
                      target_block_z - T_base_block[2, 3]])
    T = T_base_gripper_holding.copy()
    T[:3, 3] += shift
    return T


HOLD_CONFIRM_DISTANCE = 0.02   # m: a block seen this close to where the grasp put it in the hand confirms the grip
LEFT_BEHIND_HEIGHT = 0.01      # m: a block seen this close to lying on the table ...
LEFT_BEHIND_DISTANCE = 0.02    # m: ... this close to where it was before the grasp was left behind


def left_behind(T_base_block_seen, T_base_block_before, table_top_z, block_height):
    """True if the look after lifting sees the block still lying where it was (the grip holds something else)."""
    on_table = abs(T_base_block_seen[2, 3] - (table_top_z + block_height)) < LEFT_BEHIND_HEIGHT
    return bool(on_table and np.linalg.norm(T_base_block_seen[:2, 3] - T_base_block_before[:2, 3])
                < LEFT_BEHIND_DISTANCE)


# ----------------------------------------------------------------------------------------------- image features

def normalised(points_camera):
    """(N, 2) normalised image coordinates X/Z, Y/Z and (N,) depths of camera-frame points."""
    points_camera = np.atleast_2d(points_camera)
    return points_camera[:, :2] / points_camera[:, 2:3], points_camera[:, 2].copy()


def goal_features(T_camera_goal_block, model):
    """Desired point features: normalised coordinates (n, 2) and depths (n,) of the model's top-face
    vertices when the camera sees the block from the goal pose (``T_camera_goal_block``)."""
    return normalised(transform_points(T_camera_goal_block, model.vertices))


def measured_features(vertices_xy, T_camera_block, model):
    """Detected vertices (normalised, undistorted; any order) put in model order, with their depths.

    The order comes from the pose estimate: each model vertex, projected with ``T_camera_block``,
    takes the nearest detected vertex. Depths (the 'Z' of eq. 2.6) come from the estimate too: this
    is IBVS with the model-based depth estimate (the thesis's future work).
    """
    predicted_xy, depths = normalised(transform_points(T_camera_block, model.vertices))
    distances = np.linalg.norm(predicted_xy[:, None, :] - np.asarray(vertices_xy)[None, :, :], axis=2)
    order = np.argmin(distances, axis=1)
    if len(set(order.tolist())) != len(order):      # ambiguous match: fall back to the projections
        return predicted_xy, depths
    return np.asarray(vertices_xy)[order], depths


def camera_goal(T_base_goal_gripper, T_base_block, T_gripper_camera):
    """``T_camera_goal_block``: the block seen from the camera when the gripper is at the goal."""
    return invert(T_base_goal_gripper @ T_gripper_camera) @ T_base_block


def image_error_px(camera, T_camera_block, T_base_goal, T_base_block, T_gripper_camera):
    """Pixel distance between the block centre now (``T_camera_block``) and where ``camera`` sees it from the
    gripper goal ``T_base_goal``."""
    now = camera.project(T_camera_block[:3, 3][None])[0]
    at_goal = camera.project(camera_goal(T_base_goal, T_base_block, T_gripper_camera)[:3, 3][None])[0]
    return float(np.linalg.norm(now - at_goal))


def bounded_twist(twist, max_linear, max_angular):
    """The twist scaled down (direction kept) so |v| <= max_linear (m/s) and |w| <= max_angular (rad/s)."""
    twist = np.asarray(twist, dtype=float)
    scale = min(1.0, max_linear / max(np.linalg.norm(twist[:3]), 1e-12),
                max_angular / max(np.linalg.norm(twist[3:]), 1e-12))
    return twist * scale


def view_kept_twist(twist_camera, T_base_camera, T_base_block, config, camera, clearance_px=None, lookahead=0.5):
    """The velocity laws' keep-in-view: ``twist_camera`` (camera frame, (v m/s, w rad/s)), or a gentler one
    if, kept for ``lookahead`` seconds, it would take the block's vertices within ``view_margin_px`` of the
    image border or (given ``clearance_px``) of the fingers.

    The camera pose the twist reaches in ``lookahead`` s goes through ``view.keep_in_view_step`` (the
    PBVS rule: its approach and rotation are scaled down first, its lateral re-centring kept), and the
    twist is replaced by the one that reaches the kept pose in the same time. (Switching to a PBVS step
    toward the goal instead, as in Gans & Hutchinson's switched schemes, chattered against the law near a
    finger in the trials.)
    """
    vertices_base = transform_points(T_base_block, config.model.vertices)
    T_ahead = servo.integrate_twist(T_base_camera, twist_camera, lookahead)
    if view.points_in_view(T_ahead, vertices_base, camera, config.view_margin_px, clearance_px):
        return np.asarray(twist_camera, dtype=float)
    T_kept = view.keep_in_view_step(T_base_camera, T_ahead, 1.0, vertices_base, camera, np.eye(4),
                                     margin_px=config.view_margin_px, clearance_px=clearance_px)
    return servo.twist_between(T_base_camera, T_kept, lookahead)


def servo_twist(mode, T_camera_block, T_camera_goal_block, vertices_xy, model, gain):
    """Camera twist (camera frame, (v m/s, w rad/s)) of the IBVS or 2.5D law, and the RMS feature error.

    - 'ibvs': point features of the top-face vertices with the estimated depths, the 'mean'
      interaction matrix ((L + L*)/2; no retreat under large rotations about the optical axis).
    - 'hybrid': Malis's 2.5D on the block centre (x, y, log Z/Z*) and theta-u of the rotation to the
      goal: decoupled, keeps the block centre's image path straight.
    Returns (twist (6,), error (normalised units, RMS over the vertices)).
    """
    s_star, Z_star = goal_features(T_camera_goal_block, model)
    s, Z = measured_features(vertices_xy, T_camera_block, model)
    error = float(np.sqrt(np.mean(np.sum((s - s_star) ** 2, axis=1))))
    if mode == 'ibvs':
        return servo.ibvs_twist(s, s_star, Z, Z_star, gain, variant='mean'), error
    centre, centre_star = T_camera_block[:3, 3], T_camera_goal_block[:3, 3]
    R_cstar_c = T_camera_goal_block[:3, :3] @ T_camera_block[:3, :3].T
    twist = servo.hybrid_twist(centre[0] / centre[2], centre[1] / centre[2], centre[2],
                               centre_star[0] / centre_star[2], centre_star[1] / centre_star[2], centre_star[2],
                               R_cstar_c, gain)
    return twist, error


def make_gain(config):
    return servo.AdaptiveGain(*config.gain)


class StallWatch:
    """Stall detection of a velocity law: the feature error (px) must fall by ``progress`` (a fraction) within every
    ``window`` s; ``progress`` 0 disables it. A gap of over a third of ``window`` between two errors (a move that
    was not the law's: a re-acquisition) starts afresh. ``count``: stalls so far. Pure (times passed in)."""

    def __init__(self, window, progress):
        self.window, self.progress = window, progress
        self.count = 0
        self.reset()

    def reset(self):
        """Forget the errors seen (after a move that was not the velocity law's)."""
        self._history = []

    def stalled(self, now, error_px, phase=None):
        """Record ``error_px`` at time ``now`` (s) of the goal ``phase`` (a new phase starts afresh); True on a stall."""
        if self._history and (self._history[-1][2] != phase or now - self._history[-1][0] > self.window / 3):
            self.reset()
        self._history.append((now, error_px, phase))
        if self.progress <= 0:
            return False
        while len(self._history) > 1 and self._history[1][0] <= now - self.window:
            self._history.pop(0)
        then, error_then, _ = self._history[0]
        if now - then < self.window or error_px < (1.0 - self.progress) * error_then:
            return False
        self.count += 1
        return True
