"""The thesis's experiments (chapter 5) reproduced on the fake Baxter: depth (§5.2) and reach (§5.3).

``scripts/run_experiments.py depth|reach|all`` (docs/experiments.md). Frames: ``base`` (Baxter's),
``gripper`` (``left_gripper``, the tip frame: z along the fingers), ``camera`` (the hand camera's
optical frame, z forward), ``block`` (origin at the top-face centre). Metres and radians inside; the
tables and plots are in millimetres, degrees and seconds.

Depth (§5.2, Fig. 5.3-5.7). A 40 mm green square lies on the table (yaw 0: its edges parallel to the
pincer line, as the thesis requires). The gripper is put 161 mm (the thesis's ruler) from the
square's centroid, pointing at it, in five poses, each named by where the gripper is relative to the
block: ``above`` (gripper axis vertical), ``left`` / ``right`` (tilted sideways, the gripper on the
robot's left, +y, or right, -y), ``front`` / ``behind`` (tilted forward or backward, the gripper
between the robot and the block, -x, or beyond it, +x). The arm is commanded through the task layer's
public pieces, as the pick uses them (``task.motion.Motion.move_to_pose``: the IK service, safety-checked
position moves), tilting in small steps from ``above`` so that each IK solution stays on the same branch. In
each pose the task layer's ``Eye.look`` (frame, endpoint pose at its stamp, hand-eye from tf, table plane,
``observe_blocks`` with the 'sqp' estimator) with the pick's target rules runs on 56 camera frames. Two errors per sample, estimate minus truth, the
truth from the fake's ground truth (``/fake_baxter/object_poses``) and forward kinematics of the
measured joint angles:

- depth error: the block centre's depth along the camera's optical axis (``T_camera_block[2, 3]``);
- distance error: the gripper-to-centroid distance (what the thesis's ruler measured, 161 mm).

Reach (§5.3, Fig. 5.9-5.12): 2 start poses x 2 PBVS step fractions x N random placements, each a full
``pick_square.py`` run on the fake (``trials.run_trial``); the result JSON's history gives the
estimated distance, x and y errors of the block centre w.r.t. the gripper axis against time.
"""
import argparse
import csv
import json
import math
import multiprocessing
import os
import time
import traceback
from dataclasses import dataclass, fields, replace
from typing import NamedTuple

import numpy as np
import yaml
from scipy.spatial.transform import Rotation


RULER_DISTANCE_M = 0.161            # thesis: gripper centre to the square's centroid (m)
DEPTH_SAMPLES = 56                  # thesis: frames per pose
DEPTH_POSES = ('above', 'left', 'right', 'front', 'behind')
DEFAULT_TILT_DEG = 25.0             # tilt of the four side poses; 30 deg leaves front/behind out of the arm's reach
TILT_STEP_DEG = 5.0                 # the arm tilts in steps of at most this (one IK branch all the way)
SETTLE_S = 1.0                      # robot seconds to wait after a move before sampling
DEPTH_BLOCK_XY = (0.62, 0.25)       # m, base: every pose is reachable there (config/start_poses.yaml 'down' is near)
FOCAL_ERROR_SCALE = 1.03            # the calibration-error condition: true focal length 3 % above the published one
R_BASE_GRIPPER_DOWN = np.diag([-1.0, 1.0, -1.0])   # gripper pointing straight down, pincer line along base y

# Thesis, §6.1: average depth error (mm) of the poses it could measure (left/right only qualitatively:
# right read more than 161 mm, left less).
THESIS_DEPTH_ERROR_MM = {'above': 6.197, 'front': 15.486, 'behind': 17.476}
THESIS_DEPTH_QUALITATIVE = {'left': 'lower than 161 mm (expected)', 'right': 'higher than 161 mm (expected)'}


# ============================================================================================ pose geometry

def pose_direction(name, tilt_rad):
    """Unit vector (base) from the block's centroid to the gripper in the depth pose ``name`` tilted ``tilt_rad``."""
    s, c = math.sin(tilt_rad), math.cos(tilt_rad)
    directions = {'above': (0.0, 0.0, 1.0), 'left': (0.0, s, c), 'right': (0.0, -s, c),
                  'front': (-s, 0.0, c), 'behind': (s, 0.0, c)}
    if name not in directions:
        raise ValueError('unknown depth pose %r (one of %s)' % (name, DEPTH_POSES))
    return np.array(directions[name])


def pointing_pose(target_base, direction_base, distance):
    """T_base_gripper (4x4) with the gripper origin ``distance`` (m) from ``target_base`` along
    ``direction_base`` and its z axis (the fingers) pointing back at the target.

    The orientation is the straight-down one (``R_BASE_GRIPPER_DOWN``) tilted by the smallest
    rotation that turns its z axis onto the target; for the depth poses (tilts about base x or y)
    the pincer line and the gripper's x axis stay in the vertical planes through base y and x, so
    seen from above they remain parallel to the edges of a square of yaw 0.
    """
    direction = np.asarray(direction_base, dtype=float)
    direction = direction / np.linalg.norm(direction)
    tilt, _ = Rotation.align_vectors([-direction], [R_BASE_GRIPPER_DOWN[:, 2]])
    T = np.eye(4)
    T[:3, :3] = tilt.as_matrix() @ R_BASE_GRIPPER_DOWN
    T[:3, 3] = np.asarray(target_base, dtype=float) + distance * direction
    return T


def tilt_path(target_base, name, tilt_rad, distance, step_rad=math.radians(TILT_STEP_DEG)):
    """Gripper poses from ``above`` to the depth pose ``name`` (excluded: above; included: the pose),
    every ``step_rad`` or less of tilt, all ``distance`` from the target and pointing at it."""
    count = max(1, int(math.ceil(tilt_rad / step_rad - 1e-9)))
    return [pointing_pose(target_base, pose_direction(name, a), distance)
            for a in np.linspace(0.0, tilt_rad, count + 1)[1:]]


# ============================================================================================ depth samples

@dataclass
class DepthSample:
    """One frame of the depth experiment (metres). ``*_est`` from the application's perception,
    ``*_true`` from ground truth and forward kinematics."""
    condition: str
    pose: str
    sample: int
    stamp: float                  # frame time (robot s)
    depth_est: float              # block centre along the optical axis (m)
    depth_true: float
    distance_est: float           # gripper origin to block centre (m)
    distance_true: float
    position_error: float         # |estimated - true block centre| (m)
    residual_px: float
    method: str

    @property
    def depth_error_mm(self):
        return 1000.0 * (self.depth_est - self.depth_true)

    @property
    def distance_error_mm(self):
        return 1000.0 * (self.distance_est - self.distance_true)

    @property
    def ruler_error_mm(self):
        """Estimated distance minus the nominal 161 mm (what a ruler reading would compare with)."""
        return 1000.0 * (self.distance_est - RULER_DISTANCE_M)


def depth_sample(condition, pose, index, stamp, estimate, T_base_camera, T_base_gripper,
                 T_base_camera_true, T_base_gripper_true, T_base_block_true):
    """A ``DepthSample`` from a pose estimate (``pose.PoseEstimate``, camera frame) and the poses (4x4, base)
    the application used (``T_base_camera``, ``T_base_gripper``) and the true ones."""
    block_est = (T_base_camera @ estimate.T_camera_object)[:3, 3]
    block_true = T_base_block_true[:3, 3]
    depth_true = float((np.linalg.inv(T_base_camera_true) @ T_base_block_true)[2, 3])
    return DepthSample(condition, pose, index, float(stamp), float(estimate.depth_m), depth_true,
                       float(np.linalg.norm(block_est - T_base_gripper[:3, 3])),
                       float(np.linalg.norm(block_true - T_base_gripper_true[:3, 3])),
                       float(np.linalg.norm(block_est - block_true)), float(estimate.residual_px), estimate.method)


def summarise_depth(samples):
    """Per (condition, pose) statistics (mm): rows of dicts in first-seen order."""
    groups = {}
    for s in samples:
        groups.setdefault((s.condition, s.pose), []).append(s)
    rows = []
    for (condition, pose), group in groups.items():
        depth = np.array([s.depth_error_mm for s in group])
        distance = np.array([s.distance_error_mm for s in group])
        rows.append({'condition': condition, 'pose': pose, 'samples': len(group),
                     'depth_true_mm': 1000.0 * float(np.mean([s.depth_true for s in group])),
                     'distance_true_mm': 1000.0 * float(np.mean([s.distance_true for s in group])),
                     'depth_error_mean_mm': float(depth.mean()), 'depth_error_std_mm': float(depth.std()),
                     'depth_error_mean_abs_mm': float(np.abs(depth).mean()),
                     'distance_error_mean_mm': float(distance.mean()),
                     'distance_error_std_mm': float(distance.std()),
                     'distance_error_mean_abs_mm': float(np.abs(distance).mean()),
                     'ruler_error_mean_mm': float(np.mean([s.ruler_error_mm for s in group])),
                     'position_error_mean_mm': 1000.0 * float(np.mean([s.position_error for s in group]))})
    return rows


# ============================================================================================ depth, ROS edge

def block_ground_truth(timeout=5.0):
    """T_base_block (4x4) of the first block, from the fake Baxter's ground truth topic (benchmarks only)."""
    import rospy
    from geometry_msgs.msg import PoseArray
    from baxter_pnp.transforms import pose_msg_to_matrix
    message = rospy.wait_for_message('/fake_baxter/object_poses', PoseArray, timeout=timeout)
    return pose_msg_to_matrix(message.poses[0])


class DepthRig(NamedTuple):
    """The task layer's public pieces the depth experiment runs on (rospy initialised)."""
    session: object     # task.session.RobotSession, connected
    motion: object      # task.motion.Motion
    eye: object         # task.eye.Eye looking for the pick configuration's block
    rules: object       # task.target.TargetRules of that block

    def look(self, after_stamp):
        """A look whose target is the believable block (``task.target.choose_target``)."""
        from baxter_pnp.task import target

        def choose(observations, T_base_camera, camera):
            return target.choose_target(observations, T_base_camera, self.rules, (camera.width, camera.height))
        return self.eye.look(after_stamp, choose)


def connect_rig():
    """A connected :class:`DepthRig` with the package's pick and vision configuration."""
    from baxter_pnp import pick, pick_app, vision
    from baxter_pnp.task import target
    from baxter_pnp.task.eye import BlockQuery, Eye
    from baxter_pnp.task.motion import Motion
    from baxter_pnp.task.session import RobotSession
    from baxter_pnp.task.settings import load_configs
    config, session_config = load_configs(pick.PickConfig, pick_app.DEFAULT_CONFIG)
    session = RobotSession(session_config, log_name='depth')
    session.connect()
    query = BlockQuery(config.shape, config.colour, config.side_length, config.block_height, config.estimator,
                       session.table, config.edge_radius)
    # the experiment measures the image's depth: the target's estimate as posed, not pulled towards the table's height
    rules = replace(target.TargetRules.of(config, session.table), table_height_sigma=0.0)
    return DepthRig(session, Motion(session), Eye(session, vision.VisionConfig.from_yaml(), query), rules)


def sample_depth(rig, condition, pose_name, count, T_base_block_true):
    """``count`` DepthSamples from consecutive camera frames, the arm held still (rospy initialised)."""
    import rospy
    side, kinematics, limb = rig.session.config.side, rig.session.kinematics, rig.session.limb
    samples, after, misses = [], rospy.get_time(), 0
    while len(samples) < count:
        look = rig.look(after)
        after = look.frame.stamp
        if look.target is None:
            misses += 1
            if misses > count:
                raise RuntimeError('depth %s/%s: the block is not detected (%d frames without it)'
                                   % (condition, pose_name, misses))
            continue
        q = limb.joint_positions()
        samples.append(depth_sample(condition, pose_name, len(samples), look.frame.stamp, look.target.pose,
                                    look.T_base_camera, look.T_base_gripper,
                                    kinematics.fk(q, '%s_hand_camera' % side), kinematics.fk(q, '%s_gripper' % side),
                                    T_base_block_true))
    return samples


def measure_depth(condition, poses=DEPTH_POSES, samples=DEPTH_SAMPLES, tilt_deg=DEFAULT_TILT_DEG,
                  distance=RULER_DISTANCE_M):
    """Run the depth experiment against the running fake Baxter (rospy initialised): list of DepthSamples.

    For each pose the arm tilts from ``above`` to it in steps, samples ``samples`` frames after
    ``SETTLE_S`` robot seconds, and tilts back.
    """
    import rospy
    rig = connect_rig()
    T_base_block = block_ground_truth()
    target = T_base_block[:3, 3]
    tilt = math.radians(tilt_deg)
    above = pointing_pose(target, pose_direction('above', 0.0), distance)
    rig.motion.move_to_pose(above, 'depth pose above')
    results = []
    for index, name in enumerate(poses):
        path = [] if name == 'above' else tilt_path(target, name, tilt, distance)
        for k, T in enumerate(path):
            rig.motion.move_to_pose(T, 'depth pose %s (%d/%d)' % (name, k + 1, len(path)))
        rospy.sleep(SETTLE_S)
        results += sample_depth(rig, condition, name, samples, block_ground_truth())
        if path and index + 1 < len(poses):
            for k, T in enumerate(path[-2::-1] + [above]):
                rig.motion.move_to_pose(T, 'back from %s (%d/%d)' % (name, k + 1, len(path)))
    rig.session.camera.close()
    return results


def depth_scene(focal_scale=1.0, block_xy=DEPTH_BLOCK_XY):
    """Scene dict of the depth experiment: the 40 mm green square at ``block_xy``, yaw 0, start 'down'."""
    return {'table': {'top_z': -0.15, 'center': [0.75, 0.0], 'size': [0.9, 1.5]},
            'objects': [{'shape': 'square', 'side': 0.04, 'height': 0.02, 'color': [0.1, 0.7, 0.1],
                         'xy': list(block_xy), 'yaw': 0.0}],
            'start': 'down',
            'camera_error': {'xyz': [0, 0, 0], 'rpy': [0, 0, 0], 'focal_scale': float(focal_scale)}}


def _child_main(connection, master_uri, function, args):
    """Body of ``call_in_ros_node``'s child: a rospy node on ``master_uri``, then ``function(*args)``."""
    import rospy
    from baxter_pnp.sim.launcher import ros_environment
    try:
        os.environ.update(ros_environment(master_uri))
        rospy.init_node('run_experiments', anonymous=True, disable_signals=True)
        connection.send((True, function(*args)))
    except BaseException:                   # report everything, including KeyboardInterrupt, to the parent
        connection.send((False, traceback.format_exc()))
    finally:
        rospy.signal_shutdown('experiment finished')
        connection.close()


def call_in_ros_node(master, function, *args):
    """``function(*args)`` in a forked child process whose rospy node talks to ``master``; its result.

    rospy allows one node per process, bound to one master for good: each experiment gets its own
    master, fake Baxter and measuring process. The child inherits ``args`` (fork: nothing is pickled
    on the way in); the result comes back pickled. RuntimeError with the child's traceback if it failed.
    """
    context = multiprocessing.get_context('fork')
    receiver, sender = context.Pipe(duplex=False)
    child = context.Process(target=_child_main, args=(sender, master.uri, function, args), name='run_experiments')
    child.start()
    sender.close()
    try:
        ok, value = receiver.recv()
    except EOFError:
        ok, value = False, 'the measuring process exited without a result'
    finally:
        child.join(timeout=10.0)
        if child.is_alive():
            child.terminate()
            child.join()
    if not ok:
        raise RuntimeError('%s failed in its ROS process:\n%s' % (function.__name__, value))
    return value


def run_depth_condition(condition, focal_scale, workdir, poses=DEPTH_POSES, samples=DEPTH_SAMPLES,
                        tilt_deg=DEFAULT_TILT_DEG):
    """One condition of the depth experiment on a fresh master and fake Baxter: list of DepthSamples."""
    from baxter_pnp.sim.launcher import FakeBaxterProcess, RosMaster
    os.makedirs(workdir, exist_ok=True)
    scene_path = os.path.join(workdir, 'scene_%s.yaml' % condition)
    with open(scene_path, 'w') as f:
        yaml.safe_dump(depth_scene(focal_scale), f)
    with RosMaster(log_dir=os.path.join(workdir, 'ros_log')) as master:
        with FakeBaxterProcess(master, ['--scene', scene_path, '--enable', '--real-time-factor', '0'],
                               log_path=os.path.join(workdir, 'fake_%s.log' % condition)):
            return call_in_ros_node(master, measure_depth, condition, tuple(poses), samples, tilt_deg)


# ============================================================================================ reach

REACH_START_POSES = ('down', 'angled')      # thesis Fig. 5.8
REACH_FRACTIONS = (0.35, 0.12)              # thesis: 35 % and 12 % of the remaining displacement per step
REACH_SIDE_M = 0.04                         # the thesis's square
THESIS_REACH_TIME_S = {0.35: 18.0, 0.12: 31.0}   # §6.2: average time to complete the task
THESIS_REACH_OUTCOME = {
    ('down', 0.35): '1 of 3 trials reached the square (2 lost it at the image border)',
    ('angled', 0.35): 'none reached it (occluded by the gripper)',
    ('down', 0.12): 'closer, smoother, but lost before reaching',
    ('angled', 0.12): 'closer, smoother, but lost before reaching'}


@dataclass
class ReachTrial:
    """One pick run of the reach experiment: the trials row's outcome and the application's history.

    ``reach_time_s``: robot time from the first look to the first step within the application's
    position and yaw tolerances of the hover pose (None if never); ``time_s``: to the verified grasp.
    ``history``: dicts of the result JSON (time_s, error_mm, block_in_gripper_mm, ...).
    """
    start_pose: str
    step_fraction: float
    trial: int
    seed: int
    verified: bool
    failure: str
    time_s: object
    reach_time_s: object
    steps: object
    centring_mm: object
    pre_close_offset_mm: object
    wall_s: object
    trial_dir: str
    history: list


def reach_time(history, position_tolerance_mm, yaw_tolerance_deg):
    """Robot time (s) of the first history step within both tolerances of the hover pose, or None."""
    for step in history:
        if step['error_mm'] <= position_tolerance_mm and step['error_deg'] <= yaw_tolerance_deg:
            return step['time_s']
    return None


def reach_trial(row):
    """A ``ReachTrial`` from a ``trials.run_trial`` row (reads its result.json)."""
    from baxter_pnp import pick
    from baxter_pnp.bench import trials
    path = os.path.join(row['trial_dir'], 'result.json')
    history = []
    if os.path.exists(path):
        with open(path) as f:
            history = json.load(f)['history']
    config = pick.PickConfig()
    return ReachTrial(row['start_pose'], row['step_fraction'], row['trial'], row['seed'], row['verified'],
                      trials.failure_label(row), row['time_s'],
                      reach_time(history, 1000.0 * config.position_tolerance, math.degrees(config.yaw_tolerance)),
                      row['steps'], row['centring_mm'], row['pre_close_offset_mm'], row['wall_s'], row['trial_dir'],
                      history)


def reach_seed(seed, start_pose, trial):
    """Scene seed of a trial: the same placements for both step fractions (a paired comparison)."""
    return seed * 1000 + REACH_START_POSES.index(start_pose) * 100 + trial


def run_reach_cells(master, out_dir, trial_count, seed, start_poses, fractions, timeout):
    """Every (start pose, fraction, trial) run on ``master`` (this process's rospy node must be on it)."""
    from baxter_pnp.bench import trial_scenes, trials
    results = []
    for start_pose in start_poses:
        for trial in range(trial_count):
            scene_seed = reach_seed(seed, start_pose, trial)
            scene = trial_scenes.random_scene(np.random.default_rng(scene_seed), start_pose,
                                              size_range=(REACH_SIDE_M, REACH_SIDE_M))
            for fraction in fractions:
                workdir = os.path.join(out_dir, 'reach', '%s_%.2f_%02d' % (start_pose, fraction, trial))
                row = trials.run_trial(master, scene, 'pbvs', start_pose, fraction, workdir, timeout=timeout,
                                       seed=scene_seed, trial=trial)
                row['step_fraction'] = fraction
                result = reach_trial(row)
                results.append(result)
                print('reach %s %.2f trial %d: %s, time %s s, %d steps, wall %s s'
                      % (start_pose, fraction, trial, 'verified' if result.verified else 'FAILED (%s)' % result.failure,
                         _fmt(result.time_s), len(result.history), result.wall_s), flush=True)
    return results


def summarise_reach(results):
    """Per (start pose, fraction) rows: trials, verified, success %, mean/median times (s) over verified runs,
    mean reach time (s), failures {label: count}."""
    rows = []
    cells = []
    for r in results:
        if (r.start_pose, r.step_fraction) not in cells:
            cells.append((r.start_pose, r.step_fraction))
    for start_pose, fraction in cells:
        mine = [r for r in results if (r.start_pose, r.step_fraction) == (start_pose, fraction)]
        verified = [r for r in mine if r.verified]
        reached = [r.reach_time_s for r in mine if r.reach_time_s is not None]
        failures = {}
        for r in mine:
            if not r.verified:
                failures[r.failure] = failures.get(r.failure, 0) + 1
        rows.append({'start_pose': start_pose, 'step_fraction': fraction, 'trials': len(mine),
                     'verified': len(verified), 'success_pct': 100.0 * len(verified) / len(mine),
                     'reached': len(reached),
                     'reach_time_mean_s': float(np.mean(reached)) if reached else None,
                     'time_mean_s': float(np.mean([r.time_s for r in verified])) if verified else None,
                     'time_max_s': float(np.max([r.time_s for r in verified])) if verified else None,
                     'steps_mean': float(np.mean([r.steps for r in verified])) if verified else None,
                     'centring_mean_mm': float(np.mean([r.centring_mm for r in verified])) if verified else None,
                     'failures': failures})
    return rows


# ============================================================================================ outputs

def _fmt(value, digits=1):
    return 'n/a' if value is None else '%.*f' % (digits, value)


def _pyplot():
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt
    return plt


def plot_depth(samples, out_dir):
    """``depth_<pose>.png``: error per sample (mm) of each condition, like the thesis's Fig. 5.3-5.7 (b)."""
    plt = _pyplot()
    paths = []
    for pose in dict.fromkeys(s.pose for s in samples):
        figure, ax = plt.subplots(figsize=(7, 3.6))
        for colour, condition in zip(('tab:blue', 'tab:red', 'tab:green'), dict.fromkeys(s.condition for s in samples)):
            mine = [s for s in samples if s.pose == pose and s.condition == condition]
            ax.plot([s.sample + 1 for s in mine], [s.depth_error_mm for s in mine], '.-', color=colour,
                    label='%s: depth along the optical axis' % condition)
            ax.plot([s.sample + 1 for s in mine], [s.distance_error_mm for s in mine], 'x--', color=colour,
                    label='%s: gripper-to-centroid distance' % condition)
        if pose in THESIS_DEPTH_ERROR_MM:
            ax.axhline(THESIS_DEPTH_ERROR_MM[pose], color='grey', ls=':', label='thesis average error (sign not given)')
        ax.axhline(0.0, color='black', lw=0.5)
        ax.set_xlabel('sample')
        ax.set_ylabel('estimated - true (mm)')
        ax.set_title('Depth estimation error, gripper %s the square (161 mm)' % ('above' if pose == 'above' else
                                                                                 {'left': 'left of', 'right': 'right of',
                                                                                  'front': 'in front of',
                                                                                  'behind': 'behind'}[pose]))
        ax.legend(fontsize=7)
        figure.tight_layout()
        paths.append(os.path.join(out_dir, 'depth_%s.png' % pose))
        figure.savefig(paths[-1], dpi=100)
        plt.close(figure)
    return paths


def plot_reach(results, out_dir):
    """``reach_<start>_<fraction>.png``: estimated distance, x and y error vs time of every trial (Fig. 5.9-5.12)."""
    plt = _pyplot()
    paths = []
    for row in summarise_reach(results):
        start_pose, fraction = row['start_pose'], row['step_fraction']
        figure, axes = plt.subplots(3, 1, figsize=(7, 8), sharex=True)
        for r in [r for r in results if (r.start_pose, r.step_fraction) == (start_pose, fraction)]:
            t = [h['time_s'] for h in r.history]
            label = 'trial %d (%s)' % (r.trial + 1, 'picked' if r.verified else r.failure)
            for ax, values in zip(axes, ([h['error_mm'] for h in r.history],
                                         [h['block_in_gripper_mm'][0] for h in r.history],
                                         [h['block_in_gripper_mm'][1] for h in r.history])):
                line, = ax.plot(t, values, '.-', label=label)
                if t and not r.verified:
                    ax.plot(t[-1], values[-1], 'x', color=line.get_color(), ms=10)
        for ax, what in zip(axes, ('distance to the hover pose (mm)', 'x error (mm)', 'y error (mm)')):
            ax.axhline(0.0, color='black', lw=0.5)
            ax.set_ylabel(what)
        axes[0].set_title('Reach, start pose %s, steps of %d %% of the remaining displacement'
                          % (start_pose, round(100 * fraction)))
        axes[0].legend(fontsize=7)
        axes[-1].set_xlabel('time (s, robot)')
        figure.tight_layout()
        paths.append(os.path.join(out_dir, 'reach_%s_%02d.png' % (start_pose, round(100 * fraction))))
        figure.savefig(paths[-1], dpi=100)
        plt.close(figure)
    return paths


def write_depth_csv(samples, path):
    names = [f.name for f in fields(DepthSample)]
    with open(path, 'w', newline='') as f:
        writer = csv.writer(f)
        writer.writerow(names + ['depth_error_mm', 'distance_error_mm', 'ruler_error_mm'])
        for s in samples:
            writer.writerow([getattr(s, n) for n in names] + [s.depth_error_mm, s.distance_error_mm, s.ruler_error_mm])


def write_reach_csv(results, out_dir):
    """``reach_trials.csv`` (one row per run) and ``reach_history.csv`` (one row per servo step)."""
    names = [f.name for f in fields(ReachTrial) if f.name != 'history']
    with open(os.path.join(out_dir, 'reach_trials.csv'), 'w', newline='') as f:
        writer = csv.writer(f)
        writer.writerow(names)
        for r in results:
            writer.writerow([getattr(r, n) for n in names])
    with open(os.path.join(out_dir, 'reach_history.csv'), 'w', newline='') as f:
        writer = csv.writer(f)
        writer.writerow(['start_pose', 'step_fraction', 'trial', 'step', 'time_s', 'error_mm', 'error_deg',
                         'x_mm', 'y_mm', 'z_mm', 'depth_m'])
        for r in results:
            for h in r.history:
                writer.writerow([r.start_pose, r.step_fraction, r.trial, h['step'], h['time_s'], h['error_mm'],
                                 h['error_deg']] + list(h['block_in_gripper_mm']) + [h['depth_m']])


def depth_markdown(rows, tilt_deg):
    """Markdown tables of the depth experiment (per condition), beside the thesis's numbers."""
    lines = ['## Depth (thesis §5.2)', '',
             'Gripper 161 mm from the square\'s centroid, pointing at it; side poses tilted %.0f deg. Errors are '
             'estimated minus true, mean ± std over the samples (mm). "depth" = the centroid\'s depth along the '
             'optical axis; "distance" = gripper-to-centroid distance (the thesis\'s ruler).' % tilt_deg, '']
    for condition in dict.fromkeys(r['condition'] for r in rows):
        lines += ['### %s' % condition, '',
                  '| pose | samples | true depth (mm) | depth error | mean abs depth error | distance error | '
                  'mean abs distance error | thesis |', '|---|---|---|---|---|---|---|---|']
        for r in [r for r in rows if r['condition'] == condition]:
            thesis = ('%.1f mm' % THESIS_DEPTH_ERROR_MM[r['pose']] if r['pose'] in THESIS_DEPTH_ERROR_MM
                      else THESIS_DEPTH_QUALITATIVE.get(r['pose'], ''))
            lines.append('| %s | %d | %.1f | %+.2f ± %.2f | %.2f | %+.2f ± %.2f | %.2f | %s |'
                         % (r['pose'], r['samples'], r['depth_true_mm'], r['depth_error_mean_mm'],
                            r['depth_error_std_mm'], r['depth_error_mean_abs_mm'], r['distance_error_mean_mm'],
                            r['distance_error_std_mm'], r['distance_error_mean_abs_mm'], thesis))
        lines.append('')
    return '\n'.join(lines)


def reach_markdown(rows, trial_count):
    """Markdown table of the reach experiment beside the thesis's outcome."""
    lines = ['## Reach (thesis §5.3)', '',
             'PBVS look-and-move, %d random placements of a 40 mm square per cell (the same placements for both '
             'fractions). Times are robot seconds from the first look: "reach" = first step within 2 mm / 2 deg '
             'of the hover pose, "pick" = verified grasp; means over the runs that got there.' % trial_count, '',
             '| start pose | step fraction | verified picks | reached hover | reach time (s) | pick time mean / '
             'max (s) | steps | centring (mm) | failures | thesis |', '|---|---|---|---|---|---|---|---|---|---|']
    for r in rows:
        failures = ', '.join('%s %d' % item for item in sorted(r['failures'].items())) or 'none'
        thesis = '%.0f s average; %s' % (THESIS_REACH_TIME_S.get(r['step_fraction'], float('nan')),
                                        THESIS_REACH_OUTCOME.get((r['start_pose'], r['step_fraction']), ''))
        lines.append('| %s | %.2f | %d/%d (%.0f %%) | %d | %s | %s / %s | %s | %s | %s | %s |'
                     % (r['start_pose'], r['step_fraction'], r['verified'], r['trials'], r['success_pct'],
                        r['reached'], _fmt(r['reach_time_mean_s']), _fmt(r['time_mean_s']), _fmt(r['time_max_s']),
                        _fmt(r['steps_mean']), _fmt(r['centring_mean_mm']), failures, thesis))
    return '\n'.join(lines) + '\n'


def write_summary(out_dir):
    """``summary.md`` from the section files present (``depth.md``, ``reach.md``)."""
    sections = []
    for name in ('depth.md', 'reach.md'):
        path = os.path.join(out_dir, name)
        if os.path.exists(path):
            with open(path) as f:
                sections.append(f.read())
    with open(os.path.join(out_dir, 'summary.md'), 'w') as f:
        f.write('# Thesis experiments on the fake Baxter (scripts/run_experiments.py)\n\n' + '\n'.join(sections))


# ============================================================================================ experiments

def depth_experiment(out_dir, samples=DEPTH_SAMPLES, poses=DEPTH_POSES, tilt_deg=DEFAULT_TILT_DEG,
                     focal_scales=(1.0, FOCAL_ERROR_SCALE)):
    """Depth experiment for each focal scale (1.0 = nominal): CSV, plots, ``depth.md``; returns the summary rows."""
    all_samples = []
    for focal_scale in focal_scales:
        condition = 'nominal' if focal_scale == 1.0 else 'focal_x%.3g' % focal_scale
        print('depth: condition %s (%d poses x %d samples)' % (condition, len(poses), samples), flush=True)
        all_samples += run_depth_condition(condition, focal_scale, os.path.join(out_dir, 'depth_runs'), poses,
                                           samples, tilt_deg)
    rows = summarise_depth(all_samples)
    write_depth_csv(all_samples, os.path.join(out_dir, 'depth_samples.csv'))
    plot_depth(all_samples, out_dir)
    with open(os.path.join(out_dir, 'depth.md'), 'w') as f:
        f.write(depth_markdown(rows, tilt_deg))
    return rows


def reach_experiment(out_dir, trial_count, seed=0, start_poses=REACH_START_POSES, fractions=REACH_FRACTIONS,
                     timeout=300.0):
    """Reach experiment: CSVs, plots, ``reach.md``; returns the summary rows."""
    from baxter_pnp.sim.launcher import RosMaster
    with RosMaster(log_dir=os.path.join(out_dir, 'reach', 'ros_log')) as master:
        results = call_in_ros_node(master, run_reach_cells, master, out_dir, trial_count, seed, tuple(start_poses),
                                   tuple(fractions), timeout)
    rows = summarise_reach(results)
    write_reach_csv(results, out_dir)
    plot_reach(results, out_dir)
    with open(os.path.join(out_dir, 'reach.md'), 'w') as f:
        f.write(reach_markdown(rows, trial_count))
    return rows


def parse_args(argv):
    common = argparse.ArgumentParser(add_help=False)
    common.add_argument('--out', default=os.path.join('out', 'experiments'),
                        help='output directory for PNGs, CSVs and summary.md (default %(default)s)')
    depth = argparse.ArgumentParser(add_help=False)
    depth.add_argument('--samples', type=int, default=DEPTH_SAMPLES, help='frames per pose (default %(default)s)')
    depth.add_argument('--poses', default=','.join(DEPTH_POSES), help='comma-separated subset of %(default)s')
    depth.add_argument('--tilt-deg', type=float, default=DEFAULT_TILT_DEG,
                       help='tilt of the side poses (deg, default %(default)s)')
    depth.add_argument('--focal-scales', default='1.0,%g' % FOCAL_ERROR_SCALE,
                       help='true / published focal length of each condition (default %(default)s)')
    reach = argparse.ArgumentParser(add_help=False)
    reach.add_argument('--trials', type=int, default=3, help='placements per cell (default %(default)s)')
    reach.add_argument('--seed', type=int, default=0, help='seed of the placements (default %(default)s)')
    reach.add_argument('--start-poses', default=','.join(REACH_START_POSES), help='default %(default)s')
    reach.add_argument('--fractions', default=','.join('%g' % f for f in REACH_FRACTIONS), help='default %(default)s')
    reach.add_argument('--timeout', type=float, default=300.0, help='wall seconds per run (default %(default)s)')
    parser = argparse.ArgumentParser(prog='run_experiments.py', description=(
        "The thesis's chapter 5 experiments on the fake Baxter: depth estimation (5.2) and reach (5.3)."))
    commands = parser.add_subparsers(dest='command', required=True)
    commands.add_parser('depth', parents=[common, depth], help='depth estimation, 5 poses x 56 samples')
    commands.add_parser('reach', parents=[common, reach], help='PBVS reach, 2 start poses x 2 step fractions')
    commands.add_parser('all', parents=[common, depth, reach], help='both')
    args = parser.parse_args(argv)
    if hasattr(args, 'poses'):
        args.poses = tuple(p.strip() for p in args.poses.split(',') if p.strip())
        unknown = sorted(set(args.poses) - set(DEPTH_POSES))
        if unknown:
            parser.error('--poses: unknown pose(s) %s (known: %s)' % (unknown, ', '.join(DEPTH_POSES)))
        args.focal_scales = tuple(float(v) for v in args.focal_scales.split(','))
    if hasattr(args, 'fractions'):
        args.fractions = tuple(float(v) for v in args.fractions.split(','))
        args.start_poses = tuple(p.strip() for p in args.start_poses.split(','))
        unknown = sorted(set(args.start_poses) - set(REACH_START_POSES))
        if unknown:
            parser.error('--start-poses: unknown start pose(s) %s' % unknown)
    return args


def main(argv=None):
    """Entry point of ``scripts/run_experiments.py``; returns the exit code."""
    import sys
    args = parse_args(sys.argv[1:] if argv is None else argv)
    out = os.path.abspath(args.out)
    os.makedirs(out, exist_ok=True)
    started = time.monotonic()
    if args.command in ('depth', 'all'):
        print(depth_markdown(depth_experiment(out, args.samples, args.poses, args.tilt_deg, args.focal_scales),
                             args.tilt_deg), flush=True)
    if args.command in ('reach', 'all'):
        print(reach_markdown(reach_experiment(out, args.trials, args.seed, args.start_poses, args.fractions,
                                              args.timeout), args.trials), flush=True)
    write_summary(out)
    print('wrote %s (%.0f s wall)' % (os.path.join(out, 'summary.md'), time.monotonic() - started))
    return 0
