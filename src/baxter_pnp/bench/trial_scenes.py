"""Random scenes of the batch trials: where a block can stand so that the application sees and can pick it.

A scene is a dict in the ``sim/scene.py`` schema (``Scene.from_dict``). Frames: ``base`` (Baxter's), the hand
camera's optical frame, ``block`` (top-face centre, docs/ARCHITECTURE.md). Metres and radians; image
positions in pixels of the application's 640x400 hand-camera mode. The views come from the published camera
model and forward kinematics of the URDF at the named start poses (``config/start_poses.yaml``); the
fingers' footprint in the image from the fake's own rendering (:func:`rendered_hand_clearance_px`).
"""
import functools
import math

import cv2
import numpy as np
import yaml
from scipy.spatial.transform import Rotation

from baxter_pnp import pick, view
from baxter_pnp.camera import load_default_camera
from baxter_pnp.kinematics import ArmKinematics, load_start_poses
from baxter_pnp.models import SHAPES, model_for
from baxter_pnp.sim.appearance import preset_look, random_appearance
from baxter_pnp.sim.scene import Scene, Table, load_faults
from baxter_pnp.sim.world import SimWorld
from baxter_pnp.transforms import invert, make_transform, raised, transform_points

SIDE = 'left'
CAMERA_RESOLUTION = (640, 400)        # the pick application's hand-camera mode
BLOCK_HEIGHT = 0.02                   # m, height of every generated block
TARGET = ('square', 'green')
COLOURS_RGB = {'green': (0.1, 0.7, 0.1), 'red': (0.8, 0.1, 0.1), 'blue': (0.1, 0.2, 0.8),
               'yellow': (0.85, 0.8, 0.1)}   # all inside the HSV ranges of config/vision.yaml
DISTRACTOR_MIN_DISTANCE = 0.08        # m between block centres (target and distractors)
HAND_GREY_LEVEL = 120                 # rendered pixels darker than this are the hand (table ~210, floor ~255)
APPEARANCES = ('clean', 'baxter', 'random')   # run_trials.py --appearance
APPEARANCE_STREAM = 1                 # the random look's generator: (trial seed, this), apart from the placements
CLUTTER_STREAM = 2                    # the random clutter's generator (``--appearance random``): (trial seed, this)
CLUTTER_GREYS = {'black': (0.04, 0.10), 'white': (0.85, 0.95)}    # grey level ranges of the achromatic cubes
CUP_COLOURS = {'white': (0.92, 0.92, 0.9), **COLOURS_RGB}
CLUTTER_MARGIN = 0.05                 # m between clutter and a block's outline (a cup: CUP_CLEARANCE to the target)
CUP_CLEARANCE = 0.15                  # m from a cup's side to the target's centre: the fingers come down beside it
# m: blocks keep this far from a pick and place's place position: the application counts a block within two sides
# (<= 2 x 50 mm) of it as already placed (task.target)
PLACE_CLEARANCE = 0.10


@functools.lru_cache(maxsize=None)
def _kinematics():
    return ArmKinematics(SIDE)


@functools.lru_cache(maxsize=None)
def start_view(start_pose):
    """(T_base_camera, T_base_gripper, camera, q_start) at a named start pose (``config/start_poses.yaml``).

    ``camera`` is the published hand-camera model at the application's resolution (640x400).
    """
    kinematics = _kinematics()
    q_start = np.array([load_start_poses()[start_pose][name] for name in kinematics.joint_names])
    camera = load_default_camera().scaled(*CAMERA_RESOLUTION)
    return (kinematics.fk(q_start, f'{SIDE}_hand_camera'), kinematics.fk(q_start, f'{SIDE}_gripper'), camera,
            q_start)


def block_pose(xy, yaw, table_top_z, height=BLOCK_HEIGHT):
    """T_base_block (top-face centre frame, docs/ARCHITECTURE.md) of a block standing on the table at
    ``xy`` (m) rotated ``yaw`` (rad) about base +z."""
    return make_transform(Rotation.from_euler('z', yaw), (xy[0], xy[1], table_top_z + height))


@functools.lru_cache(maxsize=None)
def rendered_hand_clearance_px(start_pose):
    """(H, W) float array: distance (pixels) of each pixel of the start-pose view to the nearest pixel where
    the hand (open gripper fingers) hides the table.

    Found by rendering the empty table (``SimWorld``, the fake's renderer) from the start pose with the
    gripper fully open, as the application's first look sees it, under the ``clean`` look (a footprint, whatever
    the trials' look): the fingers render dark (grey level < ``HAND_GREY_LEVEL``), the table and floor light.
    """
    _, _, camera, _ = start_view(start_pose)
    world = SimWorld(Scene(start=start_pose, appearance=preset_look('clean')))
    world.command_gripper(SIDE, 100.0, velocity_percent=100.0)
    world.step(480)
    image = world.render_camera(f'{SIDE}_hand_camera', camera, np.random.default_rng(0))
    free = (cv2.cvtColor(image, cv2.COLOR_BGR2GRAY) >= HAND_GREY_LEVEL).astype(np.uint8)
    return cv2.distanceTransform(free, cv2.DIST_L2, 5)


def top_face_in_view(T_base_block, model, T_base_camera, camera, margin_px, clearance_px=None):
    """True if every top-face vertex is in front of the camera and projects (with distortion) at least
    ``margin_px`` pixels inside the image and, given ``clearance_px`` (see :func:`rendered_hand_clearance_px`),
    the whole face is more than ``margin_px`` pixels from anything the hand hides."""
    points_camera = transform_points(invert(T_base_camera) @ T_base_block, model.vertices)
    if np.any(points_camera[:, 2] <= 0.05):
        return False
    pixels = camera.project(points_camera)
    if not (np.all(pixels >= margin_px) and np.all(pixels[:, 0] <= camera.width - 1 - margin_px)
            and np.all(pixels[:, 1] <= camera.height - 1 - margin_px)):
        return False
    return clearance_px is None or view.polygon_clear(pixels, clearance_px, margin_px)


def on_table(T_base_block, model, table):
    """True if the whole top face lies over the table top."""
    return all(table.contains(v[:2]) for v in transform_points(T_base_block, model.vertices))


def pickable(T_base_block, side, start_pose):
    """True if the arm has IK solutions for the application's hover, grasp and lift poses of this block
    (default ``PickConfig``, fingers pointing down, aligned with the block's faces)."""
    T_base_camera, T_base_gripper, camera, q_start = start_view(start_pose)
    config = pick.PickConfig(side_length=side)
    T_grasp = pick.grasp_pose(T_base_block, config, T_base_gripper)
    targets = (pick.hover_pose(T_base_block, config, T_base_gripper), T_grasp, raised(T_grasp, config.lift_height))
    return all(_kinematics().ik(T, seed=q_start) is not None for T in targets)


def _view_footprint(T_base_camera, camera, plane_z):
    """(min xy, max xy) of the image corners' rays on the horizontal plane z = ``plane_z`` (m)."""
    corners = np.array([[0, 0], [camera.width - 1, 0], [camera.width - 1, camera.height - 1],
                        [0, camera.height - 1]], dtype=float)
    rays = np.c_[camera.undistort_points(corners), np.ones(4)] @ T_base_camera[:3, :3].T
    reach = (plane_z - T_base_camera[2, 3]) / rays[:, 2]
    if np.any(reach <= 0):
        raise ValueError('the start pose does not look down at the table')
    xy = T_base_camera[:2, 3] + reach[:, None] * rays[:, :2]
    return xy.min(axis=0), xy.max(axis=0)


def draw_placement(rng, shape, start_pose, table=None, side=None, size_range=(0.03, 0.05), require_pickable=False,
                   avoid=(), margin_px=20.0, max_attempts=5000):
    """(side (m), yaw (rad), xy (2,) m in base) of a random block of ``shape`` standing on the table.

    ``side`` uniform in ``size_range`` unless given, yaw uniform in [-pi, pi), position uniform over the
    part of the table where the block's whole top face is seen from ``start_pose`` with ``margin_px`` pixels
    to spare, from the image border and from the open gripper's fingers (published camera model at 640x400,
    forward kinematics of the URDF, :func:`rendered_hand_clearance_px`); with ``require_pickable``, the arm must also
    reach the hover, grasp and lift poses (:func:`pickable`). ``avoid``: [(xy (m), distance (m))], positions
    the block's centre must stay at least that far from. ``rng`` is a ``numpy.random.Generator``. Raises
    RuntimeError if no placement is found in ``max_attempts`` draws.
    """
    table = table or Table()
    T_base_camera, _, camera, _ = start_view(start_pose)
    clearance = rendered_hand_clearance_px(start_pose)
    low, high = _view_footprint(T_base_camera, camera, table.top_z + BLOCK_HEIGHT)
    low = np.maximum(low, np.subtract(table.center, np.divide(table.size, 2)))
    high = np.minimum(high, np.add(table.center, np.divide(table.size, 2)))
    for _ in range(max_attempts):
        block_side = float(rng.uniform(*size_range)) if side is None else side
        yaw = float(rng.uniform(-math.pi, math.pi))
        xy = rng.uniform(low, high)
        model = model_for(shape, block_side, BLOCK_HEIGHT)
        T_base_block = block_pose(xy, yaw, table.top_z)
        if any(np.linalg.norm(xy - np.asarray(other)) < distance for other, distance in avoid):
            continue
        if not (on_table(T_base_block, model, table)
                and top_face_in_view(T_base_block, model, T_base_camera, camera, margin_px, clearance)):
            continue
        if require_pickable and not pickable(T_base_block, block_side, start_pose):
            continue
        return block_side, yaw, xy
    raise RuntimeError(f'no {shape} placement in view from {start_pose!r} after {max_attempts} draws')


def block_entry(shape, colour, side, yaw, xy):
    """Scene-file entry of a generated block (rounded to 0.01 mm and 0.01 mrad)."""
    return {'shape': shape, 'side': round(side, 5), 'height': BLOCK_HEIGHT, 'color': list(COLOURS_RGB[colour]),
            'xy': [round(float(xy[0]), 5), round(float(xy[1]), 5)], 'yaw': round(yaw, 5)}


def scene_dict(objects, start_pose, table, **extra):
    """A validated scene dict (``sim/scene.py`` schema) of generated ``objects``; ``extra``: more top-level keys."""
    scene = {'table': {'top_z': table.top_z, 'center': list(table.center), 'size': list(table.size)},
             'objects': objects, 'start': start_pose,
             'camera_error': {'xyz': [0, 0, 0], 'rpy': [0, 0, 0], 'focal_scale': 1.0}, **extra}
    Scene.from_dict(scene)          # validates (SceneError on a bug here)
    return scene


def random_scene(rng, start_pose, size_range=(0.03, 0.05), distractors=0, same_colour_distractor=False,
                 margin_px=20.0, table=None, faults=None, appearance=None, clutter_rng=None, place_xy=None):
    """A random scene dict (``sim/scene.py`` schema) with one green square the application can pick.

    The target (``objects[0]``): drawn by :func:`draw_placement` (whole top face in view from
    ``start_pose``, pickable). ``distractors`` other blocks (random shape and colour, never a green
    square, same sizes, also in view) stand at least 8 cm from every other block; with
    ``same_colour_distractor`` one more block has the target's colour but another shape (triangle,
    pentagon or hexagon; the last block). ``faults``: the scene's ``faults:`` mapping (``sim/faults.py``
    schema), none if None. ``appearance``: the scene's ``appearance:`` value (a preset name or a mapping,
    ``sim/appearance.py``; see :func:`trial_appearance`), none (the fake's default look) if None. ``clutter_rng``:
    a generator to draw :func:`random_clutter` with (after the blocks), none if None. ``place_xy``: the place
    position (m, base) of a pick and place, which every block keeps ``PLACE_CLEARANCE`` from (the application takes
    a block there for one already placed), None without. ``rng`` is a ``numpy.random.Generator``.
    """
    table = table or Table()
    objects, placed = [], []
    keep_off = [] if place_xy is None else [(tuple(place_xy), PLACE_CLEARANCE)]

    def add(shape, colour, require_pickable=False):
        side, yaw, xy = draw_placement(rng, shape, start_pose, table, size_range=size_range, margin_px=margin_px,
                                       require_pickable=require_pickable,
                                       avoid=[(other, DISTRACTOR_MIN_DISTANCE) for other in placed] + keep_off)
        objects.append(block_entry(shape, colour, side, yaw, xy))
        placed.append(xy)

    add(*TARGET, require_pickable=True)
    others = [(s, c) for s in SHAPES for c in COLOURS_RGB if (s, c) != TARGET]
    for _ in range(distractors):
        add(*others[rng.integers(len(others))])
    if same_colour_distractor:
        same_colour = [s for s in SHAPES if s != TARGET[0]]
        add(same_colour[rng.integers(len(same_colour))], TARGET[1])
    if clutter_rng is not None:
        objects += random_clutter(clutter_rng, start_pose, table, placed)
    extra = {} if faults is None else {'faults': faults}
    if appearance is not None:
        extra['appearance'] = appearance
    return scene_dict(objects, start_pose, table, **extra)


def random_clutter(rng, start_pose, table, blocks_xy):
    """``objects`` entries of random clutter around the blocks at ``blocks_xy`` (the target first; m, base), in or
    near the view from ``start_pose``: a chessboard (half the time), 0-2 strips of tape of any block colour (the
    target's too), 0-2 black or white cubes, a cup (half the time, ``CUP_CLEARANCE`` from the target). Everything
    keeps ``CLUTTER_MARGIN`` from the blocks and from each other; what finds no place in 200 draws is left out.
    ``rng``: a ``numpy.random.Generator``."""
    T_base_camera, _, camera, _ = start_view(start_pose)
    low, high = _view_footprint(T_base_camera, camera, table.top_z)
    half = np.divide(table.size, 2) - 0.02
    low = np.maximum(low - 0.1, np.subtract(table.center, half))
    high = np.minimum(high + 0.1, np.add(table.center, half))
    taken = [(np.asarray(xy), 0.03) for xy in blocks_xy]             # (centre, radius) of what stands there
    entries = []

    def place(radius, target_clearance=0.0):
        inner_low = np.maximum(low, np.subtract(table.center, half) + radius)        # wholly on the table
        inner_high = np.minimum(high, np.add(table.center, half) - radius)
        if np.any(inner_low >= inner_high):
            return None
        for _ in range(200):
            xy = rng.uniform(inner_low, inner_high)
            if all(np.linalg.norm(xy - centre) >= radius + other + CLUTTER_MARGIN for centre, other in taken) and \
                    np.linalg.norm(xy - blocks_xy[0]) >= radius + target_clearance:
                taken.append((xy, radius))
                return [round(float(v), 4) for v in xy]
        return None

    colours = list(COLOURS_RGB)
    if rng.random() < 0.5:
        pattern = [int(rng.integers(4, 7)), int(rng.integers(3, 6))]
        square = round(float(rng.uniform(0.02, 0.03)), 4)
        xy = place(0.5 * math.hypot(*((np.add(pattern, 3)) * square)))
        if xy is not None:
            entries.append({'shape': 'chessboard', 'pattern': pattern, 'square': square, 'xy': xy,
                            'yaw': round(float(rng.uniform(-math.pi, math.pi)), 4)})
    for _ in range(int(rng.integers(0, 3))):
        length, width = round(float(rng.uniform(0.06, 0.15)), 4), round(float(rng.uniform(0.012, 0.025)), 4)
        xy = place(length / 2)
        if xy is not None:
            entries.append({'shape': 'tape', 'xy': xy, 'length': length, 'width': width,
                            'color': list(COLOURS_RGB[colours[rng.integers(len(colours))]]),
                            'yaw': round(float(rng.uniform(-math.pi, math.pi)), 4)})
    for _ in range(int(rng.integers(0, 3))):
        side = round(float(rng.uniform(0.025, 0.045)), 4)
        grey = round(float(rng.uniform(*CLUTTER_GREYS[('black', 'white')[rng.integers(2)]])), 3)
        xy = place(side / math.sqrt(2))
        if xy is not None:
            entries.append({'shape': 'square', 'side': side, 'height': side, 'color': [grey] * 3, 'xy': xy,
                            'yaw': round(float(rng.uniform(-math.pi, math.pi)), 4)})
    if rng.random() < 0.5:
        radius = round(float(rng.uniform(0.03, 0.045)), 4)
        xy = place(radius, CUP_CLEARANCE)
        if xy is not None:
            names = list(CUP_COLOURS)
            entries.append({'shape': 'cup', 'xy': xy, 'radius': radius,
                            'height': round(float(rng.uniform(0.08, 0.11)), 4),
                            'color': list(CUP_COLOURS[names[rng.integers(len(names))]])})
    return entries


def trial_appearance(choice, seed):
    """The ``appearance:`` value of a trial's scene for ``run_trials.py --appearance choice``: the preset name
    (``'clean'``, ``'baxter'``), or for ``random`` a look drawn by
    ``sim.appearance.random_appearance`` from the trial's ``seed`` (its own generator stream, so the same seed
    gives the same look and the same placements as with any other choice)."""
    if choice not in APPEARANCES:
        raise ValueError(f'appearance must be one of {APPEARANCES}, not {choice!r}')
    if choice == 'random':
        return random_appearance(np.random.default_rng([seed, APPEARANCE_STREAM]))
    return choice


def trial_clutter_rng(choice, seed):
    """The generator of a trial's clutter for ``run_trials.py --appearance choice``: its own stream of the trial's
    ``seed`` for ``random`` (domain randomisation of the scene's clutter too), None (no clutter) otherwise."""
    return np.random.default_rng([seed, CLUTTER_STREAM]) if choice == 'random' else None


def load_faults_mapping(path):
    """The ``faults:`` mapping of a YAML file (the format of ``fake_baxter.py --faults``: a file holding a
    ``faults:`` key, ``sim/faults.py`` schema), validated; ``SceneError`` naming the path and the key."""
    load_faults(path)
    with open(path) as f:
        return yaml.safe_load(f).get('faults') or {}


# ============================================================================================ multi-block tasks
# run_trials.py --task sort|stack (bench/table_trials.py): random scenes of several 40 mm blocks for table_task.py.
TABLE_TASK_SIDE = 0.04                            # m: table_task.py poses every block with one side length
SORT_BINS = {'green': (0.45, 0.35), 'red': (0.45, 0.0)}     # --bin COLOUR:X,Y of the sort trials
SORT_COUNTS = {'green': 2, 'red': 2}              # named squares per colour; plus one distractor
STACK_AT = (0.47, 0.10)                           # --at of the stack trials
STACK_ORDER = ('red', 'green', 'blue')            # --order, bottom first
TABLE_TASK_AREA = ((0.58, 0.80), (-0.30, 0.48))   # (x range, y range) m where the random blocks stand
TABLE_TASK_MIN_DISTANCE = 0.10                    # m between block centres (and from the bins / the tower)


def table_task_places(task):
    """The xy (m) a task's trials keep the random blocks away from: the bins' first slots or the tower."""
    if task == 'sort':
        return [(x, y - 0.08 * k) for colour, (x, y) in SORT_BINS.items() for k in range(SORT_COUNTS[colour])]
    return [STACK_AT]


def random_table_scene(rng, task, table=None, appearance=None, max_attempts=5000):
    """A random scene dict for ``table_task.py sort`` (``SORT_COUNTS`` green and red squares and a distractor: a
    blue or yellow block of any shape) or ``stack`` (a square of each ``STACK_ORDER`` colour): 40 mm blocks at
    uniform random positions in ``TABLE_TASK_AREA`` with uniform yaws, each pickable from the ``down`` pose
    (:func:`pickable`) and ``TABLE_TASK_MIN_DISTANCE`` from the others and from the task's places; start pose
    ``down``. ``rng``: a ``numpy.random.Generator``."""
    table = table or Table()
    if task == 'sort':
        kinds = [('square', colour) for colour, count in SORT_COUNTS.items() for _ in range(count)]
        kinds.append((list(SHAPES)[rng.integers(len(SHAPES))], ('blue', 'yellow')[rng.integers(2)]))
    elif task == 'stack':
        kinds = [('square', colour) for colour in STACK_ORDER]
    else:
        raise ValueError(f"task must be 'sort' or 'stack', not {task!r}")
    (x_low, x_high), (y_low, y_high) = TABLE_TASK_AREA
    taken, objects = list(table_task_places(task)), []
    for shape, colour in kinds:
        for _ in range(max_attempts):
            xy = rng.uniform((x_low, y_low), (x_high, y_high))
            yaw = float(rng.uniform(-math.pi, math.pi))
            if all(np.linalg.norm(xy - np.asarray(other)) >= TABLE_TASK_MIN_DISTANCE for other in taken) and \
                    pickable(block_pose(xy, yaw, table.top_z), TABLE_TASK_SIDE, 'down'):
                break
        else:
            raise RuntimeError(f'no place for a {colour} {shape} after {max_attempts} draws')
        taken.append(xy)
        objects.append(block_entry(shape, colour, TABLE_TASK_SIDE, yaw, xy))
    return scene_dict(objects, 'down', table, **({} if appearance is None else {'appearance': appearance}))
