"""The pick-and-place task, pure: block pose and arm pose in -> next arm target (or camera twist) out.

No ROS here (``application.py`` is the ROS edge). Frames: ``base`` (Baxter's), ``gripper`` (the
``<side>_gripper`` tip frame: z along the fingers, fingers close along y), ``camera`` (the hand
camera's optical frame), ``block`` (docs/ARCHITECTURE.md: origin at the top-face centre, z up).
Metres, radians, pixels.

The approach ends at the *hover* pose: the gripper centred over the block, fingers pointing down,
aligned to the block's faces, ``hover_height`` above the *grasp* pose (fingertips ``grasp_depth``
below the top face), to which the arm then descends and closes.
"""
import math
from dataclasses import asdict, dataclass, field, fields
from typing import List, NamedTuple, Optional

import numpy as np
import yaml
from scipy.spatial.transform import Rotation

from baxter_pnp import models, servo
from baxter_pnp.transforms import invert, make_transform, transform_points

MODES = ('pbvs', 'ibvs', 'hybrid')


@dataclass
class PickConfig:
    """Every parameter of the pick application (metres, radians, seconds, pixels). YAML: config/pick_square.yaml."""

    side: str = 'left'                      # arm
    shape: str = 'square'                   # target shape (triangle, square, pentagon, hexagon)
    side_length: float = 0.04               # block side (m)
    block_height: float = 0.02              # block height (m)
    colour: str = 'green'                   # a colour name of config/vision.yaml
    mode: str = 'pbvs'                      # pbvs (thesis look-and-move) | ibvs | hybrid (2.5D)
    step_fraction: float = 0.35             # PBVS: fraction of the remaining displacement per step (thesis 0.35, 0.12)
    start_pose: str = 'down'                # a name in config/start_poses.yaml (down, angled, neutral)
    table_top_z: float = -0.15              # table top height in base (m): the estimator's plane, the safety floor
    tip_margin: float = 0.005               # the gripper tip never goes lower than this above the table (m); the
                                            # paddles reach 3.5 mm beyond the tip plane
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
    lift_height: float = 0.10               # lift after the grasp (m)
    place_xy: Optional[List[float]] = None  # put the block down at this table position (base x, y; m)
    place_clearance: float = 0.004          # release the block this far above the table (m)
    max_grasp_attempts: int = 2             # re-servo and regrasp after a miss
    cycles: int = 1                         # blocks to pick (and place) one after the other in one run
    next_block_timeout: float = 30.0        # between cycles: wait this long (s) for the next block to appear
    save_views: bool = False                # save every annotated camera view in the output directory (views/)
    speed_ratio: float = 0.3                # position-mode speed ratio of the arm (robot default 0.3)
    resolution: List[int] = field(default_factory=lambda: [640, 400])   # hand camera mode
    fps: int = 20                           # hand camera rate (Hz)
    estimator: str = 'sqp'                  # pose estimator: sqp | ippe | sqpnp
    camera_calibration: Optional[str] = None  # camera YAML (calibrate_camera.py) used instead of the robot's
                                            # camera_info; scaled to the camera mode if calibrated at another size
    gain: List[float] = field(default_factory=lambda: [1.5, 0.4, 10.0])  # IBVS/hybrid adaptive gain (l0, linf, l0')
    max_linear_speed: float = 0.08          # IBVS/hybrid: camera speed bound (m/s)
    max_angular_speed: float = 0.5          # IBVS/hybrid: camera angular speed bound (rad/s)
    feature_tolerance_px: float = 2.0       # IBVS/hybrid: converged when the RMS feature error is below this (px)
    view_depth: float = 0.30                # IBVS/hybrid first goal: the block centre this far from the camera (m) ...
    view_row_fraction: float = 0.75         # ... at this fraction of the image height (below the fingers' image)
    view_tolerance_px: float = 8.0          # ... reached when the RMS feature error is below this (px)
    max_residual_px: float = 2.0            # estimates with a larger RMS reprojection error are not trusted (occlusion)
    max_height_error: float = 0.02          # ... nor those putting a block on the table this far off its height (m)
    waypoint_spacing: float = 0.02          # IK along straight Cartesian paths: waypoints this far apart (m)
    timeout: float = 90.0                   # whole run (s of robot time)
    stream_max_age: float = 2.0             # a robot topic silent for longer (wall s) is lost
    frame_timeout: float = 5.0              # a look waits this long (wall s) for a camera frame
    robot_wait_timeout: float = 30.0        # after lost streams, wait this long (wall s) for the robot to return
    max_recoveries: int = 2                 # times a run resumes after the robot came back

    @classmethod
    def from_dict(cls, values):
        """PickConfig from a dict; unknown keys and bad values raise ValueError naming the key."""
        known = {f.name for f in fields(cls)}
        unknown = sorted(set(values) - known)
        if unknown:
            raise ValueError('unknown pick parameter(s) %s (known: %s)' % (unknown, sorted(known)))
        config = cls(**values)
        config.validate()
        return config

    @classmethod
    def from_yaml(cls, path):
        with open(path) as f:
            values = yaml.safe_load(f) or {}
        if not isinstance(values, dict):
            raise ValueError('%s: expected a mapping of pick parameters' % path)
        try:
            return cls.from_dict(values)
        except (TypeError, ValueError) as error:
            raise ValueError('%s: %s' % (path, error)) from None

    def validate(self):
        def require(condition, key, what):
            if not condition:
                raise ValueError('%s: %s (got %r)' % (key, what, getattr(self, key)))
        require(self.side in ('left', 'right'), 'side', "must be 'left' or 'right'")
        require(self.shape in models.SHAPES, 'shape', 'must be one of %s' % sorted(models.SHAPES))
        require(self.mode in MODES, 'mode', 'must be one of %s' % (MODES,))
        for key in ('side_length', 'block_height', 'hover_height', 'tip_margin', 'position_tolerance', 'yaw_tolerance',
                    'max_step_translation', 'max_step_rotation', 'lift_height', 'backoff_height',
                    'max_linear_speed', 'max_angular_speed', 'feature_tolerance_px', 'timeout', 'stream_max_age',
                    'frame_timeout', 'robot_wait_timeout', 'view_depth', 'view_tolerance_px', 'max_residual_px',
                    'max_height_error', 'waypoint_spacing', 'next_block_timeout'):
            value = getattr(self, key)
            require(isinstance(value, (int, float)) and math.isfinite(value) and value > 0, key,
                    'must be a positive number')
        require(0.0 < self.step_fraction <= 1.0, 'step_fraction', 'must be in (0, 1]')
        require(0.0 < self.speed_ratio <= 1.0, 'speed_ratio', 'must be in (0, 1]')
        require(0.0 < self.view_row_fraction < 1.0, 'view_row_fraction', 'must be in (0, 1)')
        require(0.0 <= self.grasp_depth < self.block_height, 'grasp_depth', 'must be in [0, block_height)')
        require(self.block_height - self.grasp_depth >= self.tip_margin, 'grasp_depth',
                'leaves the gripper tip closer to the table than tip_margin')
        require(isinstance(self.table_top_z, (int, float)) and math.isfinite(self.table_top_z), 'table_top_z',
                'must be a number')
        require(self.place_xy is None or (len(self.place_xy) == 2 and all(map(math.isfinite, self.place_xy))),
                'place_xy', 'must be [x, y] in metres or null')
        require(len(self.gain) == 3 and self.gain[0] >= self.gain[1] > 0, 'gain',
                'must be [gain at 0, gain at infinity, slope at 0] with gain at 0 >= gain at infinity > 0')
        require(self.estimator in ('sqp', 'ippe', 'sqpnp'), 'estimator', 'must be sqp, ippe or sqpnp')
        require(isinstance(self.save_views, bool), 'save_views', 'must be true or false')
        for key in ('max_steps', 'cycles'):
            require(isinstance(getattr(self, key), int) and getattr(self, key) > 0, key, 'must be a positive integer')

    @property
    def model(self):
        return models.model_for(self.shape, self.side_length, self.block_height)

    def as_dict(self):
        return asdict(self)


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

def table_plane_in_camera(T_base_camera, table_top_z):
    """The table top (z = ``table_top_z`` in base, normal +z) as a ``models.Plane`` in the camera frame."""
    R, t = T_base_camera[:3, :3], T_base_camera[:3, 3]
    normal_base = np.array([0.0, 0.0, 1.0])
    return models.Plane(R.T @ normal_base, float(table_top_z - normal_base @ t))


def hover_pose(T_base_block, config, T_base_gripper):
    """Pre-grasp gripper pose: centred ``hover_height`` above the block, faces aligned (servo.grasp_goal)."""
    model = config.model
    return servo.grasp_goal(T_base_block, config.side_length, config.grasp_depth, config.hover_height,
                            model.symmetry_angle, T_base_gripper)


def grasp_pose(T_base_block, config, T_base_gripper):
    """Gripper pose to close at: fingertips ``grasp_depth`` below the top face, faces aligned."""
    return servo.grasp_goal(T_base_block, config.side_length, config.grasp_depth, 0.0,
                            config.model.symmetry_angle, T_base_gripper)


def pose_error(T_current, T_goal):
    """(translation error (m), rotation error (rad)) between two poses."""
    translation = float(np.linalg.norm(T_goal[:3, 3] - T_current[:3, 3]))
    rotation = float(Rotation.from_matrix(T_current[:3, :3].T @ T_goal[:3, :3]).magnitude())
    return translation, rotation


def converged(T_current, T_goal, config):
    translation, rotation = pose_error(T_current, T_goal)
    return translation <= config.position_tolerance and rotation <= config.yaw_tolerance


def pbvs_target(T_base_gripper, T_base_hover, T_base_block, config, camera, T_gripper_camera, clearance_px=None,
                view_depth=None):
    """Next gripper pose of the look-and-move PBVS (the thesis's law, with its failures fixed), and the goal
    it steps toward.

    Moves ``step_fraction`` of the remaining displacement toward the goal, bounded in translation and
    rotation, and shortened so that the block's vertices stay ``view_margin_px`` inside the image and,
    given the hand's ``clearance_px`` map (``servo.hand_clearance_px``), clear of the fingers after the move
    (``servo.keep_in_view_step``). Within ``snap_distance`` of the goal the step goes all the way, which
    ends the exponential tail. The goal is the hover pose ``T_base_hover``, unless the straight path there
    would take the block behind a finger (at the hover pose the block sits between the fingers, at the top
    of the image): then it is :func:`view_pose` (at ``view_depth``, default ``config.view_depth``), from
    where the path up between the fingers is clear.
    Returns ``(T_base_gripper_next, T_base_goal)``.
    """
    vertices_base = transform_points(T_base_block, config.model.vertices)
    T_base_goal = T_base_hover
    if clearance_px is not None and not servo.path_in_view(T_base_gripper, T_base_hover, vertices_base, camera,
                                                           T_gripper_camera, config.view_margin_px, clearance_px):
        T_base_goal = view_pose(T_base_block, T_base_hover, T_gripper_camera, camera, config, view_depth)
    translation, _ = pose_error(T_base_gripper, T_base_goal)
    fraction = 1.0 if translation <= config.snap_distance else config.step_fraction
    T_next = servo.keep_in_view_step(T_base_gripper, T_base_goal, fraction, vertices_base, camera, T_gripper_camera,
                                     margin_px=config.view_margin_px, max_translation=config.max_step_translation,
                                     max_rotation=config.max_step_rotation, clearance_px=clearance_px)
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

    The block's symmetric grasp orientations (``servo.grasp_orientations``) are tried from the smallest
    rotation of the gripper up, with the view pose's camera-to-block distance ``config.view_depth`` or
    shorter (by ``shrink``, ``tries`` times): the first whose hover pose and view pose pass ``reachable``
    (a predicate on a gripper pose in base, e.g. IK from the current angles) wins. At the view pose the
    camera looks down at the block low in its image, so the gripper is ~0.1 m beyond the block along its own
    x: for a far block a turned gripper brings that back into reach. If nothing is reachable, the smallest
    rotation and ``view_depth`` with ``rank`` -1.
    """
    orientations = servo.grasp_orientations(T_base_block, config.model.symmetry_angle, T_base_gripper)
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


def raised(T_base_gripper, height):
    """The same gripper pose ``height`` metres higher in base (re-acquisition, lift)."""
    T = T_base_gripper.copy()
    T[2, 3] += height
    return T


def place_pose(T_base_gripper_holding, T_gripper_block, place_xy, config, height_above_table):
    """Gripper pose that puts the held block's bottom ``height_above_table`` (m) above the table at ``place_xy``.

    The block keeps its current orientation in the hand (``T_gripper_block``); the gripper keeps its
    orientation and only translates.
    """
    T_base_block = T_base_gripper_holding @ T_gripper_block
    target_block_z = config.table_top_z + config.block_height + height_above_table
    shift = np.array([place_xy[0] - T_base_block[0, 3], place_xy[1] - T_base_block[1, 3],
                      target_block_z - T_base_block[2, 3]])
    T = T_base_gripper_holding.copy()
    T[:3, 3] += shift
    return T


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


def feature_error_px(s, s_star, focal_px):
    """RMS distance (px) between current and desired normalised features."""
    return float(np.sqrt(np.mean(np.sum((np.asarray(s) - np.asarray(s_star)) ** 2, axis=1)))) * focal_px


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

    The camera pose the twist reaches in ``lookahead`` s goes through ``servo.keep_in_view_step`` (the
    PBVS rule: its approach and rotation are scaled down first, its lateral re-centring kept), and the
    twist is replaced by the one that reaches the kept pose in the same time. (Switching to a PBVS step
    toward the goal instead, as in Gans & Hutchinson's switched schemes, chattered against the law near a
    finger in the trials.)
    """
    vertices_base = transform_points(T_base_block, config.model.vertices)
    T_ahead = servo.integrate_twist(T_base_camera, twist_camera, lookahead)
    if servo.points_in_view(T_ahead, vertices_base, camera, config.view_margin_px, clearance_px):
        return np.asarray(twist_camera, dtype=float)
    T_kept = servo.keep_in_view_step(T_base_camera, T_ahead, 1.0, vertices_base, camera, np.eye(4),
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


def block_pose_in_base(T_base_camera, T_camera_block):
    return T_base_camera @ T_camera_block
