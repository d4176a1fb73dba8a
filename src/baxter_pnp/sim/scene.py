"""Scene description of the fake Baxter: table, blocks, start pose, camera error (YAML, validated).

Lengths in metres and angles in radians, in Baxter's ``base`` frame (see docs/ARCHITECTURE.md)::

    table: {top_z: -0.15, center: [0.75, 0.0], size: [0.9, 1.5]}
    objects:
      - {shape: square, side: 0.04, height: 0.02, color: [0.1, 0.7, 0.1], xy: [0.70, 0.25], yaw: 0.4}
    start: down      # 'down' | 'angled' | 'neutral' (config/start_poses.yaml) | {left_s0: ..., ..., left_w2: ...}
    camera_error: {xyz: [0, 0, 0], rpy: [0, 0, 0], focal_scale: 1.0}

``table``, ``start`` and ``camera_error`` (and each of their keys), an object's ``height`` and
``yaw`` are optional (the values above are the defaults); an object's ``shape``, ``side``, ``color``
and ``xy`` are required. Every problem raises ``SceneError`` whose message starts with the key.
"""
import math
import os
from dataclasses import dataclass, field

import numpy as np
import yaml

from baxter_pnp.kinematics import arm_joint_names, load_start_poses
from baxter_pnp.models import SHAPES, model_for
from baxter_pnp.runtime import PACKAGE_ROOT
from baxter_pnp.transforms import from_xyz_rpy

DEFAULT_SCENE_YAML = os.path.join(PACKAGE_ROOT, 'config', 'scenes', 'default.yaml')


class SceneError(ValueError):
    """An invalid scene; the message names the offending key (``objects[1].side: ...``)."""


@dataclass(frozen=True)
class Table:
    """Static table: top face at ``z = top_z``, centred at ``center`` (x, y), ``size`` (x, y) in metres."""
    top_z: float = -0.15
    center: tuple = (0.75, 0.0)
    size: tuple = (0.9, 1.5)

    def contains(self, xy):
        """True if the point ``xy`` (m) lies on the table top."""
        return bool(np.all(np.abs(np.subtract(xy, self.center)) <= np.divide(self.size, 2.0)))


@dataclass(frozen=True)
class SceneObject:
    """A block standing on the table: a regular prism (``shape``, ``side``, ``height`` in m), RGB ``color``
    in 0..1, top-face centre above ``xy`` (m), rotated ``yaw`` (rad) about base +z."""
    shape: str
    side: float
    color: tuple
    xy: tuple
    height: float = 0.02
    yaw: float = 0.0

    @property
    def model(self):
        """The block's ``models.PolygonModel``."""
        return model_for(self.shape, self.side, self.height)


@dataclass(frozen=True)
class CameraError:
    """The true hand camera minus the published one: mount offset ``xyz`` (m) and ``rpy`` (rad, URDF
    fixed-axis) in the published optical frame, and the ratio ``focal_scale`` of true to published focal lengths."""
    xyz: tuple = (0.0, 0.0, 0.0)
    rpy: tuple = (0.0, 0.0, 0.0)
    focal_scale: float = 1.0

    @property
    def T_published_true(self):
        """4x4 pose of the true camera optical frame in the published one."""
        return from_xyz_rpy(self.xyz, self.rpy)


@dataclass(frozen=True)
class Scene:
    """A validated scene. ``start`` is a start-pose name or a dict of the 7 left-arm joint angles (rad)."""
    table: Table = field(default_factory=Table)
    objects: tuple = ()
    start: object = 'down'
    camera_error: CameraError = field(default_factory=CameraError)

    @classmethod
    def from_dict(cls, d):
        """Scene from a dictionary (parsed YAML); ``SceneError`` naming the bad key."""
        d = _mapping(d, 'scene', {'table', 'objects', 'start', 'camera_error'})
        table = _table(d.get('table', {}))
        objects = d.get('objects', [])
        if not isinstance(objects, list):
            raise SceneError('objects: must be a list')
        parsed = tuple(_object(o, f'objects[{i}]', table) for i, o in enumerate(objects))
        return cls(table, parsed, _start(d.get('start', 'down')), _camera_error(d.get('camera_error', {})))

    def start_positions(self, start_poses_path=None):
        """dict left-arm joint name -> angle (rad) of the start pose (named poses from ``config/start_poses.yaml``)."""
        if isinstance(self.start, dict):
            return dict(self.start)
        return load_start_poses(start_poses_path)[self.start]


def load_scene(path=None):
    """Scene from a YAML file (default ``config/scenes/default.yaml``); ``SceneError`` prefixed with the path."""
    path = path or DEFAULT_SCENE_YAML
    with open(path) as f:
        d = yaml.safe_load(f)
    try:
        return Scene.from_dict(d)
    except SceneError as error:
        raise SceneError(f'{path}: {error}') from None


# ------------------------------------------------------------------------------------------- validation
def _mapping(value, key, allowed):
    if not isinstance(value, dict):
        raise SceneError(f'{key}: must be a mapping')
    for k in value:
        if k not in allowed:
            raise SceneError(f'{key}.{k}: unknown key (expected one of {sorted(allowed)})')
    return value


def _number(value, key, positive=False):
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise SceneError(f'{key}: must be a {"positive " if positive else ""}number')
    if positive and value <= 0:
        raise SceneError(f'{key}: must be a positive number')
    return float(value)


def _vector(value, key, length, positive=False):
    if not isinstance(value, (list, tuple)) or len(value) != length:
        raise SceneError(f'{key}: must be a list of {length} numbers')
    return tuple(_number(v, f'{key}[{i}]', positive) for i, v in enumerate(value))


def _table(d):
    d = _mapping(d, 'table', {'top_z', 'center', 'size'})
    default = Table()
    return Table(_number(d.get('top_z', default.top_z), 'table.top_z'),
                 _vector(d.get('center', default.center), 'table.center', 2),
                 _vector(d.get('size', default.size), 'table.size', 2, positive=True))


def _object(d, key, table):
    d = _mapping(d, key, {'shape', 'side', 'height', 'color', 'xy', 'yaw'})
    for required in ('shape', 'side', 'color', 'xy'):
        if required not in d:
            raise SceneError(f'{key}.{required}: missing')
    if d['shape'] not in SHAPES:
        raise SceneError(f'{key}.shape: must be one of {sorted(SHAPES, key=SHAPES.get)}, got {d["shape"]!r}')
    color = _vector(d['color'], f'{key}.color', 3)
    if not all(0.0 <= c <= 1.0 for c in color):
        raise SceneError(f'{key}.color: RGB components must be in 0..1')
    xy = _vector(d['xy'], f'{key}.xy', 2)
    if not table.contains(xy):
        raise SceneError(f'{key}.xy: {list(xy)} is not on the table')
    return SceneObject(d['shape'], _number(d['side'], f'{key}.side', positive=True), color, xy,
                       _number(d.get('height', 0.02), f'{key}.height', positive=True),
                       _number(d.get('yaw', 0.0), f'{key}.yaw'))


def _start(value):
    if isinstance(value, str):
        if value not in ('down', 'angled', 'neutral'):
            raise SceneError(f"start: must be 'down', 'angled', 'neutral' or a map of the 7 left-arm joints, "
                             f"got {value!r}")
        return value
    names = arm_joint_names('left')
    d = _mapping(value, 'start', set(names))
    missing = [n for n in names if n not in d]
    if missing:
        raise SceneError(f'start.{missing[0]}: missing (a start map needs all of {names})')
    return {n: _number(d[n], f'start.{n}') for n in names}


def _camera_error(d):
    d = _mapping(d, 'camera_error', {'xyz', 'rpy', 'focal_scale'})
    return CameraError(_vector(d.get('xyz', (0, 0, 0)), 'camera_error.xyz', 3),
                       _vector(d.get('rpy', (0, 0, 0)), 'camera_error.rpy', 3),
                       _number(d.get('focal_scale', 1.0), 'camera_error.focal_scale', positive=True))
