"""Scene description of the fake Baxter: table, blocks, start pose, camera error, faults (YAML, validated).

Lengths in metres and angles in radians, in Baxter's ``base`` frame (see docs/ARCHITECTURE.md)::

    table: {top_z: -0.15, center: [0.75, 0.0], size: [0.9, 1.5]}
    objects:
      - {shape: square, side: 0.04, height: 0.02, color: [0.1, 0.7, 0.1], xy: [0.70, 0.25], yaw: 0.4}
    start: down      # 'down' | 'angled' | 'neutral' (config/start_poses.yaml) | {left_s0: ..., ..., left_w2: ...}
    camera_error: {xyz: [0, 0, 0], rpy: [0, 0, 0], focal_scale: 1.0}
    faults: {camera: {drop_probability: 0.2}, estop_at: 10.0}     # sim.faults; docs/fake_baxter.md
    respawn: {poses: [[0.62, 0.30, 0.5], [0.70, 0.18, -1.0]], delay: 2.0, object: 0}   # (x m, y m, yaw rad)

``table``, ``start``, ``camera_error``, ``faults`` and ``respawn`` (and each of their keys, except
``respawn.poses``), an object's ``height`` and ``yaw`` are optional (the values above are the defaults; no
faults and no respawn by default); an object's ``shape``, ``side``, ``color`` and ``xy`` are required, and
blocks may not overlap. Every problem raises ``SceneError`` whose message starts with the key.
"""
import dataclasses
import math
import os
from dataclasses import dataclass, field
from typing import Optional

import cv2
import numpy as np
import yaml

from baxter_pnp.kinematics import arm_joint_names, load_start_poses
from baxter_pnp.models import SHAPES, model_for
from baxter_pnp.runtime import PACKAGE_ROOT
from baxter_pnp.sim.faults import (NUDGE_DURATION, OCCLUDER_COLOR, Box, CameraFaults, Faults, GripperFaults,
                                   IKFaults, Nudge, Occluder, Window)
from baxter_pnp.transforms import from_xyz_rpy

DEFAULT_SCENE_YAML = os.path.join(PACKAGE_ROOT, 'config', 'scenes', 'default.yaml')
RESPAWN_DELAY = 2.0             # s (simulated): default wait of a respawn (see Respawn)
TIME_ORIGINS = ('boot', 'camera_open')     # what fault times count from (sim/faults.py)


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

    def footprint(self):
        """(n, 2) vertices (m, base x-y) of the block's outline on the table."""
        c, s = math.cos(self.yaw), math.sin(self.yaw)
        return self.model.vertices[:, :2] @ np.array([[c, s], [-s, c]]) + self.xy


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
class Respawn:
    """The fake re-places block ``object`` (scene order) for endless pick-and-place runs (soak tests).

    Once the block has been lifted (its underside at least 3 cm above the table top) and is then at rest on
    the table again, released (every gripper open or touching it with neither finger) and with every
    gripper tip at least 8 cm above its top, for ``delay`` seconds of simulated time, it is moved, at rest,
    to the next of ``poses`` (x (m), y (m), yaw (rad) of its top-face centre, in ``base``), cycling through
    them. ``sim.world.SimWorld`` acts it out (docs/fake_baxter.md "Scene file")."""
    poses: tuple
    delay: float = RESPAWN_DELAY
    object: int = 0


@dataclass(frozen=True)
class Scene:
    """A validated scene. ``start`` is a start-pose name or a dict of the 7 left-arm joint angles (rad);
    ``faults`` a ``sim.faults.Faults`` (none by default); ``respawn`` a ``Respawn`` or None."""
    table: Table = field(default_factory=Table)
    objects: tuple = ()
    start: object = 'down'
    camera_error: CameraError = field(default_factory=CameraError)
    faults: Faults = field(default_factory=Faults)
    respawn: Optional[Respawn] = None

    def __post_init__(self):
        nudge = self.faults.nudge
        if nudge is not None and nudge.object >= len(self.objects):
            raise SceneError(f'faults.nudge.object: {nudge.object} but the scene has {len(self.objects)} object(s)')

    @classmethod
    def from_dict(cls, d):
        """Scene from a dictionary (parsed YAML); ``SceneError`` naming the bad key."""
        d = _mapping(d, 'scene', {'table', 'objects', 'start', 'camera_error', 'faults', 'respawn'})
        table = _table(d.get('table', {}))
        objects = d.get('objects', [])
        if not isinstance(objects, list):
            raise SceneError('objects: must be a list')
        parsed = tuple(_object(o, f'objects[{i}]', table) for i, o in enumerate(objects))
        _check_no_overlap(parsed)
        respawn = None if d.get('respawn') is None else _respawn(d['respawn'], table, parsed)
        return cls(table, parsed, _start(d.get('start', 'down')), _camera_error(d.get('camera_error', {})),
                   _faults(d.get('faults', {})), respawn)

    def with_faults(self, faults):
        """This scene with ``faults`` (a ``Faults``) instead of its own; ``SceneError`` if they do not fit it."""
        return dataclasses.replace(self, faults=faults)

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


def load_faults(path):
    """``Faults`` of the ``faults:`` key of a YAML file (the same key as in a scene file, nothing else);
    ``SceneError`` prefixed with the path."""
    with open(path) as f:
        d = yaml.safe_load(f)
    try:
        return _faults(_mapping(d, 'file', {'faults'}).get('faults', {}))
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


def _non_negative(value, key):
    if _number(value, key) < 0:
        raise SceneError(f'{key}: must be a non-negative number')
    return float(value)


def _probability(value, key):
    if not 0.0 <= _number(value, key) <= 1.0:
        raise SceneError(f'{key}: must be a probability in 0..1')
    return float(value)


def _count(value, key):
    if isinstance(value, bool) or not isinstance(value, int) or value < 0:
        raise SceneError(f'{key}: must be a non-negative integer')
    return value


def _vector(value, key, length, positive=False):
    if not isinstance(value, (list, tuple)) or len(value) != length:
        raise SceneError(f'{key}: must be a list of {length} numbers')
    return tuple(_number(v, f'{key}[{i}]', positive) for i, v in enumerate(value))


def _color(value, key):
    color = _vector(value, key, 3)
    if not all(0.0 <= c <= 1.0 for c in color):
        raise SceneError(f'{key}: RGB components must be in 0..1')
    return color


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
    color = _color(d['color'], f'{key}.color')
    xy = _vector(d['xy'], f'{key}.xy', 2)
    if not table.contains(xy):
        raise SceneError(f'{key}.xy: {list(xy)} is not on the table')
    return SceneObject(d['shape'], _number(d['side'], f'{key}.side', positive=True), color, xy,
                       _number(d.get('height', 0.02), f'{key}.height', positive=True),
                       _number(d.get('yaw', 0.0), f'{key}.yaw'))


def _overlap(a, b):
    """True if the outlines of scene objects ``a`` and ``b`` on the table overlap (touching is fine)."""
    area, _ = cv2.intersectConvexConvex(a.footprint().astype(np.float32), b.footprint().astype(np.float32))
    return area > 1e-7                                         # m^2 (0.1 mm^2)


def _check_no_overlap(objects):
    """SceneError naming the later of two blocks whose outlines on the table overlap (touching is fine)."""
    for j in range(len(objects)):
        for i in range(j):
            if _overlap(objects[i], objects[j]):
                raise SceneError(f'objects[{j}].xy: the block overlaps objects[{i}] on the table')


def _respawn(d, table, objects):
    """``Respawn`` of the ``respawn:`` mapping; every pose must put the block on the table, clear of the other
    blocks' scene positions."""
    d = _mapping(d, 'respawn', {'poses', 'delay', 'object'})
    _required(d, 'respawn', ('poses',))
    index = _count(d.get('object', 0), 'respawn.object')
    if index >= len(objects):
        raise SceneError(f'respawn.object: {index} but the scene has {len(objects)} object(s)')
    if not isinstance(d['poses'], list) or not d['poses']:
        raise SceneError('respawn.poses: must be a non-empty list of [x, y, yaw]')
    poses = tuple(_vector(pose, f'respawn.poses[{k}]', 3) for k, pose in enumerate(d['poses']))
    for k, (x, y, yaw) in enumerate(poses):
        moved = dataclasses.replace(objects[index], xy=(x, y), yaw=yaw)
        if not table.contains(moved.xy):
            raise SceneError(f'respawn.poses[{k}]: {[x, y]} is not on the table')
        for i, other in enumerate(objects):
            if i != index and _overlap(moved, other):
                raise SceneError(f'respawn.poses[{k}]: the block would overlap objects[{i}] on the table')
    return Respawn(poses, _non_negative(d.get('delay', RESPAWN_DELAY), 'respawn.delay'), index)


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


# ------------------------------------------------------------------------------------------- faults
def _faults(d, key='faults'):
    d = _mapping(d, key, {'camera', 'nudge', 'occluder', 'ik', 'gripper', 'joint_command_delay', 'estop_at',
                          'time_origin'})
    if d.get('time_origin', 'boot') not in TIME_ORIGINS:
        raise SceneError(f'{key}.time_origin: must be one of {", ".join(TIME_ORIGINS)}')

    def optional(name, parse):
        return None if d.get(name) is None else parse(d[name], f'{key}.{name}')
    return Faults(camera=_camera_faults(d.get('camera', {}), f'{key}.camera'),
                  nudge=optional('nudge', _nudge),
                  occluder=optional('occluder', _occluder),
                  ik=_ik_faults(d.get('ik', {}), f'{key}.ik'),
                  gripper=_gripper_faults(d.get('gripper', {}), f'{key}.gripper'),
                  joint_command_delay=_non_negative(d.get('joint_command_delay', 0.0), f'{key}.joint_command_delay'),
                  estop_at=optional('estop_at', _non_negative),
                  time_origin=d.get('time_origin', 'boot'))


def _required(d, key, names):
    for name in names:
        if name not in d:
            raise SceneError(f'{key}.{name}: missing')


def _window(d, key):
    d = _mapping(d, key, {'at', 'duration'})
    _required(d, key, ('at', 'duration'))
    return Window(_non_negative(d['at'], f'{key}.at'), _number(d['duration'], f'{key}.duration', positive=True))


def _camera_faults(d, key):
    d = _mapping(d, key, {'drop_probability', 'latency', 'stall', 'blackout', 'brightness_gain'})
    return CameraFaults(
        drop_probability=_probability(d.get('drop_probability', 0.0), f'{key}.drop_probability'),
        latency=_non_negative(d.get('latency', 0.0), f'{key}.latency'),
        stall=None if d.get('stall') is None else _window(d['stall'], f'{key}.stall'),
        blackout=None if d.get('blackout') is None else _window(d['blackout'], f'{key}.blackout'),
        brightness_gain=_non_negative(d.get('brightness_gain', 1.0), f'{key}.brightness_gain'))


def _nudge(d, key):
    d = _mapping(d, key, {'at', 'offset', 'object', 'duration'})
    _required(d, key, ('at', 'offset'))
    return Nudge(_non_negative(d['at'], f'{key}.at'), _vector(d['offset'], f'{key}.offset', 2),
                 _count(d.get('object', 0), f'{key}.object'),
                 _non_negative(d.get('duration', NUDGE_DURATION), f'{key}.duration'))


def _occluder(d, key):
    d = _mapping(d, key, {'xy', 'size', 'height', 'yaw', 'color'})
    _required(d, key, ('xy', 'size', 'height'))
    return Occluder(_vector(d['xy'], f'{key}.xy', 2), _vector(d['size'], f'{key}.size', 2, positive=True),
                    _non_negative(d['height'], f'{key}.height'), _number(d.get('yaw', 0.0), f'{key}.yaw'),
                    _color(d.get('color', OCCLUDER_COLOR), f'{key}.color'))


def _ik_faults(d, key):
    d = _mapping(d, key, {'failure_probability', 'fail_region', 'absent'})
    region = None
    if d.get('fail_region') is not None:
        region_key = f'{key}.fail_region'
        r = _mapping(d['fail_region'], region_key, {'min', 'max'})
        _required(r, region_key, ('min', 'max'))
        region = Box(_vector(r['min'], f'{region_key}.min', 3), _vector(r['max'], f'{region_key}.max', 3))
        if not all(low <= high for low, high in zip(region.min, region.max)):
            raise SceneError(f'{region_key}: min must not exceed max on any axis')
    absent = d.get('absent', False)
    if not isinstance(absent, bool):
        raise SceneError(f'{key}.absent: must be true or false')
    return IKFaults(_probability(d.get('failure_probability', 0.0), f'{key}.failure_probability'), region, absent)


def _gripper_faults(d, key):
    d = _mapping(d, key, {'miss_first'})
    return GripperFaults(_count(d.get('miss_first', 0), f'{key}.miss_first'))
