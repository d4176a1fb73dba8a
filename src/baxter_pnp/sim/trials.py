"""Batch pick trials on the fake Baxter: random scenes, the full ``pick_square.py`` run, ground-truth scoring.

``scripts/run_trials.py --trials N --seed S --mode all --start-pose both`` draws N random scenes per start
pose (:func:`random_scene`), runs the unmodified pick application on each scene in each mode against a
fresh fake Baxter (:func:`run_trial`), scores every run with the simulator's ground truth and prints a
per-mode table (:func:`summarise`, :func:`format_table`); ``trials.csv``, ``summary.json`` and the plots go
to ``--out``. See docs/trials.md.

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

from baxter_pnp import pick
from baxter_pnp.camera import load_default_camera
from baxter_pnp.kinematics import ArmKinematics, load_start_poses
from baxter_pnp.models import SHAPES, model_for
from baxter_pnp.sim.scene import Scene, Table
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
              'app_success', 'failure_reason', 'verified', 'lifted', 'rise_mm', 'centring_mm', 'centring_x_mm',
              'centring_y_mm', 'pre_close_offset_mm', 'place_error_mm', 'time_s', 'steps', 'grasp_attempts', 'final_error_mm_est',
              'wall_s', 'returncode', 'timed_out', 'trial_dir')


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
    if clearance_px is None:
        return True
    face = np.zeros(clearance_px.shape, np.uint8)
    cv2.fillPoly(face, [np.round(pixels).astype(np.int32)], 1)
    return bool(clearance_px[face > 0].min() > margin_px)


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


def random_scene(rng, start_pose, size_range=(0.03, 0.05), distractors=0, margin_px=20.0, table=None,
                 max_attempts=5000):
    """A random scene dict (``sim/scene.py`` schema) with one green square the application can pick.

    The target: side uniform in ``size_range`` (m), yaw uniform in [-pi, pi), position uniform over the
    part of the table where its whole top face is seen from ``start_pose`` with ``margin_px`` pixels to
    spare, from the image border and from the open gripper's fingers (published camera model at 640x400,
    forward kinematics of the URDF, :func:`hand_clearance_px`), and the arm can reach the hover, grasp and
    lift poses. ``distractors`` other blocks (random shape and colour, never a green
    square, same sizes, also in view) stand at least 8 cm from every other block. ``rng`` is a
    ``numpy.random.Generator``. Raises RuntimeError if no placement is found in ``max_attempts`` draws.
    """
    table = table or Table()
    T_base_camera, _, camera, _ = start_view(start_pose)
    clearance = hand_clearance_px(start_pose)
    low, high = _view_footprint(T_base_camera, camera, table.top_z + BLOCK_HEIGHT)
    low = np.maximum(low, np.subtract(table.center, np.divide(table.size, 2)))
    high = np.minimum(high, np.add(table.center, np.divide(table.size, 2)))

    def draw(shape, require_pickable, placed):
        for _ in range(max_attempts):
            side = float(rng.uniform(*size_range))
            yaw = float(rng.uniform(-math.pi, math.pi))
            xy = rng.uniform(low, high)
            model = model_for(shape, side, BLOCK_HEIGHT)
            T_base_block = block_pose(xy, yaw, table.top_z)
            if any(np.linalg.norm(xy - other) < DISTRACTOR_MIN_DISTANCE for other in placed):
                continue
            if not (on_table(T_base_block, model, table)
                    and top_face_in_view(T_base_block, model, T_base_camera, camera, margin_px, clearance)):
                continue
            if require_pickable and not pickable(T_base_block, side, start_pose):
                continue
            return side, yaw, xy
        raise RuntimeError(f'no {shape} placement in view from {start_pose!r} after {max_attempts} draws')

    def block(shape, colour, side, yaw, xy):
        return {'shape': shape, 'side': round(side, 5), 'height': BLOCK_HEIGHT, 'color': list(COLOURS_RGB[colour]),
                'xy': [round(float(xy[0]), 5), round(float(xy[1]), 5)], 'yaw': round(yaw, 5)}

    side, yaw, xy = draw(TARGET[0], True, [])
    objects, placed = [block(*TARGET, side, yaw, xy)], [xy]
    others = [(s, c) for s in SHAPES for c in COLOURS_RGB if (s, c) != TARGET]
    for _ in range(distractors):
        shape, colour = others[rng.integers(len(others))]
        side, yaw, xy = draw(shape, False, placed)
        objects.append(block(shape, colour, side, yaw, xy))
        placed.append(xy)
    scene = {'table': {'top_z': table.top_z, 'center': list(table.center), 'size': list(table.size)},
             'objects': objects, 'start': start_pose,
             'camera_error': {'xyz': [0, 0, 0], 'rpy': [0, 0, 0], 'focal_scale': 1.0}}
    Scene.from_dict(scene)          # validates (SceneError on a bug here)
    return scene


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


def _percentile(values, q):
    return float(np.percentile(values, q)) if len(values) else None


def summarise(rows, by_start_pose=False):
    """Statistics per mode (or per mode and start pose): dict 'mode' (or 'mode start_pose') -> {trials,
    verified, success_pct, centring_median_mm, centring_p90_mm, pre_close_median_mm, time_median_s,
    time_p90_s, wall_median_s, failures {label: count}}.

    Centring and time statistics are over verified picks; time = the application's ``time_s`` (robot
    time from the first look to the verified grasp).
    """
    groups = {}
    for row in sorted(rows, key=lambda r: (MODES.index(r['mode']), START_POSES.index(r['start_pose']))):
        key = f"{row['mode']} {row['start_pose']}" if by_start_pose else row['mode']
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
    (the first object's pose, the latest ``/robot/limb/left/endpoint_state`` pose and gripper opening).
    """

    def __init__(self):
        import rospy
        from geometry_msgs.msg import PoseArray

        from baxter_pnp.msgs import msg
        self._lock = threading.Lock()
        self.samples = []            # GroundTruthSample, in arrival order
        self._gripper_pose = None
        self._gripper_position = None
        self._subscribers = [
            rospy.Subscriber('/fake_baxter/object_poses', PoseArray, self._on_objects, queue_size=10),
            rospy.Subscriber(f'/robot/limb/{SIDE}/endpoint_state', msg.EndpointState, self._on_endpoint, queue_size=1),
            rospy.Subscriber(f'/robot/end_effector/{SIDE}_gripper/state', msg.EndEffectorState, self._on_gripper,
                             queue_size=1)]

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

    def wait_for_samples(self, count, timeout=10.0):
        """The sample list once it holds more than ``count`` samples (wall ``timeout`` s), else RuntimeError."""
        deadline = time.monotonic() + timeout
        while self.count() <= count:
            if time.monotonic() > deadline:
                raise RuntimeError('no ground truth from /fake_baxter/object_poses')
            time.sleep(0.02)
        with self._lock:
            return list(self.samples)

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
               'mode': str, 'start_pose': str, 'failure_reason': str, 'trial_dir': str,
               'app_success': 'bool', 'verified': 'bool', 'lifted': 'bool', 'timed_out': 'bool'}


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


def parse_args(argv):
    parser = argparse.ArgumentParser(prog='run_trials.py', description=(
        'Batch pick trials on the fake Baxter: N random scenes per start pose, each picked in each mode, scored '
        'with the ground truth (docs/trials.md).'))
    parser.add_argument('--trials', type=int, default=10, help='random scenes per start pose (default %(default)s)')
    parser.add_argument('--seed', type=int, default=0, help='seed of the scenes and image noise (default %(default)s)')
    parser.add_argument('--mode', choices=MODES + ('all',), default='all')
    parser.add_argument('--start-pose', choices=START_POSES + ('both',), default='both')
    parser.add_argument('--step-fraction', type=float, default=0.35, help='PBVS step fraction (default %(default)s)')
    parser.add_argument('--distractors', type=int, default=0, help='other blocks per scene (default %(default)s)')
    parser.add_argument('--timeout', type=float, default=300.0, help='wall seconds per trial (default %(default)s)')
    parser.add_argument('--place', metavar='X,Y', type=lambda text: [float(v) for v in text.split(',')],
                        help='also place each block at this table position (base, m); scored by where it ends')
    parser.add_argument('--out', default='trials_out', help='output directory (default %(default)s)')
    parser.add_argument('--from-csv', nargs='+', metavar='CSV', help='run nothing: merge these trials.csv files '
                        'into --out and report them (tables, summary.json, plots)')
    return parser.parse_args(argv)


def main(argv=None):
    """Entry point of ``scripts/run_trials.py``; returns the exit code (0 when every trial ran)."""
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
    modes = MODES if args.mode == 'all' else (args.mode,)
    start_poses = START_POSES if args.start_pose == 'both' else (args.start_pose,)
    out = os.path.abspath(args.out)
    os.makedirs(out, exist_ok=True)
    plan = []
    for start_pose in start_poses:
        for trial in range(args.trials):
            scene_seed = args.seed * 100000 + START_POSES.index(start_pose) * 10000 + trial
            scene = random_scene(np.random.default_rng(scene_seed), start_pose, distractors=args.distractors)
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


def report(rows, out, command, args=None):
    """Print the tables (per mode, per mode and start pose); write ``summary.json`` and the plots in ``out``."""
    per_mode, per_start_pose = summarise(rows), summarise(rows, by_start_pose=True)
    with open(os.path.join(out, 'summary.json'), 'w') as f:
        json.dump({'command': command, 'args': args, 'per_mode': per_mode,
                   'per_mode_and_start_pose': per_start_pose}, f, indent=1)
    plot_results(rows, out)
    print(f'\n{command}\n\n{format_table(per_mode)}\n\n{format_table(per_start_pose)}')
    placed = [float(r['place_error_mm']) for r in rows if r.get('place_error_mm') not in (None, '')]
    if placed:
        within = sum(e <= 1000 * PLACE_TOLERANCE for e in placed)
        print(f'\nplace error (ground truth): median {np.median(placed):.1f} mm, p90 '
              f'{np.percentile(placed, 90):.1f} mm, within {1000 * PLACE_TOLERANCE:.0f} mm: {within}/{len(rows)}')
