"""Fault injection of the fake Baxter: what goes wrong, and when (no ROS, no PyBullet).

A scene's ``faults:`` key (see docs/fake_baxter.md "Fault injection") becomes a ``Faults``
(``Faults.from_dict``, via ``sim.scene``; ``params.ParameterError`` naming the key). Times are simulated
seconds since the fake Baxter started, lengths metres in ``base``, probabilities in 0..1. The world
(``sim.world``) acts out the physical faults (nudge, occluder, gripper misses and slips); the node
(``sim.node``) the camera, IK, command-delay and e-stop faults. Random faults take a uniform draw in [0, 1)
per decision from a generator seeded with the fake's ``--seed``, so a run is reproducible; the helpers here
only decide.
"""
import collections
import math
from dataclasses import dataclass, field
from typing import Optional, Tuple

import numpy as np

from baxter_pnp.params import ParameterError, Parameters

NUDGE_DURATION = 0.2            # s: default length of a nudge's push
OCCLUDER_COLOR = (0.5, 0.5, 0.5)
OCCLUDER_THICKNESS = 0.002      # m
TIME_ORIGINS = ('boot', 'camera_open')     # what fault times count from (Faults.time_origin)


@dataclass(frozen=True)
class Window(Parameters):
    """The simulated-time interval [``at``, ``at + duration``) (s)."""
    at: float
    duration: float

    def validate(self):
        self.require_non_negative('at')
        self.require_positive('duration')

    def contains(self, t):
        return self.at <= t < self.at + self.duration


@dataclass(frozen=True)
class CameraFaults(Parameters):
    """Faults of every open camera.

    ``drop_probability``: each frame is lost with this probability. ``latency`` (s): a frame is published
    this long after its capture, stamped with its capture time. ``stall``: no frame captured in this
    window is published (the stream stops). ``blackout``: frames captured in this window are black
    (sensor noise only). ``brightness_gain``: image intensities are multiplied by it (lighting change).
    """
    drop_probability: float = 0.0
    latency: float = 0.0
    stall: Optional[Window] = None
    blackout: Optional[Window] = None
    brightness_gain: float = 1.0

    def validate(self):
        self.require(0.0 <= self.drop_probability <= 1.0, 'drop_probability', 'must be a probability in 0..1')
        self.require_non_negative('latency', 'brightness_gain')

    def publishes(self, capture_time, uniform):
        """True if the frame captured at ``capture_time`` (s) is published; ``uniform``: its draw in [0, 1)."""
        stalled = self.stall is not None and self.stall.contains(capture_time)
        return not stalled and uniform >= self.drop_probability

    def gain(self, capture_time):
        """Intensity gain of the frame captured at ``capture_time`` (s): 0 in the blackout."""
        if self.blackout is not None and self.blackout.contains(capture_time):
            return 0.0
        return self.brightness_gain


@dataclass(frozen=True)
class Nudge(Parameters):
    """Block ``object`` (scene order) is pushed by ``offset`` (dx, dy) (m, base) in a straight slide that
    starts at ``at`` (s) and lasts ``duration`` (s), without rotating."""
    at: float
    offset: Tuple[float, float]
    object: int = 0
    duration: float = NUDGE_DURATION

    def validate(self):
        self.require_non_negative('at', 'duration')
        self.require(self.object >= 0, 'object', 'must be a non-negative integer')

    def displacement(self, t):
        """(2,) displacement (m) of the block at time ``t`` (s): 0 before ``at``, ``offset`` after the push,
        a smoothstep (zero speed at both ends) in between."""
        if t < self.at:
            return np.zeros(2)
        s = 1.0 if self.duration == 0 else min((t - self.at) / self.duration, 1.0)
        return np.multiply(self.offset, s * s * (3.0 - 2.0 * s))

    def moves_during(self, t0, t1):
        """True if the push moves the block during [``t0``, ``t1``] (s)."""
        return self.at <= t1 and t0 <= self.at + self.duration


@dataclass(frozen=True)
class Occluder(Parameters):
    """A thin horizontal plate hiding part of the table from the camera: centred above ``xy`` (m), ``size``
    (x, y) (m) before its ``yaw`` (rad) about base +z, its underside ``height`` (m) above the table top.
    Seen by the cameras only: nothing collides with it and the range sensor does not see it."""
    xy: Tuple[float, float]
    size: Tuple[float, float]
    height: float
    yaw: float = 0.0
    color: Tuple[float, float, float] = OCCLUDER_COLOR

    def validate(self):
        self.require_positive('size')
        self.require_non_negative('height')
        self.require(all(0.0 <= c <= 1.0 for c in self.color), 'color', 'RGB components must be in 0..1')


@dataclass(frozen=True)
class Box(Parameters):
    """Axis-aligned box in ``base``: corners ``min`` and ``max`` (x, y, z) (m)."""
    min: Tuple[float, float, float]
    max: Tuple[float, float, float]

    def validate(self):
        if not all(low <= high for low, high in zip(self.min, self.max)):
            raise ParameterError('', f'min must not exceed max on any axis (got min {list(self.min)}, '
                                     f'max {list(self.max)})')

    def contains(self, point):
        return bool(np.all(np.asarray(self.min) <= point) and np.all(np.asarray(point) <= self.max))


@dataclass(frozen=True)
class IKFaults(Parameters):
    """IK service faults: a pose fails with ``failure_probability``, or always when its target position
    lies in ``fail_region``; with ``absent`` the service is never advertised."""
    failure_probability: float = 0.0
    fail_region: Optional[Box] = None
    absent: bool = False

    def validate(self):
        self.require(0.0 <= self.failure_probability <= 1.0, 'failure_probability', 'must be a probability in 0..1')

    def fails(self, position_base, uniform):
        """True if the pose whose target origin is ``position_base`` (3,) (m, base) must fail; ``uniform``:
        its draw in [0, 1)."""
        in_region = self.fail_region is not None and self.fail_region.contains(position_base)
        return in_region or uniform < self.failure_probability


@dataclass(frozen=True)
class GripperFaults(Parameters):
    """The first ``miss_first`` closes of each gripper find nothing: the fingers pass through the blocks. The
    ``slip_first`` closes after those grip, but then let go of the block (it stays on the table when they rise)
    while the gripper keeps reporting ``gripping`` (it holds the opening it closed to until it next opens)."""
    miss_first: int = 0
    slip_first: int = 0

    def validate(self):
        self.require(self.miss_first >= 0, 'miss_first', 'must be a non-negative integer')
        self.require(self.slip_first >= 0, 'slip_first', 'must be a non-negative integer')

    def misses(self, attempt):
        """True if close attempt ``attempt`` (0 = the first) must miss."""
        return attempt < self.miss_first

    def slips(self, attempt):
        """True if close attempt ``attempt`` (0 = the first) must let the block slip (after the misses)."""
        return self.miss_first <= attempt < self.miss_first + self.slip_first


@dataclass(frozen=True)
class Faults(Parameters):
    """Every fault of a run. ``joint_command_delay`` (s): a JointCommand takes effect this long after it
    arrives. ``estop_at`` (s): the robot stops then, as on ``/robot/set_super_stop``. ``time_origin``:
    what the fault times (camera stall/blackout ``at``, ``nudge.at``, ``estop_at``) count from:
    ``'boot'`` (the fake's start) or ``'camera_open'`` (the first time any camera is opened, i.e. when an
    application starts looking; no timed fault happens before that)."""
    camera: CameraFaults = field(default_factory=CameraFaults)
    nudge: Optional[Nudge] = None
    occluder: Optional[Occluder] = None
    ik: IKFaults = field(default_factory=IKFaults)
    gripper: GripperFaults = field(default_factory=GripperFaults)
    joint_command_delay: float = 0.0
    estop_at: Optional[float] = None
    time_origin: str = 'boot'

    def validate(self):
        self.require_non_negative('joint_command_delay', 'estop_at')
        self.require(self.time_origin in TIME_ORIGINS, 'time_origin', 'must be one of %s' % ', '.join(TIME_ORIGINS))

    def summary(self):
        """One line naming the faults that differ from none, e.g. ``camera.latency=0.1, estop_at=10``."""
        default = Faults()
        parts = []
        for name in ('camera', 'ik', 'gripper'):
            group, none = getattr(self, name), getattr(default, name)
            parts += [f'{name}.{key}={_short(value)}' for key, value in vars(group).items()
                      if value != getattr(none, key)]
        parts += [f'{key}={_short(getattr(self, key))}'
                  for key in ('nudge', 'occluder', 'joint_command_delay', 'estop_at', 'time_origin')
                  if getattr(self, key) != getattr(default, key)]
        return ', '.join(parts) or 'none'


def _short(value):
    if isinstance(value, float):
        return f'{value:g}'
    if isinstance(value, tuple):
        return '[' + ', '.join(_short(v) for v in value) + ']'
    if hasattr(value, '__dataclass_fields__'):
        return '{' + ', '.join(f'{k}: {_short(v)}' for k, v in vars(value).items()) + '}'
    return str(value)


class DelayLine:
    """First in, first out: items come out ``delay`` seconds (simulated) after they went in."""

    def __init__(self, delay):
        if not (math.isfinite(delay) and delay >= 0):
            raise ValueError(f'delay must be a non-negative number of seconds, got {delay!r}')
        self.delay = float(delay)
        self._queue = collections.deque()

    def put(self, now, item):
        """Queue ``item`` at time ``now`` (s)."""
        self._queue.append((now + self.delay, item))

    def due(self, now):
        """The items whose delay has passed at time ``now`` (s), oldest first (removed from the line)."""
        items = []
        while self._queue and self._queue[0][0] <= now + 1e-9:
            items.append(self._queue.popleft()[1])
        return items

    def __len__(self):
        return len(self._queue)
