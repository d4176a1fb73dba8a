"""Scene description of the fake Baxter: table, blocks, chessboards, start pose, camera error, faults (YAML, validated).

Lengths in metres and angles in radians, in Baxter's ``base`` frame (see docs/ARCHITECTURE.md)::

    table: {top_z: -0.15, center: [0.75, 0.0], size: [0.9, 1.5]}
    objects:
      - {shape: square, side: 0.04, height: 0.02, color: [0.1, 0.7, 0.1], xy: [0.70, 0.25], yaw: 0.4}
      - {shape: chessboard, pattern: [9, 6], square: 0.025, xy: [0.53, 0.25], yaw: -1.5}
      - {shape: tape, xy: [0.60, 0.05], length: 0.12, width: 0.019, color: [0.8, 0.1, 0.1], yaw: 0.3}
      - {shape: cup, xy: [0.85, 0.40], radius: 0.04, height: 0.095, color: [0.9, 0.9, 0.88]}
    start: down      # 'down' | 'angled' | 'neutral' (config/start_poses.yaml) | {left_s0: ..., ..., left_w2: ...}
    camera_error: {xyz: [0, 0, 0], rpy: [0, 0, 0], focal_scale: 1.0}
    faults: {camera: {drop_probability: 0.2}, estop_at: 10.0}     # sim.faults; docs/fake_baxter.md
    respawn: {poses: [[0.62, 0.30, 0.5], [0.70, 0.18, -1.0]], delay: 2.0, object: 0}   # (x m, y m, yaw rad)
    appearance: baxter   # 'baxter' (a real hand camera's look) | 'clean' | {preset: clean, exposure: 0.5, ...}
    supersampling: 1     # camera samples a pixel along each axis (2: anti-aliased edges, n^2 the drawing cost)

``table``, ``start``, ``camera_error``, ``faults``, ``respawn``, ``appearance`` and ``supersampling`` (and each of
their keys, except ``respawn.poses``), an object's ``height`` and ``yaw`` are optional (the values above are the
defaults; no faults and no respawn by default); an object's ``shape``, ``side``, ``color`` and ``xy`` are required
(a chessboard's ``pattern``, ``square`` and ``xy``; its ``yaw``, ``border`` and ``thickness`` are optional; a
tape's or cup's ``shape`` and ``xy``, the rest optional), and neither blocks nor cups may overlap. Every problem
raises ``SceneError`` whose message starts with the key (checked by ``params``: each dataclass below from its
mapping, then its ``validate``).

``objects`` entries with ``shape: chessboard`` are printed boards lying on the table (``Chessboard``), those with
``shape: tape`` or ``cup`` clutter (``Prop``), not blocks: ``Scene.from_dict`` puts them in ``Scene.boards`` and
``Scene.props`` and the blocks, in their order, in ``Scene.objects`` (black, white or grey blocks are clutter too:
no colour class takes them). **Block indices count blocks only** (``respawn.object``, ``faults.nudge.object``,
``SimWorld.object_poses`` and the fake's ground-truth topic ``/fake_baxter/object_poses``); error keys name the
entry's place in the YAML list.
"""
import contextlib
import dataclasses
import math
import os
import re
from dataclasses import dataclass, field
from typing import Dict, Optional, Tuple, Union

import cv2
import numpy as np

from baxter_pnp.kinematics import arm_joint_names, load_start_poses
from baxter_pnp.models import SHAPES, model_for
from baxter_pnp.params import ParameterError, Parameters, from_mapping
from baxter_pnp.runtime import PACKAGE_ROOT
from baxter_pnp.sim import appearance
from baxter_pnp.sim.appearance import AppearanceConfig
from baxter_pnp.sim.faults import Faults
from baxter_pnp.transforms import from_xyz_rpy

DEFAULT_SCENE_YAML = os.path.join(PACKAGE_ROOT, 'config', 'scenes', 'default.yaml')
RESPAWN_DELAY = 2.0             # s (simulated): default wait of a respawn (see Respawn)
BOARD_THICKNESS = 0.0005        # m: default thickness of a chessboard (a printed sheet on the table)
MAX_SUPERSAMPLING = 4           # camera samples a pixel along each axis (the render costs about n^2 times as much)
START_POSE_NAMES = ('down', 'angled', 'neutral')       # config/start_poses.yaml
PROP_SHAPES = ('tape', 'cup')   # clutter that is not a block (``Prop``)
TAPE_THICKNESS = 0.0003         # m: a strip of tape on the table
CUP_SIDES = 16                  # the polygon a cup's outline is checked as (``Prop.footprint``)


class SceneError(ParameterError):
    """An invalid scene; the message starts with the offending key (``objects[1].side: ...``)."""


@contextlib.contextmanager
def _scene_errors(positions=None):
    """Every ParameterError raised inside re-raised as a SceneError (same key and message); with ``positions``
    ({'objects' | 'boards': [index in the YAML ``objects`` list, ...]}), ``objects[i]`` and ``boards[i]`` in
    the key and message renamed ``objects[<YAML index>]``."""
    try:
        yield
    except ParameterError as error:
        if positions is None:
            raise SceneError(error.key, error.problem) from None
        raise SceneError(_yaml_indices(error.key, positions), _yaml_indices(error.problem, positions)) from None


def _yaml_indices(text, positions):
    """``text`` with each ``objects[i]`` / ``boards[i]`` replaced by ``objects[<its index in the YAML list>]``."""
    return re.sub(r'\b(objects|boards|props)\[(\d+)\]',
                  lambda match: f'objects[{positions[match.group(1)][int(match.group(2))]}]', text)


def _split_entries(values):
    """(``values`` with its ``objects`` list split into ``objects`` (blocks), ``boards`` (entries with ``shape:
    chessboard``) and ``props`` (``shape`` in ``PROP_SHAPES``), positions: {'objects' | 'boards' | 'props': [index
    in the YAML list, ...]}); unchanged if ``objects`` is not a list (the parameter check names it)."""
    entries = values.get('objects', [])
    if not isinstance(entries, list):
        return values, None
    positions = {'objects': [], 'boards': [], 'props': []}
    for i, entry in enumerate(entries):
        shape = entry.get('shape') if isinstance(entry, dict) else None
        positions['boards' if shape == 'chessboard' else 'props' if shape in PROP_SHAPES else 'objects'].append(i)
    split = {key: [entries[i] for i in indices] for key, indices in positions.items()}
    return {**values, **split}, positions


@dataclass(frozen=True)
class Table(Parameters):
    """Static table: top face at ``z = top_z``, centred at ``center`` (x, y), ``size`` (x, y) in metres."""
    top_z: float = -0.15
    center: Tuple[float, float] = (0.75, 0.0)
    size: Tuple[float, float] = (0.9, 1.5)

    def validate(self):
        self.require_positive('size')

    def contains(self, xy):
        """True if the point ``xy`` (m) lies on the table top."""
        return bool(np.all(np.abs(np.subtract(xy, self.center)) <= np.divide(self.size, 2.0)))


@dataclass(frozen=True)
class SceneObject(Parameters):
    """A block standing on the table: a regular prism (``shape``, ``side``, ``height`` in m), RGB ``color``
    in 0..1, top-face centre above ``xy`` (m), rotated ``yaw`` (rad) about base +z."""
    shape: str
    side: float
    color: Tuple[float, float, float]
    xy: Tuple[float, float]
    height: float = 0.02
    yaw: float = 0.0

    def validate(self):
        self.require(self.shape in SHAPES, 'shape',
                     f"must be one of {sorted(SHAPES, key=SHAPES.get)}, 'chessboard', 'tape' or 'cup'")
        self.require_positive('side', 'height')
        self.require(all(0.0 <= c <= 1.0 for c in self.color), 'color', 'RGB components must be in 0..1')

    @property
    def model(self):
        """The block's ``models.PolygonModel``."""
        return model_for(self.shape, self.side, self.height)

    def footprint(self):
        """(n, 2) vertices (m, base x-y) of the block's outline on the table."""
        c, s = math.cos(self.yaw), math.sin(self.yaw)
        return self.model.vertices[:, :2] @ np.array([[c, s], [-s, c]]) + self.xy


@dataclass(frozen=True)
class Chessboard(Parameters):
    """A printed chessboard lying flat on the table, seen by the cameras only (no collision shape: the arm, the
    fingers and the blocks pass through it; blocks may stand on it). ``pattern`` (columns, rows) of **inner**
    corners, so (columns + 1) x (rows + 1) squares of ``square`` m, black and white, the one before the first
    corner black (OpenCV's pattern), inside a white ``border`` (m, default one square); the board is ``thickness``
    m thick (its printed top that far above the table top); the inner-corner grid is centred above ``xy`` (m)
    and rotated ``yaw`` (rad) about base +z (see ``T_base_board``)."""
    pattern: Tuple[int, int]
    square: float
    xy: Tuple[float, float]
    yaw: float = 0.0
    border: Optional[float] = None
    thickness: float = BOARD_THICKNESS
    shape: str = 'chessboard'

    def __post_init__(self):
        if self.border is None:
            object.__setattr__(self, 'border', self.square)

    def validate(self):
        self.require(self.shape == 'chessboard', 'shape', "must be 'chessboard'")
        for i, count in enumerate(self.pattern):
            self.require(count >= 2, f'pattern[{i}]', 'must be at least 2 inner corners', count)
        self.require_positive('square', 'thickness')
        self.require_non_negative('border')

    @property
    def size(self):
        """(length along the board's x, along its y) of the whole board, border included (m)."""
        return tuple((count + 1) * self.square + 2 * self.border for count in self.pattern)

    def T_base_board(self, table_top_z):
        """4x4 pose (m) of the board frame in ``base``, the frame of ``calibration.board_object_points``: origin
        at the first inner corner on the printed top (``thickness`` above ``table_top_z``), x along a row of
        corners (rotated ``yaw`` from base +x), y along the columns to the next row, z into the table (-base z),
        as OpenCV's object points have it: x right, y down, z away from a camera that looks at the board."""
        c, s = math.cos(self.yaw), math.sin(self.yaw)
        R = np.array([[c, s, 0.0], [s, -c, 0.0], [0.0, 0.0, -1.0]])      # Rz(yaw) Rx(pi)
        centre = np.array([*self.xy, table_top_z + self.thickness])
        first_corner = centre - R[:, :2] @ ((np.array(self.pattern) - 1) * self.square / 2)
        T = np.eye(4)
        T[:3, :3], T[:3, 3] = R, first_corner
        return T

    def black_squares(self):
        """(K, 4, 2) corners (m, board frame x-y, in order around each square) of the black squares: square
        (a, b), a = 0..columns, b = 0..rows, spans x in [(a-1) s, a s] and y in [(b-1) s, b s] and is black when
        a + b is even (square (0, 0), before the first inner corner, is black)."""
        unit = np.array([[0, 0], [1, 0], [1, 1], [0, 1]])
        return np.array([(unit + [a - 1, b - 1]) * self.square
                         for b in range(self.pattern[1] + 1) for a in range(self.pattern[0] + 1) if (a + b) % 2 == 0])

    def footprint(self):
        """(4, 2) corners (m, base x-y) of the whole board, border included, on the table."""
        c, s = math.cos(self.yaw), math.sin(self.yaw)
        half = np.array(self.size) / 2
        outline = np.array([[-1, -1], [1, -1], [1, 1], [-1, 1]]) * half
        return outline @ np.array([[c, s], [-s, c]]) + self.xy


@dataclass(frozen=True)
class Prop(Parameters):
    """Clutter on the table that is no block. ``shape: tape``: a strip of tape stuck on the table, ``length`` x
    ``width`` m, ``TAPE_THICKNESS`` thick, its length along ``yaw`` (rad, from base +x), seen only (nothing
    touches it; blocks may stand on it); ``shape: cup``: a mug standing open side up, ``radius`` and ``height`` m,
    fixed to the table (the arm and the blocks hit it), its inside shaded darker. Centred above ``xy`` (m), RGB
    ``color`` in 0..1."""
    shape: str
    xy: Tuple[float, float]
    color: Tuple[float, float, float] = (0.8, 0.1, 0.1)
    yaw: float = 0.0
    length: float = 0.12
    width: float = 0.019
    radius: float = 0.04
    height: float = 0.095

    def validate(self):
        self.require(self.shape in PROP_SHAPES, 'shape', f'must be one of {list(PROP_SHAPES)}')
        self.require_positive('length', 'width', 'radius', 'height')
        self.require(all(0.0 <= c <= 1.0 for c in self.color), 'color', 'RGB components must be in 0..1')

    def footprint(self):
        """(n, 2) vertices (m, base x-y) of the outline on the table (a cup's as a ``CUP_SIDES``-gon around it)."""
        if self.shape == 'cup':
            angles = 2 * np.pi * np.arange(CUP_SIDES) / CUP_SIDES
            outline = np.column_stack([np.cos(angles), np.sin(angles)])
            return self.radius / math.cos(np.pi / CUP_SIDES) * outline + self.xy
        c, s = math.cos(self.yaw), math.sin(self.yaw)
        outline = np.array([[-1, -1], [1, -1], [1, 1], [-1, 1]]) * [self.length / 2, self.width / 2]
        return outline @ np.array([[c, s], [-s, c]]) + self.xy


@dataclass(frozen=True)
class CameraError(Parameters):
    """The true hand camera minus the published one: mount offset ``xyz`` (m) and ``rpy`` (rad, URDF
    fixed-axis) in the published optical frame, and the ratio ``focal_scale`` of true to published focal lengths."""
    xyz: Tuple[float, float, float] = (0.0, 0.0, 0.0)
    rpy: Tuple[float, float, float] = (0.0, 0.0, 0.0)
    focal_scale: float = 1.0

    def validate(self):
        self.require_positive('focal_scale')

    @property
    def T_published_true(self):
        """4x4 pose of the true camera optical frame in the published one."""
        return from_xyz_rpy(self.xyz, self.rpy)


@dataclass(frozen=True)
class Respawn(Parameters):
    """The fake re-places block ``object`` (scene order) for endless pick-and-place runs (soak tests).

    Once the block has been lifted (its underside at least 3 cm above the table top) and is then at rest on
    the table again, released (every gripper open or touching it with neither finger) and with every
    gripper tip at least 8 cm above its top, for ``delay`` seconds of simulated time, it is moved, at rest,
    to the next of ``poses`` (x (m), y (m), yaw (rad) of its top-face centre, in ``base``), cycling through
    them. ``sim.world.SimWorld`` acts it out (docs/fake_baxter.md "Scene file")."""
    poses: Tuple[Tuple[float, float, float], ...]
    delay: float = RESPAWN_DELAY
    object: int = 0

    def validate(self):
        self.require(len(self.poses) > 0, 'poses', 'must be a non-empty list of [x, y, yaw]')
        self.require_non_negative('delay')
        self.require(self.object >= 0, 'object', 'must be a non-negative integer')


# The 7 left-arm joint angles (rad) of a start map (``Scene.start``).
_StartJoints = dataclasses.make_dataclass('_StartJoints', [(name, float) for name in arm_joint_names('left')],
                                          bases=(Parameters,), frozen=True)


@dataclass(frozen=True)
class Scene(Parameters):
    """A validated scene. ``objects``: the blocks; ``boards``: the chessboards (``objects`` entries with ``shape:
    chessboard`` in YAML, see ``from_dict``); ``props``: tape and cups (``shape: tape | cup``). ``start`` is a
    start-pose name or a dict of the 7 left-arm joint angles (rad); ``faults`` a ``sim.faults.Faults`` (none by default); ``respawn`` a ``Respawn`` or None.
    ``validate`` checks what lies between the sections: blocks on the table and apart, boards wholly on the
    table and apart (blocks may stand on them), the respawn poses, the blocks that ``respawn`` and
    ``faults.nudge`` name (block indices count blocks only)."""
    table: Table = field(default_factory=Table)
    objects: Tuple[SceneObject, ...] = ()
    boards: Tuple[Chessboard, ...] = ()
    props: Tuple[Prop, ...] = ()
    start: Union[str, Dict[str, float]] = 'down'
    camera_error: CameraError = field(default_factory=CameraError)
    faults: Faults = field(default_factory=Faults)
    respawn: Optional[Respawn] = None
    appearance: AppearanceConfig = field(default_factory=appearance.default_appearance)
    supersampling: int = 1

    def validate(self):
        self.require(1 <= self.supersampling <= MAX_SUPERSAMPLING, 'supersampling',
                     f'must be an integer from 1 to {MAX_SUPERSAMPLING}')
        for i, obj in enumerate(self.objects):
            if not self.table.contains(obj.xy):
                raise ParameterError(f'objects[{i}].xy', f'{list(obj.xy)} is not on the table')
        for j in range(len(self.objects)):
            for i in range(j):
                if _overlap(self.objects[i], self.objects[j]):
                    raise ParameterError(f'objects[{j}].xy', f'the block overlaps objects[{i}] on the table')
        for j, board in enumerate(self.boards):
            if not all(self.table.contains(corner) for corner in board.footprint()):
                raise ParameterError(f'boards[{j}].xy', f'the {board.size[0]:.3f} x {board.size[1]:.3f} m board '
                                                        f'(border included) does not lie wholly on the table')
            for i in range(j):
                if _overlap(self.boards[i], board):
                    raise ParameterError(f'boards[{j}].xy', f'the board overlaps boards[{i}] on the table')
        for j, prop in enumerate(self.props):
            if not all(self.table.contains(corner) for corner in prop.footprint()):
                raise ParameterError(f'props[{j}].xy', f'the {prop.shape} does not lie wholly on the table')
            if prop.shape == 'cup':
                for i, obj in enumerate(self.objects):
                    if _overlap(obj, prop):
                        raise ParameterError(f'props[{j}].xy', f'the cup overlaps objects[{i}] on the table')
                for i, other in enumerate(self.props[:j]):
                    if other.shape == 'cup' and _overlap(other, prop):
                        raise ParameterError(f'props[{j}].xy', f'the cup overlaps props[{i}] on the table')
        if isinstance(self.start, str):
            self.require(self.start in START_POSE_NAMES, 'start',
                         "must be 'down', 'angled', 'neutral' or a map of the 7 left-arm joints")
        else:
            from_mapping(_StartJoints, self.start, 'start')
        if self.respawn is not None:
            self._validate_respawn()
        nudge = self.faults.nudge
        if nudge is not None and nudge.object >= len(self.objects):
            raise ParameterError('faults.nudge.object', f'{nudge.object} but the scene has {len(self.objects)} '
                                                        'object(s) (blocks: boards do not count)')

    def _validate_respawn(self):
        """Every respawn pose puts the block on the table, clear of the other blocks' scene positions."""
        index = self.respawn.object
        if index >= len(self.objects):
            raise ParameterError('respawn.object', f'{index} but the scene has {len(self.objects)} object(s) '
                                                   '(blocks: boards do not count)')
        for k, (x, y, yaw) in enumerate(self.respawn.poses):
            moved = dataclasses.replace(self.objects[index], xy=(x, y), yaw=yaw)
            if not self.table.contains(moved.xy):
                raise ParameterError(f'respawn.poses[{k}]', f'{[x, y]} is not on the table')
            for i, other in enumerate(self.objects):
                if i != index and _overlap(moved, other):
                    raise ParameterError(f'respawn.poses[{k}]', f'the block would overlap objects[{i}] on the table')

    @classmethod
    def from_dict(cls, values, where=''):
        """Scene from a dictionary (parsed YAML), its ``objects`` list split into blocks (``objects``),
        chessboards (``boards``) and clutter (``props``); ``SceneError`` naming the bad key (``objects[i]``: the
        i-th entry of the list)."""
        positions = None
        if isinstance(values, dict):
            for key in ('boards', 'props'):
                if key in values:
                    raise SceneError(key, "unknown key: chessboards, tape and cups go in 'objects', with their "
                                          "'shape'")
            if 'appearance' in values:
                values = {**values, 'appearance': appearance.expand(values['appearance'])}
            values, positions = _split_entries(values)
        with _scene_errors(positions):
            return super().from_dict(values, where)

    def with_faults(self, faults):
        """This scene with ``faults`` (a ``Faults``) instead of its own; ``SceneError`` if they do not fit it."""
        scene = dataclasses.replace(self, faults=faults)
        with _scene_errors():
            scene.validate()
        return scene

    def start_positions(self, start_poses_path=None):
        """dict left-arm joint name -> angle (rad) of the start pose (named poses from ``config/start_poses.yaml``)."""
        if isinstance(self.start, dict):
            return dict(self.start)
        return load_start_poses(start_poses_path)[self.start]


@dataclass(frozen=True)
class _FaultsFile(Parameters):
    """A faults file: the ``faults:`` key of a scene file, nothing else."""
    faults: Faults = field(default_factory=Faults)


def load_scene(path=None):
    """Scene from a YAML file (default ``config/scenes/default.yaml``); ``SceneError`` prefixed with the path."""
    with _scene_errors():
        return Scene.from_yaml(path or DEFAULT_SCENE_YAML)


def load_faults(path):
    """``Faults`` of the ``faults:`` key of a YAML file (the same key as in a scene file, nothing else);
    ``SceneError`` prefixed with the path."""
    with _scene_errors():
        return _FaultsFile.from_yaml(path).faults


def _overlap(a, b):
    """True if the outlines (``footprint()``) of blocks or boards ``a`` and ``b`` on the table overlap (touching is
    fine)."""
    area, _ = cv2.intersectConvexConvex(a.footprint().astype(np.float32), b.footprint().astype(np.float32))
    return area > 1e-7                                         # m^2 (0.1 mm^2)
