"""Multi-block table tasks, pure: where each block goes when sorting, clearing or stacking (issue 14).

Input: the blocks of a ``table_map.TableMap`` (``MapBlock`` s: id, shape, colour, fused position in ``base``);
output: a list of :class:`Move` s (which block, from where, to which table position, on which stack level).
Metres and radians in ``base``; the table top is level at ``table_z`` for the levels' heights.

Rules (issue 14, item 4):

- **slots**: blocks put down in an area stand in a row from the area's position along ``direction``, ``spacing``
  apart (``per_row`` to a row, the next row ``spacing`` further along the perpendicular to the left), so they
  never touch and the open fingers fit between them (:func:`slots`);
- **never where another stands**: a slot is *free* when no block of the map other than the one moved, and no
  slot already given to another move, lies within ``clearance`` of it (:func:`is_free`); a block already in one
  of its area's slots stays where it is;
- **stack**: the first colour's block goes to the tower's position (or stays, if it is there), each next one on
  the block below (level k: its bottom on level k-1's top face, ``table_z + (k - 1) * height``); the tower's
  position must be free of every block that is not part of it.

``PlanError`` (a ValueError) says in words a user understands why a task cannot be planned.
"""
import math
from dataclasses import dataclass, field
from typing import List, NamedTuple, Tuple

import numpy as np

from baxter_pnp import models, perception, pick

SLOT_SPACING = 0.08         # m between slot centres: a 4 cm block, the open fingers (5.8 cm gap, ~1 cm paddles) fit
CLEARANCE = 0.07            # m: a slot is free when no other block's centre is this close
IN_PLACE = 0.015            # m: a block this close to a slot (or the tower's position) is already there
MAX_SLOTS = 40              # slots tried per area before giving up


@dataclass
class TableTaskConfig(pick.PickConfig):
    """``table_task.py``'s parameters: the pick's (``pick.PickConfig``: how each block is picked) and these
    (metres); config/table_task.yaml."""

    slot_spacing: float = SLOT_SPACING      # between the centres of blocks put down in a row
    clearance: float = CLEARANCE            # a place is free when no other block's centre is this close
    row_direction: List[float] = field(default_factory=lambda: [0.0, -1.0])   # a bin's row runs this way (base x, y)
    clear_per_row: int = 3                  # clear: blocks to a row of the area
    place_tolerance: float = IN_PLACE       # a block seen this close to its place (xy) was put there
    stack_tolerance: float = 0.01           # a stacked block seen this close (xy) to the one below stands on it
    level_tolerance: float = 0.01           # a block's top this close to a level's height stands on that level
                                            # (half a block: the estimates from 0.4 m are up to ~1 cm deep)
    max_level: int = 4                      # stack levels a look accepts
    step_retries: int = 1                   # a step whose look does not verify it is tried again this often

    def validate(self):
        super().validate()
        self.require_positive('slot_spacing', 'clearance', 'place_tolerance', 'stack_tolerance', 'level_tolerance',
                              'max_level', 'clear_per_row')
        self.require(self.level_tolerance <= 0.5 * self.block_height, 'level_tolerance',
                     'must not exceed half the block height (a block would stand on two levels)')
        self.require(len(self.row_direction) == 2 and np.hypot(*self.row_direction) > 0, 'row_direction',
                     'must be a non-zero [x, y]')
        self.require(self.clearance <= self.slot_spacing, 'clearance', 'must not exceed slot_spacing')
        self.require(self.step_retries >= 0, 'step_retries', 'must be >= 0')


class PlanError(ValueError):
    """The task cannot be planned (message for the user)."""


class Move(NamedTuple):
    """Put block ``block_id`` (``shape``, ``colour``, now at ``from_xy``) at ``to_xy`` (m in base) on stack
    ``level`` (1: on the table, k: on the level k-1 block)."""
    block_id: int
    shape: str
    colour: str
    from_xy: Tuple[float, float]
    to_xy: Tuple[float, float]
    level: int = 1

    def to_json(self):
        return {'block_id': int(self.block_id), 'shape': self.shape, 'colour': self.colour,
                'from_xy': [round(float(v), 5) for v in self.from_xy],
                'to_xy': [round(float(v), 5) for v in self.to_xy],
                'level': int(self.level)}


def parse_xy(text, option):
    """(x, y) in metres from ``'X,Y'``; PlanError naming ``option`` otherwise."""
    try:
        x, y = (float(v) for v in str(text).split(','))
    except ValueError:
        raise PlanError('%s: expected X,Y in metres (e.g. 0.6,0.3), got %r' % (option, text)) from None
    if not (math.isfinite(x) and math.isfinite(y)):
        raise PlanError('%s: X and Y must be finite numbers, got %r' % (option, text))
    return x, y


def parse_bin(text):
    """(colour, (x, y)) of a ``--bin COLOUR:X,Y`` value."""
    colour, sep, xy = str(text).partition(':')
    if not sep or not colour.strip():
        raise PlanError('--bin: expected COLOUR:X,Y (e.g. green:0.6,0.3), got %r' % text)
    return colour.strip(), parse_xy(xy, '--bin %s' % colour.strip())


def parse_order(text):
    """The colours of ``--order C1,C2,...`` (bottom first), at least two."""
    colours = [c.strip() for c in str(text).split(',') if c.strip()]
    if len(colours) < 2:
        raise PlanError('--order: expected at least two colours, bottom first (e.g. red,green,blue), got %r' % text)
    return colours


def slots(origin_xy, direction=(0.0, -1.0), spacing=SLOT_SPACING, per_row=None):
    """Endless generator of slot centres (x, y) (m): ``origin_xy``, then every ``spacing`` along ``direction``
    (normalised), ``per_row`` to a row (None: one row), each next row ``spacing`` along ``direction`` turned
    +90 deg about +z."""
    d = np.asarray(direction, dtype=float)
    d = d / np.linalg.norm(d)
    across = np.array([-d[1], d[0]])
    k = 0
    while True:
        along, row = (k, 0) if per_row is None else (k % per_row, k // per_row)
        yield tuple(np.asarray(origin_xy, dtype=float) + spacing * (along * d + row * across))
        k += 1


def is_free(xy, blocks, clearance=CLEARANCE, ignore=(), taken=()):
    """True if no block of ``blocks`` (``MapBlock`` s; those whose id is in ``ignore`` aside) and no position of
    ``taken`` (xy, m) lies within ``clearance`` (m) of ``xy``."""
    xy = np.asarray(xy, dtype=float)
    near = [b.position[:2] for b in blocks if b.id not in ignore] + [np.asarray(t, dtype=float) for t in taken]
    return all(np.linalg.norm(xy - p) >= clearance for p in near)


def _wanted(block, colours, shape):
    return block.colour in colours and (shape is None or block.shape == shape)


def plan_to_areas(blocks, areas, shape=None, spacing=SLOT_SPACING, clearance=CLEARANCE, direction=(0.0, -1.0),
                  per_row=None, placeable=None, in_place=IN_PLACE, fixed=()):
    """Moves that put every block of a colour named in ``areas`` ({colour: (x, y) of its area's first slot}; the
    key None: every colour) and of ``shape`` (None: any) into its area's slots (:func:`slots`). A block already
    in a slot of its area stays; the others, nearest to their area first, take the next free slot (``is_free``
    against every block but themselves and the slots given so far) that ``placeable(xy)`` accepts (on the
    table, reachable; None: all). Blocks of other colours or shapes, and those whose id is in ``fixed`` (given
    up), are not moved. PlanError when an area has no free placeable slot within MAX_SLOTS."""
    def area_of(block):
        return block.colour if block.colour in areas else None

    named = [b for b in blocks if (None in areas or b.colour in areas) and (shape is None or b.shape == shape)]
    area_slots = {key: [s for s, _ in zip(slots(xy, direction, spacing, per_row), range(MAX_SLOTS))]
                  for key, xy in areas.items()}
    taken, staying = [], set()
    for block in named:         # blocks already in one of their area's slots keep it
        for slot in area_slots[area_of(block)]:
            if np.linalg.norm(block.position[:2] - slot) <= in_place and not any(
                    np.linalg.norm(np.subtract(slot, t)) < 1e-9 for t in taken):
                taken.append(slot)
                staying.add(block.id)
                break
    moves = []
    movers = sorted((b for b in named if b.id not in staying and b.id not in fixed),
                    key=lambda b: float(np.linalg.norm(b.position[:2] - np.asarray(areas[area_of(b)]))))
    for block in movers:
        key = area_of(block)
        slot = next((s for s in area_slots[key] if is_free(s, blocks, clearance, ignore=(block.id,), taken=taken)
                     and (placeable is None or placeable(s))), None)
        if slot is None:
            raise PlanError('no free place for the %s %s near (%.3f, %.3f) m: the area is full or out of reach '
                            '(%d slots %.0f mm apart tried)' % (block.colour, block.shape, *areas[key],
                                                               MAX_SLOTS, 1000 * spacing))
        taken.append(slot)
        moves.append(Move(block.id, block.shape, block.colour, tuple(block.position[:2]), tuple(slot)))
    return moves


def plan_sort(blocks, bins, shape=None, **options):
    """``sort --bin COLOUR:X,Y ...``: every block of a bin's colour (and ``shape``) into a row starting at its
    bin; the others stay (:func:`plan_to_areas`, ``options`` passed on)."""
    if not bins:
        raise PlanError('sort: name at least one bin (--bin COLOUR:X,Y)')
    return plan_to_areas(blocks, dict(bins), shape, **options)


def plan_clear(blocks, to_xy, shape=None, per_row=3, **options):
    """``clear --to X,Y``: every block (of ``shape``) into one area, rows of ``per_row`` starting at ``to_xy``."""
    return plan_to_areas(blocks, {None: tuple(to_xy)}, shape, per_row=per_row, **options)


def plan_stack(blocks, at_xy, order, shape=None, clearance=CLEARANCE, placeable=None, in_place=IN_PLACE):
    """``stack --at X,Y --order C1,C2,...``: the moves of a tower at ``at_xy``: for each colour of ``order``
    (bottom first) the block of that colour (and ``shape``) nearest the tower, level 1, 2, ...; level 1 has no
    move when its block already stands at ``at_xy``. PlanError when a colour has no block, the spot is taken
    by a block that is not part of the tower, or ``placeable(at_xy)`` is False."""
    at_xy = tuple(float(v) for v in at_xy)
    if placeable is not None and not placeable(at_xy):
        raise PlanError('stack: (%.3f, %.3f) m is off the table or out of the arm\'s reach' % at_xy)
    chosen = []
    for level, colour in enumerate(order, start=1):
        candidates = [b for b in blocks if _wanted(b, (colour,), shape) and b.id not in {c.id for c in chosen}]
        if not candidates:
            raise PlanError('stack: no %s%s left on the table for level %d (map: %s)'
                            % (colour, '' if shape is None else ' ' + shape, level, describe(blocks)))
        chosen.append(min(candidates, key=lambda b: float(np.linalg.norm(b.position[:2] - np.asarray(at_xy)))))
    bottom_in_place = np.linalg.norm(chosen[0].position[:2] - np.asarray(at_xy)) <= in_place
    in_the_way = [b for b in blocks if not (bottom_in_place and b.id == chosen[0].id)
                  and np.linalg.norm(b.position[:2] - np.asarray(at_xy)) < clearance]
    if in_the_way:
        raise PlanError('stack: (%.3f, %.3f) m is taken by the %s: choose a free spot'
                        % (*at_xy, ', '.join('%s %s' % (b.colour, b.shape) for b in in_the_way)))
    return [Move(b.id, b.shape, b.colour, tuple(b.position[:2]), at_xy, level)
            for level, b in enumerate(chosen, start=1) if not (level == 1 and bottom_in_place)]


def level_of(z_top, table_z, height, tolerance):
    """The stack level (1: on the table) of a block whose top face is at ``z_top`` (m), or None when it is not
    within ``tolerance`` (m) of a level's top (``table_z + level * height``)."""
    level = int(round((z_top - table_z) / height))
    return level if level >= 1 and abs(z_top - (table_z + level * height)) <= tolerance else None


def on_height(T_base_block, camera_xyz, z):
    """``T_base_block`` (4x4, m in base) moved along the ray from the camera at ``camera_xyz`` (m in base) through its
    origin until the origin is at height ``z`` (m): a pose estimate whose depth is off, put on the known height of
    its top face (the image position, which the estimate fits best, kept)."""
    T = np.array(T_base_block, dtype=float)
    camera_xyz = np.asarray(camera_xyz, dtype=float)
    ray = T[:3, 3] - camera_xyz
    T[:3, 3] = camera_xyz + ray * (z - camera_xyz[2]) / ray[2]
    return T


def displaced(before, after, moved_ids, tolerance=IN_PLACE):
    """The blocks of ``before`` (``MapBlock`` s) not in ``moved_ids`` that ``after`` (a later map's blocks) no
    longer has within ``tolerance`` (m, xy) with their shape and colour: knocked over, pushed or taken."""
    return [b for b in before if b.id not in moved_ids
            and not any(a.shape == b.shape and a.colour == b.colour
                        and np.linalg.norm(a.position[:2] - b.position[:2]) <= tolerance for a in after)]


def describe(blocks):
    """One line of text naming ``blocks`` (``MapBlock`` s)."""
    return ', '.join('%s %s at (%.3f, %.3f)' % (b.colour, b.shape, *b.position[:2]) for b in blocks) or 'no blocks'


def block_line(block):
    """The ``survey`` subcommand's line for a ``MapBlock``: id, colour, shape, position (mm), yaw (deg), std, views."""
    x, y, z = 1000.0 * np.asarray(block.position, dtype=float)
    return ('block %d: %s %s at x %.1f y %.1f z %.1f mm, yaw %.1f deg, +- %.1f mm, %d view(s)'
            % (block.id, block.colour, block.shape, x, y, z, math.degrees(block.yaw), 1000.0 * block.std,
               block.views))


def level_of_pose(pose, T_base_camera, table, config):
    """The stack level (1: on the table) of a believable ``pose.PoseEstimate`` (camera frame; ``T_base_camera`` the
    camera's pose in base, ``table`` the table top, a ``models.Plane`` in base, ``config`` a ``TableTaskConfig``),
    None for an estimate not to trust: none, a residual over ``max_residual_px``, a top face farther than
    ``level_tolerance`` from every level's height, or above ``max_level``."""
    if pose is None or pose.residual_px > config.max_residual_px:
        return None
    position = (T_base_camera @ pose.T_camera_object)[:3, 3]
    level = level_of(position[2], table.z_at(position[:2]), config.block_height, config.level_tolerance)
    return level if level is not None and level <= config.max_level else None


def on_level(observation, camera, T_base_camera, table, level, config):
    """``(pose, refitted)``: ``observation``'s (a ``perception.BlockObservation``) pose when it is on stack
    ``level`` (``level_of_pose``); when its own pose is on no level, or one level off, or it has none,
    ``pose_on_level``'s (its top face or silhouette on that level) if that fits, ``refitted`` True; else
    ``(None, False)``. A look checks the level a block was put on: a pose 10-15 mm off lands on the next level (every
    height is within ``level_tolerance``, half a block, of some level), and the face's size cannot tell two
    neighbouring levels apart (one level is 6 % of it from 0.33 m); a pose two levels off stays there."""
    found = level_of_pose(observation.pose, T_base_camera, table, config)
    if found == level:
        return observation.pose, False
    if found is not None and abs(found - level) > 1:
        return None, False
    pose = pose_on_level(observation.detection, camera, T_base_camera, table, level, config.side_length,
                         config.block_height, config.edge_radius)
    return pose, pose is not None


def pose_on_level(detection, camera, T_base_camera, table, level, side, height, edge_radius=0.0):
    """The ``perception.pose_on_plane`` pose (camera frame) of ``detection`` as a ``side`` x ``height`` (m) block on
    stack ``level`` (its bottom on ``table``, a ``models.Plane`` in base, raised by ``level - 1`` heights): its polygon
    as that level's top face where it is that face in shape and size, else its blob's silhouette (top and side faces:
    a side face kept in the polygon) where that fits; else None. A look that checks a block put on a known level
    tests that hypothesis: the polygon pose's depth comes from the face's size, and a pixel of rim or side face in
    the polygon puts it 10-15 mm off from 0.3 m, on no level or the next one (docs/survey.md); fitted on the level,
    the block is where it stands within millimetres. Its size cannot tell two levels apart (one level is 6 % of the
    size from 0.33 m, a polygon's error as much): the look's knowledge of the level is the test."""
    if level < 1:
        raise ValueError(f'pose_on_level: levels start at 1, got {level}')
    plane = models.table_plane_in_camera(T_base_camera, table.raised((level - 1) * height))
    return perception.pose_on_plane(detection, camera, side, height, plane, edge_radius)
