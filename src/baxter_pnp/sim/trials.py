"""Batch pick trials on the fake Baxter: random scenes, the full ``pick_square.py`` run, ground-truth scoring.

``scripts/run_trials.py --trials N --seed S --mode all --start-pose both`` draws N random scenes per start
pose (:func:`random_scene`), runs the unmodified pick application on each scene in each mode against a
fresh fake Baxter (:func:`run_trial`), scores every run with the simulator's ground truth and prints a
per-mode table (:func:`summarise`, :func:`format_table`); ``trials.csv``, ``summary.json`` and the plots go
to ``--out``. ``--faults FILE`` and ``--distractor-same-colour`` run a batch under faults; every row records
its conditions (:func:`condition`). ``--soak N`` runs N pick-and-place cycles in one application run against
one fake that respawns the block (:func:`run_soak`), scoring each cycle with the ground truth and watching
both processes' memory. See docs/trials.md.

Ground truth (``/fake_baxter/object_poses``, the gripper pose of ``/robot/limb/left/endpoint_state``) is
read here, by the runner only; the application never sees it. Scores (metres in, millimetres out):

- *lifted*: the block's top face rose at least ``LIFT_THRESHOLD`` (5 cm) above its height in the scene;
- *centring error*: the norm of the block centre's (x, y) in the ``left_gripper`` frame after the lift,
  i.e. its offset from the gripper axis (fingers close along y, so x carries most of it);
- *pre-close offset*: the same (x, y) just before the gripper first started closing (the servo's true
  accuracy, before the fingers push the block);
- a *verified pick* = the application reports success AND the block is lifted.
"""
import argparse
import csv
import functools
import json
import math
import os
import sys
import threading
import time
from typing import NamedTuple

import cv2
import numpy as np
import yaml
from scipy.spatial.transform import Rotation

from baxter_pnp import pick, servo
from baxter_pnp.camera import load_default_camera
from baxter_pnp.kinematics import ArmKinematics, load_start_poses
from baxter_pnp.models import SHAPES, model_for
from baxter_pnp.sim.scene import RESPAWN_DELAY, Scene, SceneError, Table, load_faults
from baxter_pnp.sim.world import SimWorld
from baxter_pnp.transforms import invert, make_transform, pose_msg_to_matrix, transform_points

SIDE = 'left'
CAMERA_RESOLUTION = (640, 400)        # the pick application's hand-camera mode
BLOCK_HEIGHT = 0.02                   # m, height of every generated block
TARGET = ('square', 'green')
COLOURS_RGB = {'green': (0.1, 0.7, 0.1), 'red': (0.8, 0.1, 0.1), 'blue': (0.1, 0.2, 0.8),
               'yellow': (0.85, 0.8, 0.1)}   # all inside the HSV ranges of config/vision.yaml
LIFT_THRESHOLD = 0.05                 # m the block must rise for a pick to count as lifted
DISTRACTOR_MIN_DISTANCE = 0.08        # m between block centres (target and distractors)
HAND_GREY_LEVEL = 120                 # rendered pixels darker than this are the hand (table ~210, floor ~255)
MODES = pick.MODES
START_POSES = ('down', 'angled')
PLACE_TOLERANCE = 0.01          # m: a placed block must end this close to the requested position
CSV_FIELDS = ('mode', 'start_pose', 'trial', 'seed', 'side_mm', 'yaw_deg', 'x_m', 'y_m', 'distractors',
              'same_colour_distractor', 'faults', 'app_success', 'failure_reason', 'verified', 'lifted', 'rise_mm',
              'centring_mm', 'centring_x_mm', 'centring_y_mm', 'pre_close_offset_mm', 'place_error_mm', 'time_s',
              'steps', 'grasp_attempts', 'final_error_mm_est', 'wall_s', 'returncode', 'timed_out', 'trial_dir')


# ============================================================================================ scenes (pure)

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
def hand_clearance_px(start_pose):
    """(H, W) float array: distance (pixels) of each pixel of the start-pose view to the nearest pixel where
    the hand (open gripper fingers) hides the table.

    Found by rendering the empty table (``SimWorld``, the fake's renderer) from the start pose with the
    gripper fully open, as the application's first look sees it; the fingers render dark (grey level
    < ``HAND_GREY_LEVEL``), the table and floor light.
    """
    _, _, camera, _ = start_view(start_pose)
    world = SimWorld(Scene(start=start_pose))
    world.command_gripper(SIDE, 100.0, velocity_percent=100.0)
    world.step(480)
    image = world.render_camera(f'{SIDE}_hand_camera', camera, np.random.default_rng(0))
    free = (cv2.cvtColor(image, cv2.COLOR_BGR2GRAY) >= HAND_GREY_LEVEL).astype(np.uint8)
    return cv2.distanceTransform(free, cv2.DIST_L2, 5)


def top_face_in_view(T_base_block, model, T_base_camera, camera, margin_px, clearance_px=None):
    """True if every top-face vertex is in front of the camera and projects (with distortion) at least
    ``margin_px`` pixels inside the image and, given ``clearance_px`` (see :func:`hand_clearance_px`),
    the whole face is more than ``margin_px`` pixels from anything the hand hides."""
    points_camera = transform_points(invert(T_base_camera) @ T_base_block, model.vertices)
    if np.any(points_camera[:, 2] <= 0.05):
        return False
    pixels = camera.project(points_camera)
    if not (np.all(pixels >= margin_px) and np.all(pixels[:, 0] <= camera.width - 1 - margin_px)
            and np.all(pixels[:, 1] <= camera.height - 1 - margin_px)):
        return False
    return clearance_px is None or servo.polygon_clear(pixels, clearance_px, margin_px)


def on_table(T_base_block, model, table):
    """True if the whole top face lies over the table top."""
    return all(table.contains(v[:2]) for v in transform_points(T_base_block, model.vertices))


def pickable(T_base_block, side, start_pose):
    """True if the arm has IK solutions for the application's hover, grasp and lift poses of this block
    (default ``PickConfig``, fingers pointing down, aligned with the block's faces)."""
    T_base_camera, T_base_gripper, camera, q_start = start_view(start_pose)
    config = pick.PickConfig(side_length=side)
    T_grasp = pick.grasp_pose(T_base_block, config, T_base_gripper)
    targets = (pick.hover_pose(T_base_block, config, T_base_gripper), T_grasp, pick.raised(T_grasp, config.lift_height))
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
    forward kinematics of the URDF, :func:`hand_clearance_px`); with ``require_pickable``, the arm must also
    reach the hover, grasp and lift poses (:func:`pickable`). ``avoid``: [(xy (m), distance (m))], positions
    the block's centre must stay at least that far from. ``rng`` is a ``numpy.random.Generator``. Raises
    RuntimeError if no placement is found in ``max_attempts`` draws.
    """
    table = table or Table()
    T_base_camera, _, camera, _ = start_view(start_pose)
    clearance = hand_clearance_px(start_pose)
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


def _block(shape, colour, side, yaw, xy):
    """Scene-file entry of a generated block (rounded to 0.01 mm and 0.01 mrad)."""
    return {'shape': shape, 'side': round(side, 5), 'height': BLOCK_HEIGHT, 'color': list(COLOURS_RGB[colour]),
            'xy': [round(float(xy[0]), 5), round(float(xy[1]), 5)], 'yaw': round(yaw, 5)}


def _scene_dict(objects, start_pose, table, **extra):
    """A validated scene dict (``sim/scene.py`` schema) of generated ``objects``; ``extra``: more top-level keys."""
    scene = {'table': {'top_z': table.top_z, 'center': list(table.center), 'size': list(table.size)},
             'objects': objects, 'start': start_pose,
             'camera_error': {'xyz': [0, 0, 0], 'rpy': [0, 0, 0], 'focal_scale': 1.0}, **extra}
    Scene.from_dict(scene)          # validates (SceneError on a bug here)
    return scene


def random_scene(rng, start_pose, size_range=(0.03, 0.05), distractors=0, same_colour_distractor=False,
                 margin_px=20.0, table=None, faults=None):
    """A random scene dict (``sim/scene.py`` schema) with one green square the application can pick.

    The target (``objects[0]``): drawn by :func:`draw_placement` (whole top face in view from
    ``start_pose``, pickable). ``distractors`` other blocks (random shape and colour, never a green
    square, same sizes, also in view) stand at least 8 cm from every other block; with
    ``same_colour_distractor`` one more block has the target's colour but another shape (triangle,
    pentagon or hexagon; the last object). ``faults``: the scene's ``faults:`` mapping (``sim/faults.py``
    schema), none if None. ``rng`` is a ``numpy.random.Generator``.
    """
    table = table or Table()
    objects, placed = [], []

    def add(shape, colour, require_pickable=False):
        side, yaw, xy = draw_placement(rng, shape, start_pose, table, size_range=size_range, margin_px=margin_px,
                                       require_pickable=require_pickable,
                                       avoid=[(other, DISTRACTOR_MIN_DISTANCE) for other in placed])
        objects.append(_block(shape, colour, side, yaw, xy))
        placed.append(xy)

    add(*TARGET, require_pickable=True)
    others = [(s, c) for s in SHAPES for c in COLOURS_RGB if (s, c) != TARGET]
    for _ in range(distractors):
        add(*others[rng.integers(len(others))])
    if same_colour_distractor:
        same_colour = [s for s in SHAPES if s != TARGET[0]]
        add(same_colour[rng.integers(len(same_colour))], TARGET[1])
    return _scene_dict(objects, start_pose, table, **({} if faults is None else {'faults': faults}))


def load_faults_mapping(path):
    """The ``faults:`` mapping of a YAML file (the format of ``fake_baxter.py --faults``: a file holding a
    ``faults:`` key, ``sim/faults.py`` schema), validated; ``SceneError`` naming the path and the key."""
    load_faults(path)
    with open(path) as f:
        return yaml.safe_load(f).get('faults') or {}


# ============================================================================================ scoring (pure)

def block_in_gripper_mm(T_base_gripper, T_base_block):
    """(3,) position of the block's top-face centre in the gripper frame (mm)."""
    return 1000.0 * (invert(T_base_gripper) @ T_base_block)[:3, 3]


def score(scene, T_base_block_end, T_base_gripper_end, T_base_block_pre_close=None, T_base_gripper_pre_close=None):
    """Ground-truth scores of a run from the target block's final pose and the gripper's (base, m).

    Returns dict: lifted (bool), rise_mm (top-face rise over its scene height), centring_mm (norm of the
    block centre's x, y in the gripper frame at the end; None if not lifted), centring_x_mm,
    centring_y_mm, pre_close_offset_mm (same norm just before the first close; None if unknown).
    """
    target = scene['objects'][0]
    rise = T_base_block_end[2, 3] - (scene['table']['top_z'] + target['height'])
    lifted = bool(rise >= LIFT_THRESHOLD)
    in_gripper = block_in_gripper_mm(T_base_gripper_end, T_base_block_end)
    pre_close = None
    if T_base_block_pre_close is not None and T_base_gripper_pre_close is not None:
        pre_close = float(np.linalg.norm(block_in_gripper_mm(T_base_gripper_pre_close, T_base_block_pre_close)[:2]))
    return {'lifted': lifted, 'rise_mm': 1000.0 * float(rise),
            'centring_mm': float(np.linalg.norm(in_gripper[:2])) if lifted else None,
            'centring_x_mm': float(in_gripper[0]) if lifted else None,
            'centring_y_mm': float(in_gripper[1]) if lifted else None,
            'pre_close_offset_mm': pre_close}


def failure_label(row):
    """Why a row is not a verified pick ('' if it is): the app's reason, 'not_lifted' (the app claimed
    success but the block is not up), 'wall_timeout' or 'crashed' (no result)."""
    if row['verified']:
        return ''
    if row['timed_out']:
        return 'wall_timeout'
    if row['app_success'] is None:
        return 'crashed'
    if row['app_success']:
        return 'not_lifted'
    return row['failure_reason'] or 'unknown'


def condition(row):
    """The conditions a row ran under, as one label: its faults (``Faults.summary()``, ``none`` for a clean
    run; rows of CSVs written before the column count as ``none``) and its distractors, e.g.
    ``faults: camera.drop_probability=0.2, camera.latency=0.1; distractors: 1 (1 of the target's colour)``."""
    same = ' (1 of the target\'s colour)' if row.get('same_colour_distractor') else ''
    return f"faults: {row.get('faults') or 'none'}; distractors: {row.get('distractors') or 0}{same}"


def _percentile(values, q):
    return float(np.percentile(values, q)) if len(values) else None


def summarise(rows, by_start_pose=False, by_condition=False):
    """Statistics per mode (and start pose, and :func:`condition`, if asked): dict 'mode' (or 'mode
    start_pose', 'mode [condition]') -> {trials, verified, success_pct, centring_median_mm, centring_p90_mm,
    pre_close_median_mm, time_median_s, time_p90_s, wall_median_s, failures {label: count}}.

    Centring and time statistics are over verified picks; time = the application's ``time_s`` (robot
    time from the first look to the verified grasp).
    """
    groups = {}
    for row in sorted(rows, key=lambda r: (MODES.index(r['mode']), START_POSES.index(r['start_pose']))):
        key = ' '.join([row['mode']] + ([row['start_pose']] if by_start_pose else [])
                       + ([f'[{condition(row)}]'] if by_condition else []))
        groups.setdefault(key, []).append(row)
    summary = {}
    for key, mine in groups.items():
        verified = [r for r in mine if r['verified']]
        centring = [r['centring_mm'] for r in verified]
        pre_close = [r['pre_close_offset_mm'] for r in verified if r['pre_close_offset_mm'] is not None]
        times = [r['time_s'] for r in verified]
        failures = {}
        for r in mine:
            label = failure_label(r)
            if label:
                failures[label] = failures.get(label, 0) + 1
        summary[key] = {'trials': len(mine), 'verified': len(verified),
                        'success_pct': 100.0 * len(verified) / len(mine),
                        'centring_median_mm': _percentile(centring, 50), 'centring_p90_mm': _percentile(centring, 90),
                        'pre_close_median_mm': _percentile(pre_close, 50),
                        'time_median_s': _percentile(times, 50), 'time_p90_s': _percentile(times, 90),
                        'wall_median_s': _percentile([r['wall_s'] for r in mine if r['wall_s'] is not None], 50),
                        'failures': failures}
    return summary


def format_table(summary):
    """A ``summarise`` result as a Markdown table."""
    def number(value, digits=1):
        return 'n/a' if value is None else f'{value:.{digits}f}'
    lines = ['| mode | verified picks | centring error median / p90 (mm) | pre-close offset median (mm) | '
             'time to grasp median / p90 (s, sim) | failures |',
             '|---|---|---|---|---|---|']
    for mode, s in summary.items():
        failures = ', '.join(f'{label} {count}' for label, count in sorted(s['failures'].items())) or 'none'
        lines.append(f"| {mode} | {s['verified']}/{s['trials']} ({s['success_pct']:.0f} %) | "
                     f"{number(s['centring_median_mm'])} / {number(s['centring_p90_mm'])} | "
                     f"{number(s['pre_close_median_mm'])} | "
                     f"{number(s['time_median_s'])} / {number(s['time_p90_s'])} | {failures} |")
    return '\n'.join(lines)


# ============================================================================================ plots

def plot_results(rows, out_dir):
    """``time_to_grasp.png`` (histogram per mode, verified picks) and ``centring.png`` (block centre x, y
    in the gripper frame after the lift, per mode). Returns the paths written."""
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt
    modes = [m for m in MODES if any(r['mode'] == m for r in rows)]
    paths = []
    figure, axes = plt.subplots(len(modes), 1, figsize=(7, 2.4 * len(modes) + 0.6), sharex=True, squeeze=False)
    times = [r['time_s'] for r in rows if r['verified']]
    bins = np.linspace(0.0, max(times + [1.0]) * 1.05, 25)
    for ax, mode in zip(axes[:, 0], modes):
        for start_pose in START_POSES:
            values = [r['time_s'] for r in rows
                      if r['verified'] and r['mode'] == mode and r['start_pose'] == start_pose]
            if values:
                ax.hist(values, bins=bins, alpha=0.6, label=f'{start_pose} (n={len(values)})')
        ax.set_ylabel(f'{mode}\ntrials')
        ax.legend(fontsize=8)
    axes[-1, 0].set_xlabel('time to grasp (s, simulated; verified picks)')
    figure.tight_layout()
    paths.append(os.path.join(out_dir, 'time_to_grasp.png'))
    figure.savefig(paths[-1], dpi=100)
    plt.close(figure)

    figure, ax = plt.subplots(figsize=(6, 6))
    for mode, marker in zip(modes, 'os^'):
        mine = [r for r in rows if r['verified'] and r['mode'] == mode]
        ax.scatter([r['centring_x_mm'] for r in mine], [r['centring_y_mm'] for r in mine], marker=marker,
                   alpha=0.7, label=f'{mode} (n={len(mine)})')
    ax.axhline(0, color='grey', lw=0.5)
    ax.axvline(0, color='grey', lw=0.5)
    ax.add_patch(plt.Circle((0, 0), 3.0, fill=False, ls='--', color='grey'))
    ax.set_aspect('equal')
    ax.set_xlabel('block centre x in left_gripper (mm)')
    ax.set_ylabel('block centre y in left_gripper (mm; fingers close along y)')
    ax.set_title('grasp centring after the lift (ground truth); circle = 3 mm')
    ax.legend(fontsize=8)
    figure.tight_layout()
    paths.append(os.path.join(out_dir, 'centring.png'))
    figure.savefig(paths[-1], dpi=100)
    plt.close(figure)
    return paths


# ============================================================================================ ROS edge

class GroundTruthSample(NamedTuple):
    """The simulator's state at one ``/fake_baxter/object_poses`` message."""
    stamp: float                 # simulated time (s)
    T_base_block: np.ndarray     # the target block (objects[0]), top-face centre frame
    T_base_gripper: np.ndarray   # latest endpoint state (left_gripper)
    gripper_percent: float       # latest gripper opening (0 closed .. 100 open)


def write_ground_truth(samples, path):
    """The trace as CSV: time (s), block and gripper positions (base, mm), block yaw (deg), the block
    centre in the gripper frame (mm) and the gripper opening (%)."""
    with open(path, 'w', newline='') as f:
        writer = csv.writer(f)
        writer.writerow(['t_s', 'block_x_mm', 'block_y_mm', 'block_z_mm', 'block_yaw_deg', 'gripper_x_mm',
                         'gripper_y_mm', 'gripper_z_mm', 'block_in_gripper_x_mm', 'block_in_gripper_y_mm',
                         'block_in_gripper_z_mm', 'gripper_percent'])
        for sample in samples:
            yaw = math.degrees(math.atan2(sample.T_base_block[1, 0], sample.T_base_block[0, 0]))
            writer.writerow(['%.4f' % sample.stamp] + ['%.2f' % v for v in (
                *(1000 * sample.T_base_block[:3, 3]), yaw, *(1000 * sample.T_base_gripper[:3, 3]),
                *block_in_gripper_mm(sample.T_base_gripper, sample.T_base_block), sample.gripper_percent)])


class GroundTruthMonitor:
    """Records the simulator's ground truth during a trial (runner only; needs this process's rospy node).

    On every ``/fake_baxter/object_poses`` message (30 Hz simulated) it stores a ``GroundTruthSample``
    (the first object's pose, the latest ``/robot/limb/left/endpoint_state`` pose and gripper opening);
    ``respawns`` is the latest ``/fake_baxter/respawns`` count (scenes with a ``respawn:`` key).
    """

    def __init__(self):
        import rospy
        from geometry_msgs.msg import PoseArray
        from std_msgs.msg import UInt32

        from baxter_pnp.msgs import msg
        self._lock = threading.Lock()
        self.samples = []            # GroundTruthSample, in arrival order
        self._gripper_pose = None
        self._gripper_position = None
        self.respawns = 0
        self._subscribers = [
            rospy.Subscriber('/fake_baxter/respawns', UInt32, self._on_respawns, queue_size=1),
            rospy.Subscriber('/fake_baxter/object_poses', PoseArray, self._on_objects, queue_size=10),
            rospy.Subscriber(f'/robot/limb/{SIDE}/endpoint_state', msg.EndpointState, self._on_endpoint, queue_size=1),
            rospy.Subscriber(f'/robot/end_effector/{SIDE}_gripper/state', msg.EndEffectorState, self._on_gripper,
                             queue_size=1)]

    def _on_respawns(self, message):
        self.respawns = message.data

    def _on_endpoint(self, message):
        with self._lock:
            self._gripper_pose = pose_msg_to_matrix(message.pose)

    def _on_gripper(self, message):
        with self._lock:
            self._gripper_position = float(message.position)

    def _on_objects(self, message):
        if not message.poses:
            return
        with self._lock:
            if self._gripper_pose is not None and self._gripper_position is not None:
                self.samples.append(GroundTruthSample(message.header.stamp.to_sec(),
                                                      pose_msg_to_matrix(message.poses[0]), self._gripper_pose,
                                                      self._gripper_position))

    def count(self):
        with self._lock:
            return len(self.samples)

    def snapshot(self):
        """A copy of the sample list."""
        with self._lock:
            return list(self.samples)

    def wait_for_samples(self, count, timeout=10.0):
        """The sample list once it holds more than ``count`` samples (wall ``timeout`` s), else RuntimeError."""
        deadline = time.monotonic() + timeout
        while self.count() <= count:
            if time.monotonic() > deadline:
                raise RuntimeError('no ground truth from /fake_baxter/object_poses')
            time.sleep(0.02)
        return self.snapshot()

    def close(self):
        for subscriber in self._subscribers:
            subscriber.unregister()


def pre_close_sample(samples, open_above=95.0, drop=2.0):
    """The last sample before the gripper first started closing: once open (above ``open_above`` %;
    calibration opens it first), its opening fell more than ``drop`` points below the widest seen since
    (a block held crooked can stop the fingers above 90 %). None if it never closed."""
    widest = None
    for k, position in enumerate(sample.gripper_percent for sample in samples):
        if widest is not None and position < widest - drop:
            return samples[k - 1]
        if position >= open_above:
            widest = max(position, widest or position)
    return None


def run_trial(master, scene, mode, start_pose, step_fraction, workdir, timeout=300.0, seed=0, trial=0,
              place_xy=None):
    """One full pick (and place at ``place_xy``, base x, y in m, if given) on a fresh fake Baxter, scored
    with the ground truth; returns a CSV row dict. A place run is verified when the app succeeded and the
    block ends on the table within ``PLACE_TOLERANCE`` of ``place_xy`` (``place_error_mm``).

    Writes ``scene.yaml`` to ``workdir``, starts ``fake_baxter.py --scene scene.yaml --real-time-factor 0
    --seed seed`` on ``master`` (a ``launcher.RosMaster``), runs ``scripts/pick_square.py`` (its log
    ``pick.log``, ``result.json`` and outputs in ``workdir``; interrupted after ``timeout`` wall seconds),
    then reads the block and gripper poses and scores them (:func:`score`). This process's rospy node must
    already run on ``master`` (see :func:`main`).
    """
    import rospy
    from baxter_pnp.sim.launcher import FakeBaxterProcess, run_script
    if not rospy.core.is_initialized():
        raise RuntimeError('run_trial needs a rospy node on the master (rospy.init_node inside master.environment())')
    os.makedirs(workdir, exist_ok=True)
    scene_path = os.path.join(workdir, 'scene.yaml')
    with open(scene_path, 'w') as f:
        yaml.safe_dump(scene, f, default_flow_style=None, sort_keys=False)
    target = scene['objects'][0]
    result_path = os.path.join(workdir, 'result.json')
    if os.path.exists(result_path):
        os.remove(result_path)
    monitor = GroundTruthMonitor()
    fake = FakeBaxterProcess(master, ['--scene', scene_path, '--real-time-factor', '0', '--seed', seed],
                             log_path=os.path.join(workdir, 'fake_baxter.log'))
    run, samples, error = None, [], None
    try:
        fake.start()
        run = run_script(master, 'pick_square.py',
                         ['--mode', mode, '--start-pose', start_pose, '--side-length', target['side'],
                          '--step-fraction', step_fraction, '--result-json', result_path, '--output-dir', workdir]
                         + ([] if place_xy is None else ['--place', '%g,%g' % tuple(place_xy)]),
                         timeout=timeout, log_path=os.path.join(workdir, 'pick.log'))
        samples = monitor.wait_for_samples(monitor.count() + 1)
    except RuntimeError as problem:      # the fake did not start, or no ground truth came
        error = str(problem)
    finally:
        monitor.close()
        fake.stop()
    result = None
    if os.path.exists(result_path):
        with open(result_path) as f:
            result = json.load(f)
    if samples:
        write_ground_truth(samples, os.path.join(workdir, 'ground_truth.csv'))
        pre = pre_close_sample(samples)
        scores = score(scene, samples[-1].T_base_block, samples[-1].T_base_gripper,
                       *((pre.T_base_block, pre.T_base_gripper) if pre else (None, None)))
    else:
        scores = {'lifted': False, 'rise_mm': None, 'centring_mm': None, 'centring_x_mm': None,
                  'centring_y_mm': None, 'pre_close_offset_mm': None}
    row = {'mode': mode, 'start_pose': start_pose, 'trial': trial, 'seed': seed,
           'side_mm': round(1000 * target['side'], 2), 'yaw_deg': round(math.degrees(target['yaw']), 2),
           'x_m': target['xy'][0], 'y_m': target['xy'][1], 'distractors': len(scene['objects']) - 1,
           'same_colour_distractor': any(o['color'] == target['color'] and o['shape'] != target['shape']
                                         for o in scene['objects'][1:]),
           'faults': Scene.from_dict(scene).faults.summary(),
           'app_success': None if result is None else bool(result['success']),
           'failure_reason': error if result is None else result['failure_reason'],
           'time_s': None if result is None else result['time_s'],
           'steps': None if result is None else result['steps'],
           'grasp_attempts': None if result is None else result['grasp_attempts'],
           'final_error_mm_est': None if result is None else result['final_error_mm_est'],
           'wall_s': None if run is None else round(run.wall_seconds, 2),
           'returncode': None if run is None else run.returncode, 'timed_out': bool(run and run.timed_out),
           'trial_dir': workdir}
    row.update(scores)
    row['verified'] = bool(row['app_success']) and scores['lifted']
    row['place_error_mm'] = None
    if place_xy is not None and samples:
        T_end = samples[-1].T_base_block
        on_table = abs(T_end[2, 3] - (scene['table']['top_z'] + target['height'])) < 0.003
        row['place_error_mm'] = 1000.0 * float(np.hypot(T_end[0, 3] - place_xy[0], T_end[1, 3] - place_xy[1]))
        row['verified'] = bool(row['app_success']) and on_table and row['place_error_mm'] <= 1000 * PLACE_TOLERANCE
    return row


def _csv_value(value):
    if isinstance(value, float):
        return f'{value:.4g}' if abs(value) < 1e4 else f'{value:.1f}'
    return '' if value is None else value


FIELD_TYPES = {'trial': int, 'seed': int, 'steps': int, 'grasp_attempts': int, 'returncode': int, 'distractors': int,
               'mode': str, 'start_pose': str, 'failure_reason': str, 'trial_dir': str, 'faults': str,
               'same_colour_distractor': 'bool', 'app_success': 'bool', 'verified': 'bool', 'lifted': 'bool',
               'timed_out': 'bool'}


def read_csv(path):
    """Rows of a ``trials.csv`` with their types back (numbers float unless listed in FIELD_TYPES, '' = None)."""
    def parse(key, text):
        kind = FIELD_TYPES.get(key, float)
        if text == '':
            return None
        if kind == 'bool':
            return text == 'True'
        return kind(text)
    with open(path, newline='') as f:
        return [{k: parse(k, v) for k, v in row.items()} for row in csv.DictReader(f)]


def write_csv(rows, path):
    with open(path, 'w', newline='') as f:
        writer = csv.DictWriter(f, fieldnames=CSV_FIELDS)
        writer.writeheader()
        for row in rows:
            writer.writerow({k: _csv_value(row.get(k)) for k in CSV_FIELDS})


# ============================================================================================ soak

SOAK_PLACE_XY = (0.62, 0.12)      # m (base): default place position of a soak (as in the place trials)
SOAK_PLACE_CLEARANCE = 0.10       # m: every soak pose's centre stays this far from the place position
SOAK_POLL = 0.25                  # wall s between looks at the application's result JSON
SOAK_MEMORY_INTERVAL = 10.0       # wall s between the periodic memory samples
SOAK_FIELDS = ('cycle', 'app_success', 'failure_reason', 'lifted', 'verified', 'time_s', 'total_time_s', 'steps',
               'grasp_attempts', 'final_error_mm_est', 'place_error_mm_est', 'end_sim_s', 'cycle_sim_s', 'end_wall_s',
               'respawns', 'app_rss_mib', 'fake_rss_mib')
SOAK_MEMORY_FIELDS = ('wall_s', 'sim_s', 'cycles_done', 'app_rss_mib', 'fake_rss_mib')


def soak_poses(rng, start_pose, count, place_xy, table=None, size_range=(0.03, 0.05)):
    """(side (m), [(x (m), y (m), yaw (rad))] * ``count``): one green square's side and ``count`` poses of it
    on the table, each drawn by :func:`draw_placement` (whole top face in view from ``start_pose``,
    pickable) with its centre at least ``SOAK_PLACE_CLEARANCE`` from ``place_xy`` (m, base)."""
    side, poses = None, []
    for _ in range(count):
        side, yaw, xy = draw_placement(rng, TARGET[0], start_pose, table, side=side, size_range=size_range,
                                       require_pickable=True, avoid=[(place_xy, SOAK_PLACE_CLEARANCE)])
        poses.append((round(float(xy[0]), 5), round(float(xy[1]), 5), round(yaw, 5)))
    return side, poses


def soak_scene(side, poses, start_pose, table=None, faults=None, respawn_delay=RESPAWN_DELAY):
    """Scene dict of a soak: the green square of ``side`` (m) at ``poses[0]``, respawned by the fake at
    ``poses[1:]`` in turn (``respawn:`` key, ``respawn_delay`` s) after each pick and place; ``faults``: the
    ``faults:`` mapping or None. Needs at least two poses."""
    if len(poses) < 2:
        raise ValueError('a soak needs at least two poses (the first, then the respawns)')
    table = table or Table()
    x, y, yaw = poses[0]
    extra = {'respawn': {'poses': [list(pose) for pose in poses[1:]], 'delay': respawn_delay, 'object': 0}}
    if faults is not None:
        extra['faults'] = faults
    return _scene_dict([_block(*TARGET, side, yaw, (x, y))], start_pose, table, **extra)


def vm_rss_mib(status_text):
    """Resident memory (MiB) from the text of a ``/proc/PID/status`` file (its ``VmRSS: N kB`` line), or None
    if it has none (e.g. a zombie)."""
    for line in status_text.splitlines():
        if line.startswith('VmRSS:'):
            value, unit = line.split()[1:3]
            if unit != 'kB':
                raise ValueError(f'unexpected VmRSS unit {unit!r}')
            return int(value) / 1024.0
    return None


def _read_proc(proc, pid, name):
    try:
        with open(os.path.join(proc, str(pid), name)) as f:
            return f.read()
    except OSError:              # the process is gone (or not ours to read)
        return None


def process_tree(root, proc='/proc'):
    """PIDs of process ``root`` and all its descendants, from ``proc``'s ``PID/stat`` files (parent = field 4)."""
    children = {}
    for entry in os.listdir(proc):
        stat = _read_proc(proc, entry, 'stat') if entry.isdigit() else None
        if stat:
            children.setdefault(int(stat.rsplit(')', 1)[1].split()[1]), []).append(int(entry))
    tree, todo = [], [root]
    while todo:
        pid = todo.pop()
        tree.append(pid)
        todo += children.get(pid, [])
    return tree


def python_rss_mib(root, proc='/proc'):
    """(pid, resident MiB) of the largest Python process (``comm`` starting with ``python``) among ``root``
    and its descendants: the launched process may be a wrapper (a shell, ``rosrun``) around the interpreter,
    or the interpreter itself (which may re-exec itself under the venv, keeping its PID). (None, None) when
    there is none (yet, or any more)."""
    best = (None, None)
    for pid in process_tree(root, proc):
        comm, status = _read_proc(proc, pid, 'comm'), _read_proc(proc, pid, 'status')
        rss = vm_rss_mib(status) if comm and comm.startswith('python') and status else None
        if rss is not None and (best[1] is None or rss > best[1]):
            best = (pid, rss)
    return best


def lift_times(samples, rest_z, threshold=LIFT_THRESHOLD):
    """Simulated times (s) at which the target block started a lift: its top face rose to ``threshold`` (m)
    above ``rest_z`` (its top face's height at rest on the table) from below; ``samples``:
    ``GroundTruthSample``s in time order."""
    times, up = [], False
    for sample in samples:
        rising = sample.T_base_block[2, 3] - rest_z >= threshold
        if rising and not up:
            times.append(sample.stamp)
        up = rising
    return times


def score_cycles(results, ends, lifts, start):
    """Per-cycle rows of a soak: the application's result of each finished cycle (``results``, in order), the
    simulated time at which the runner saw each one finished (``ends``, s), the lift start times (``lifts``,
    s, :func:`lift_times`) and the time the application started (``start``, s). Cycle k spans (end of k - 1,
    end of k]; it is *lifted* if a lift started then, *verified* if the application reports success and it
    is lifted. ``cycle_sim_s`` is its length."""
    rows, previous = [], start
    for k, (result, end) in enumerate(zip(results, ends)):
        lifted = any(previous < t <= end for t in lifts)
        rows.append({'cycle': k + 1, 'app_success': bool(result.get('success')),
                     'failure_reason': result.get('failure_reason'), 'lifted': lifted,
                     'verified': bool(result.get('success')) and lifted, 'end_sim_s': end,
                     'cycle_sim_s': end - previous,
                     **{key: result.get(key) for key in ('time_s', 'total_time_s', 'steps', 'grasp_attempts',
                                                         'final_error_mm_est', 'place_error_mm_est')}})
        previous = end
    return rows


def _memory_change(rows, key):
    """{start_mib, start_cycle, end_mib, end_cycle, growth_pct} of the first and last cycle rows with a
    ``key`` memory reading, or None without any."""
    measured = [row for row in rows if row.get(key) is not None]
    if not measured:
        return None
    first, last = measured[0], measured[-1]
    return {'start_mib': first[key], 'start_cycle': first['cycle'], 'end_mib': last[key], 'end_cycle': last['cycle'],
            'growth_pct': 100.0 * (last[key] - first[key]) / first[key]}


def summarise_soak(rows, cycles):
    """Statistics of a soak's cycle rows (:func:`score_cycles` plus memory columns) out of ``cycles`` asked:
    success counts and percentages (over ``cycles``: an unfinished cycle is a failure), failures by label,
    time to grasp (the application's ``time_s``, verified cycles) and cycle length (simulated s, all
    finished cycles) median and p90, memory of the application and the fake (MiB) at the first and last
    cycle end measured and its growth (%)."""
    verified = [r for r in rows if r['verified']]
    failures = {}
    for row in rows:
        if not row['verified']:
            label = row['failure_reason'] or ('not_lifted' if row['app_success'] else 'unknown')
            failures[label] = failures.get(label, 0) + 1
    if cycles > len(rows):
        failures['not_finished'] = cycles - len(rows)
    grasp_times = [r['time_s'] for r in verified if r['time_s'] is not None]
    lengths = [r['cycle_sim_s'] for r in rows]
    return {'cycles': cycles, 'finished': len(rows), 'app_successes': sum(r['app_success'] for r in rows),
            'verified': len(verified), 'app_success_pct': 100.0 * sum(r['app_success'] for r in rows) / cycles,
            'verified_pct': 100.0 * len(verified) / cycles, 'failures': failures,
            'time_to_grasp_median_s': _percentile(grasp_times, 50), 'time_to_grasp_p90_s': _percentile(grasp_times, 90),
            'cycle_median_s': _percentile(lengths, 50), 'cycle_p90_s': _percentile(lengths, 90),
            'app_memory': _memory_change(rows, 'app_rss_mib'), 'fake_memory': _memory_change(rows, 'fake_rss_mib')}


def format_soak(summary):
    """A ``summarise_soak`` result as a few lines of text."""
    def number(value, digits=1):
        return 'n/a' if value is None else f'{value:.{digits}f}'

    def memory(change):
        if change is None:
            return 'n/a'
        return (f"{change['start_mib']:.0f} MiB after cycle {change['start_cycle']} -> {change['end_mib']:.0f} MiB "
                f"after cycle {change['end_cycle']} ({change['growth_pct']:+.1f} %)")
    s = summary
    failures = ', '.join(f'{label} {count}' for label, count in sorted(s['failures'].items())) or 'none'
    return '\n'.join([
        f"cycles: {s['finished']}/{s['cycles']} finished; app-reported successes {s['app_successes']}/{s['cycles']} "
        f"({s['app_success_pct']:.0f} %), verified by ground truth {s['verified']}/{s['cycles']} "
        f"({s['verified_pct']:.0f} %); failures: {failures}",
        f"time to grasp (verified, s sim): median {number(s['time_to_grasp_median_s'])}, "
        f"p90 {number(s['time_to_grasp_p90_s'])}; cycle (s sim): median {number(s['cycle_median_s'])}, "
        f"p90 {number(s['cycle_p90_s'])}",
        f"memory (VmRSS) app: {memory(s['app_memory'])}; fake: {memory(s['fake_memory'])}"])


def plot_soak_memory(rows, series, path):
    """``path`` (PNG): resident memory (MiB) of the application and the fake at each cycle end, and the
    periodic samples against wall time."""
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt
    figure, (by_cycle, by_time) = plt.subplots(2, 1, figsize=(7, 6))
    for key, label in (('app_rss_mib', 'pick_square.py'), ('fake_rss_mib', 'fake_baxter.py')):
        measured = [r for r in rows if r.get(key) is not None]
        by_cycle.plot([r['cycle'] for r in measured], [r[key] for r in measured], 'o-', label=label)
        sampled = [m for m in series if m[key] is not None]
        by_time.plot([m['wall_s'] / 60 for m in sampled], [m[key] for m in sampled], '-', label=label)
    by_cycle.set_xlabel('cycle')
    by_cycle.set_ylabel('VmRSS at the cycle end (MiB)')
    by_cycle.legend(fontsize=8)
    by_time.set_xlabel('wall time (min)')
    by_time.set_ylabel('VmRSS (MiB)')
    figure.tight_layout()
    figure.savefig(path, dpi=100)
    plt.close(figure)


def _write_rows(rows, fields, path):
    with open(path, 'w', newline='') as f:
        writer = csv.DictWriter(f, fieldnames=fields)
        writer.writeheader()
        for row in rows:
            writer.writerow({k: _csv_value(row.get(k)) for k in fields})


class SoakWatcher:
    """Watches a running soak from a thread (runner only; needs this process's rospy node for ``/clock``).

    Every ``SOAK_POLL`` wall seconds it reads the application's result JSON; when more cycles are listed it
    records, for each new one, the simulated time, the wall time, the fake's respawn count and the resident
    memory of the application's and the fake's Python processes (``ends``). Every ``SOAK_MEMORY_INTERVAL``
    it appends a memory sample to ``series`` (and to the CSV at ``memory_csv``).
    """

    def __init__(self, result_path, app_pid, fake_pid, monitor, memory_csv):
        self.result_path, self.app_pid, self.fake_pid, self.monitor = result_path, app_pid, fake_pid, monitor
        self.memory_csv = memory_csv
        self.ends, self.series = [], []
        self._started = time.monotonic()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)

    def start(self):
        with open(self.memory_csv, 'w', newline='') as f:
            csv.writer(f).writerow(SOAK_MEMORY_FIELDS)
        self._thread.start()
        return self

    def stop(self):
        """Stop watching, after one last look at the result JSON."""
        self._stop.set()
        self._thread.join()
        self.poll()

    def results(self):
        """The per-cycle result dicts the application has written so far ([] if none yet or unreadable)."""
        try:
            with open(self.result_path) as f:
                return json.load(f).get('cycles', [])
        except (OSError, ValueError):          # not written yet, or caught while being rewritten
            return []

    def memory(self):
        """{app_rss_mib, fake_rss_mib} now (None for a process that is gone)."""
        return {'app_rss_mib': python_rss_mib(self.app_pid)[1], 'fake_rss_mib': python_rss_mib(self.fake_pid)[1]}

    def poll(self):
        import rospy
        finished = len(self.results())
        if finished > len(self.ends):
            now = {'end_sim_s': rospy.get_time(), 'end_wall_s': time.monotonic() - self._started,
                   'respawns': self.monitor.respawns, **self.memory()}
            self.ends += [now] * (finished - len(self.ends))

    def _run(self):
        import rospy
        next_sample = 0.0
        while not self._stop.wait(SOAK_POLL):
            self.poll()
            wall = time.monotonic() - self._started
            if wall >= next_sample:
                sample = {'wall_s': round(wall, 1), 'sim_s': round(rospy.get_time(), 2), 'cycles_done': len(self.ends),
                          **self.memory()}
                self.series.append(sample)
                with open(self.memory_csv, 'a', newline='') as f:
                    csv.writer(f).writerow([_csv_value(sample[k]) for k in SOAK_MEMORY_FIELDS])
                next_sample = wall + SOAK_MEMORY_INTERVAL


def run_soak(master, cycles, mode, start_pose, place_xy, out, seed=0, step_fraction=0.35, timeout_per_cycle=300.0,
             faults=None):
    """``cycles`` pick-and-place cycles in one ``pick_square.py --cycles`` run against one fake Baxter that
    respawns the block (:func:`soak_scene`), scored per cycle with the ground truth; returns (cycle rows,
    summary dict). Writes ``scene.yaml``, ``fake_baxter.log``, ``pick.log``, ``result.json`` (the
    application's), ``ground_truth.csv``, ``soak_memory.csv`` (periodic memory samples), ``soak.csv`` (one
    row per cycle) and ``soak_memory.png`` to ``out``. The run is interrupted after ``timeout_per_cycle`` x
    ``cycles`` wall seconds. This process's rospy node must already run on ``master`` (see :func:`main`).
    """
    import rospy
    from rosgraph_msgs.msg import Clock
    from baxter_pnp.sim.launcher import FakeBaxterProcess, start_script
    os.makedirs(out, exist_ok=True)
    side, poses = soak_poses(np.random.default_rng(seed), start_pose, cycles, place_xy)
    scene = soak_scene(side, poses, start_pose, faults=faults)
    scene_path, result_path = os.path.join(out, 'scene.yaml'), os.path.join(out, 'result.json')
    with open(scene_path, 'w') as f:
        yaml.safe_dump(scene, f, default_flow_style=None, sort_keys=False)
    if os.path.exists(result_path):
        os.remove(result_path)
    monitor = GroundTruthMonitor()
    fake = FakeBaxterProcess(master, ['--scene', scene_path, '--real-time-factor', '0', '--seed', seed],
                             log_path=os.path.join(out, 'fake_baxter.log'))
    run, watcher = None, None
    try:
        fake.start()
        # the new fake's simulated time: this node's rospy clock may still show an earlier fake's last /clock
        started = rospy.wait_for_message('/clock', Clock, timeout=10.0).clock.to_sec()
        app = start_script(master, 'pick_square.py',
                           ['--cycles', cycles, '--place', '%g,%g' % tuple(place_xy), '--mode', mode,
                            '--start-pose', start_pose, '--side-length', side, '--step-fraction', step_fraction,
                            '--result-json', result_path, '--output-dir', os.path.join(out, 'app')],
                           log_path=os.path.join(out, 'pick.log'))
        watcher = SoakWatcher(result_path, app.process.pid, fake.process.pid, monitor,
                              os.path.join(out, 'soak_memory.csv')).start()
        run = app.wait(timeout_per_cycle * cycles)
    finally:
        if watcher is not None:
            watcher.stop()
        samples = monitor.snapshot()
        monitor.close()
        fake.stop()
    results = watcher.results()
    ends = watcher.ends[:len(results)]
    rows = score_cycles(results, [end['end_sim_s'] for end in ends],
                        lift_times(samples, scene['table']['top_z'] + BLOCK_HEIGHT), started)
    for row, end in zip(rows, ends):
        row.update({k: end[k] for k in ('end_wall_s', 'respawns', 'app_rss_mib', 'fake_rss_mib')})
    if samples:
        write_ground_truth(samples, os.path.join(out, 'ground_truth.csv'))
    _write_rows(rows, SOAK_FIELDS, os.path.join(out, 'soak.csv'))
    plot_soak_memory(rows, watcher.series, os.path.join(out, 'soak_memory.png'))
    summary = summarise_soak(rows, cycles)
    summary.update({'returncode': run.returncode, 'timed_out': run.timed_out, 'wall_s': round(run.wall_seconds, 1),
                    'respawns': monitor.respawns, 'side_m': side, 'poses': poses})
    return rows, summary


def parse_args(argv):
    parser = argparse.ArgumentParser(prog='run_trials.py', description=(
        'Batch pick trials on the fake Baxter: N random scenes per start pose, each picked in each mode, scored '
        'with the ground truth; or a soak: N pick-and-place cycles in one run (docs/trials.md).'))
    parser.add_argument('--trials', type=int, default=10, help='random scenes per start pose (default %(default)s)')
    parser.add_argument('--seed', type=int, default=0, help='seed of the scenes and image noise (default %(default)s)')
    parser.add_argument('--mode', choices=MODES + ('all',), help='default: all (soak: pbvs)')
    parser.add_argument('--start-pose', choices=START_POSES + ('both',), help='default: both (soak: down)')
    parser.add_argument('--step-fraction', type=float, default=0.35, help='PBVS step fraction (default %(default)s)')
    parser.add_argument('--distractors', type=int, default=0, help='other blocks per scene (default %(default)s)')
    parser.add_argument('--distractor-same-colour', action='store_true',
                        help="one more block per scene of the target's colour but not a square")
    parser.add_argument('--faults', metavar='FILE', help="YAML file with a 'faults:' key (as fake_baxter.py "
                        "--faults, docs/fake_baxter.md): the faults of every scene")
    parser.add_argument('--timeout', type=float, default=300.0,
                        help='wall seconds per trial, or per soak cycle (default %(default)s)')
    parser.add_argument('--place', metavar='X,Y', type=lambda text: [float(v) for v in text.split(',')],
                        help='also place each block at this table position (base, m); scored by where it ends '
                             '(soak: default %g,%g)' % SOAK_PLACE_XY)
    parser.add_argument('--soak', type=int, metavar='N', help='instead of trials: N pick-and-place cycles in one '
                        'run of pick_square.py --cycles N against one fake that respawns the block')
    parser.add_argument('--out', default='trials_out', help='output directory (default %(default)s)')
    parser.add_argument('--from-csv', nargs='+', metavar='CSV', help='run nothing: merge these trials.csv files '
                        'into --out and report them (tables, summary.json, plots)')
    args = parser.parse_args(argv)
    if args.soak is not None:
        if args.soak < 2:
            parser.error('--soak needs at least 2 cycles')
        if args.mode == 'all' or args.start_pose == 'both':
            parser.error('--soak runs one mode from one start pose')
        if args.distractors or args.distractor_same_colour or args.from_csv:
            parser.error('--soak takes no distractors and no --from-csv')
        args.mode, args.start_pose = args.mode or 'pbvs', args.start_pose or 'down'
        args.place = args.place or list(SOAK_PLACE_XY)
    else:
        args.mode, args.start_pose = args.mode or 'all', args.start_pose or 'both'
    if args.place is not None and len(args.place) != 2:
        parser.error('--place: expected X,Y in metres')
    return args


def main(argv=None):
    """Entry point of ``scripts/run_trials.py``; returns the exit code (0 when every trial ran; a soak: the
    application's exit code, 0 when every cycle succeeded; 2 for a bad --faults file)."""
    import rospy
    from baxter_pnp.sim.launcher import RosMaster
    argv = sys.argv[1:] if argv is None else argv
    args = parse_args(argv)
    command = 'scripts/run_trials.py ' + ' '.join(argv)
    if args.from_csv:
        out = os.path.abspath(args.out)
        os.makedirs(out, exist_ok=True)
        rows = [row for path in args.from_csv for row in read_csv(path)]
        write_csv(rows, os.path.join(out, 'trials.csv'))
        report(rows, out, command)
        return 0
    try:
        faults = None if args.faults is None else load_faults_mapping(args.faults)
    except (SceneError, OSError, yaml.YAMLError) as error:
        print(f'run_trials.py: error: --faults: {error}', file=sys.stderr)
        return 2
    out = os.path.abspath(args.out)
    os.makedirs(out, exist_ok=True)
    if args.soak is not None:
        return soak_main(args, faults, out, command)
    modes = MODES if args.mode == 'all' else (args.mode,)
    start_poses = START_POSES if args.start_pose == 'both' else (args.start_pose,)
    plan = []
    for start_pose in start_poses:
        for trial in range(args.trials):
            scene_seed = args.seed * 100000 + START_POSES.index(start_pose) * 10000 + trial
            scene = random_scene(np.random.default_rng(scene_seed), start_pose, distractors=args.distractors,
                                 same_colour_distractor=args.distractor_same_colour, faults=faults)
            plan += [(start_pose, trial, scene_seed, scene, mode) for mode in modes]
    rows = []
    print(f'{len(plan)} runs ({args.trials} scenes x {len(start_poses)} start poses x {len(modes)} modes) -> {out}',
          flush=True)
    with RosMaster(log_dir=os.path.join(out, 'ros_log')) as master, master.environment():
        rospy.init_node('run_trials', anonymous=True, disable_signals=True)
        for k, (start_pose, trial, scene_seed, scene, mode) in enumerate(plan):
            workdir = os.path.join(out, f'{start_pose}_{trial:03d}_{mode}')
            row = run_trial(master, scene, mode, start_pose, args.step_fraction, workdir, timeout=args.timeout,
                            seed=scene_seed, trial=trial, place_xy=args.place)
            rows.append(row)
            write_csv(rows, os.path.join(out, 'trials.csv'))
            centring = 'n/a' if row['centring_mm'] is None else '%.1f mm' % row['centring_mm']
            print(f"[{k + 1}/{len(plan)}] {mode:6s} {start_pose:6s} scene {trial:3d}: "
                  f"{'verified' if row['verified'] else 'FAILED (' + failure_label(row) + ')'}; "
                  f"time {row['time_s'] if row['time_s'] is None else round(row['time_s'], 1)} s, "
                  f"centring {centring}, wall {row['wall_s']} s", flush=True)
        rospy.signal_shutdown('trials finished')
    report(rows, out, command, vars(args))
    return 0


def soak_main(args, faults, out, command):
    """``--soak N``: run it on a private master (:func:`run_soak`), print the summary, write ``soak.json``;
    returns the application's exit code (1 if it had to be interrupted)."""
    import rospy
    from baxter_pnp.sim.launcher import RosMaster
    print(f'soak: {args.soak} cycles, mode {args.mode}, start pose {args.start_pose}, place at '
          f'{args.place[0]:g},{args.place[1]:g} -> {out}', flush=True)
    with RosMaster(log_dir=os.path.join(out, 'ros_log')) as master, master.environment():
        rospy.init_node('run_trials', anonymous=True, disable_signals=True)
        _, summary = run_soak(master, args.soak, args.mode, args.start_pose, args.place, out, seed=args.seed,
                              step_fraction=args.step_fraction, timeout_per_cycle=args.timeout, faults=faults)
        rospy.signal_shutdown('soak finished')
    with open(os.path.join(out, 'soak.json'), 'w') as f:
        json.dump({'command': command, 'args': vars(args), **summary}, f, indent=1)
    print(f'\n{command}\n\n{format_soak(summary)}')
    return 1 if summary['returncode'] is None else summary['returncode']


def report(rows, out, command, args=None):
    """Print the tables (per mode, per mode and start pose, and per mode and :func:`condition` when the rows
    ran under more than one); write ``summary.json`` and the plots in ``out``."""
    per_mode, per_start_pose = summarise(rows), summarise(rows, by_start_pose=True)
    per_condition = summarise(rows, by_condition=True)
    with open(os.path.join(out, 'summary.json'), 'w') as f:
        json.dump({'command': command, 'args': args, 'per_mode': per_mode,
                   'per_mode_and_start_pose': per_start_pose, 'per_mode_and_condition': per_condition}, f, indent=1)
    plot_results(rows, out)
    print(f'\n{command}\n\n{format_table(per_mode)}\n\n{format_table(per_start_pose)}')
    if len({condition(row) for row in rows}) > 1:
        print(f'\n{format_table(per_condition)}')
    placed = [float(r['place_error_mm']) for r in rows if r.get('place_error_mm') not in (None, '')]
    if placed:
        within = sum(e <= 1000 * PLACE_TOLERANCE for e in placed)
        print(f'\nplace error (ground truth): median {np.median(placed):.1f} mm, p90 '
              f'{np.percentile(placed, 90):.1f} mm, within {1000 * PLACE_TOLERANCE:.0f} mm: {within}/{len(rows)}')
