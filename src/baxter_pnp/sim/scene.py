"""Scene description of the fake Baxter: table, blocks, start pose, camera error, faults (YAML, validated).

Lengths in metres and angles in radians, in Baxter's ``base`` frame (see docs/ARCHITECTURE.md)::

    table: {top_z: -0.15, center: [0.75, 0.0], size: [0.9, 1.5]}
    objects:
      - {shape: square, side: 0.04, height: 0.02, color: [0.1, 0.7, 0.1], xy: [0.70, 0.25], yaw: 0.4}
    start: down      # 'down' | 'angled' | 'neutral' (config/start_poses.yaml) | {left_s0: ..., ..., left_w2: ...}
    camera_error: {xyz: [0, 0, 0], rpy: [0, 0, 0], focal_scale: 1.0}
    faults: {camera: {drop_probability: 0.2}, estop_at: 10.0}     # sim.faults; docs/fake_baxter.md
    respawn: {poses: [[0.62, 0.30, 0.5], [0.70, 0.18, -1.0]], delay: 2.0, object: 0}   # (x m, y m, yaw rad)
    appearance: clean    # 'clean' | 'baxter' | {preset: baxter, exposure: 0.5, ...}: sim.appearance

``table``, ``start``, ``camera_error``, ``faults``, ``respawn`` and ``appearance`` (and each of their keys, except
``respawn.poses``), an object's ``height`` and ``yaw`` are optional (the values above are the defaults; no
faults and no respawn by default); an object's ``shape``, ``side``, ``color`` and ``xy`` are required, and
blocks may not overlap. Every problem raises ``SceneError`` whose message starts with the key (checked by
``params``: each dataclass below from its mapping, then its ``validate``).
"""
import contextlib
import dataclasses
import math
import os
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
START_POSE_NAMES = ('down', 'angled', 'neutral')       # config/start_poses.yaml


class SceneError(ParameterError):
    """An invalid scene; the message starts with the offending key (``objects[1].side: ...``)."""


@contextlib.contextmanager
def _scene_errors():
    """Every ParameterError raised inside re-raised as a SceneError (same key and message)."""
    try:
        yield
    except ParameterError as error:
        raise SceneError(error.key, error.problem) from None


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
        self.require(self.shape in SHAPES, 'shape', f'must be one of {sorted(SHAPES, key=SHAPES.get)}')
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
    """A validated scene. ``start`` is a start-pose name or a dict of the 7 left-arm joint angles (rad);
    ``faults`` a ``sim.faults.Faults`` (none by default); ``respawn`` a ``Respawn`` or None. ``validate``
    checks what lies between the sections: blocks on the table and apart, the respawn poses, the objects
    that ``respawn`` and ``faults.nudge`` name."""
    table: Table = field(default_factory=Table)
    objects: Tuple[SceneObject, ...] = ()
    start: Union[str, Dict[str, float]] = 'down'
    camera_error: CameraError = field(default_factory=CameraError)
    faults: Faults = field(default_factory=Faults)
    respawn: Optional[Respawn] = None
    appearance: AppearanceConfig = field(default_factory=AppearanceConfig)

    def validate(self):
        for i, obj in enumerate(self.objects):
            if not self.table.contains(obj.xy):
                raise ParameterError(f'objects[{i}].xy', f'{list(obj.xy)} is not on the table')
        for j in range(len(self.objects)):
            for i in range(j):
                if _overlap(self.objects[i], self.objects[j]):
                    raise ParameterError(f'objects[{j}].xy', f'the block overlaps objects[{i}] on the table')
        if isinstance(self.start, str):
            self.require(self.start in START_POSE_NAMES, 'start',
                         "must be 'down', 'angled', 'neutral' or a map of the 7 left-arm joints")
        else:
            from_mapping(_StartJoints, self.start, 'start')
        if self.respawn is not None:
            self._validate_respawn()
        nudge = self.faults.nudge
        if nudge is not None and nudge.object >= len(self.objects):
            raise ParameterError('faults.nudge.object',
                                 f'{nudge.object} but the scene has {len(self.objects)} object(s)')

    def _validate_respawn(self):
        """Every respawn pose puts the block on the table, clear of the other blocks' scene positions."""
        index = self.respawn.object
        if index >= len(self.objects):
            raise ParameterError('respawn.object', f'{index} but the scene has {len(self.objects)} object(s)')
        for k, (x, y, yaw) in enumerate(self.respawn.poses):
            moved = dataclasses.replace(self.objects[index], xy=(x, y), yaw=yaw)
            if not self.table.contains(moved.xy):
                raise ParameterError(f'respawn.poses[{k}]', f'{[x, y]} is not on the table')
            for i, other in enumerate(self.objects):
                if i != index and _overlap(moved, other):
                    raise ParameterError(f'respawn.poses[{k}]', f'the block would overlap objects[{i}] on the table')

    @classmethod
    def from_dict(cls, values, where=''):
        """Scene from a dictionary (parsed YAML); ``SceneError`` naming the bad key."""
        if isinstance(values, dict) and 'appearance' in values:
            values = {**values, 'appearance': appearance.expand(values['appearance'])}
        with _scene_errors():
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
    """True if the outlines of scene objects ``a`` and ``b`` on the table overlap (touching is fine)."""
    area, _ = cv2.intersectConvexConvex(a.footprint().astype(np.float32), b.footprint().astype(np.float32))
    return area > 1e-7                                         # m^2 (0.1 mm^2)
