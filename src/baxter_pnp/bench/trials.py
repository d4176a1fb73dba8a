"""Batch pick trials on the fake Baxter: random scenes, the full ``pick_square.py`` run, ground-truth scoring.

``scripts/run_trials.py --trials N --seed S --mode all --start-pose both`` draws N random scenes per start
pose (``trial_scenes.random_scene``), runs the unmodified pick application on each scene in each mode
against a fresh fake Baxter (:func:`run_trial`), scores every run with the simulator's ground truth and
prints a per-mode table (:func:`summarise`, :func:`format_table`); ``trials.csv``, ``summary.json`` and the
plots go to ``--out``. ``--faults FILE`` and ``--distractor-same-colour`` run a batch under faults;
``--appearance clean|baxter|random`` sets the fake camera's look (``random``: a look per scene drawn from its
seed, ``trial_scenes.trial_appearance``); every row records its conditions (:func:`condition`) and its look.
``--task sort|stack`` runs ``table_task.py`` on random multi-block scenes instead (``table_trials``).
``--soak N`` runs N pick-and-place cycles in one application run against one fake that respawns the block
(``soak.run_soak``), scoring each cycle with the ground truth and watching both processes' memory. See
docs/trials.md.

Ground truth (``/fake_baxter/object_poses``, the gripper pose of ``/robot/limb/left/endpoint_state``:
``ground_truth.GroundTruthMonitor``) is read by the runner only; the application never sees it. Scores
(metres in, millimetres out):

- *lifted*: the block's top face rose at least ``LIFT_THRESHOLD`` (5 cm) above its height in the scene;
- *centring error*: the norm of the block centre's (x, y) in the ``left_gripper`` frame after the lift,
  i.e. its offset from the gripper axis (fingers close along y, so x carries most of it);
- *pre-close offset*: the same (x, y) just before the gripper first started closing (the servo's true
  accuracy, before the fingers push the block);
- a *verified pick* = the application reports success AND the block is lifted.
"""
import argparse
import csv
import json
import math
import os
import sys

import numpy as np
import yaml

from baxter_pnp import pick
from baxter_pnp.params import ParameterError
from baxter_pnp.bench.ground_truth import (LIFT_THRESHOLD, GroundTruthMonitor, block_in_gripper_mm,
                                           pre_close_sample, write_ground_truth)
from baxter_pnp.bench.records import format_number, percentile, write_rows
from baxter_pnp.bench.soak import SOAK_PLACE_XY, soak_main
from baxter_pnp.bench.table_trials import table_trials_main
from baxter_pnp.bench.trial_scenes import (APPEARANCES, COLOURS_RGB, load_faults_mapping, random_scene, trial_appearance,
                                           trial_clutter_rng)
from baxter_pnp.sim.appearance import DEFAULT_PRESET, describe
from baxter_pnp.sim.scene import Scene, SceneError

MODES = pick.MODES
TABLE_TASKS = ('sort', 'stack')     # --task: table_task.py trials (bench/table_trials.py)
START_POSES = ('down', 'angled')
PLACE_TOLERANCE = 0.01          # m: a placed block must end this close to the requested position
CSV_FIELDS = ('mode', 'start_pose', 'trial', 'seed', 'side_mm', 'yaw_deg', 'x_m', 'y_m', 'distractors',
              'same_colour_distractor', 'clutter', 'faults', 'appearance', 'appearance_look', 'app_success',
              'failure_reason',
              'verified', 'lifted', 'rise_mm', 'centring_mm', 'centring_x_mm', 'centring_y_mm', 'pre_close_offset_mm',
              'place_error_mm', 'time_s', 'steps', 'grasp_attempts', 'final_error_mm_est', 'wall_s', 'returncode',
              'timed_out', 'trial_dir')


# ============================================================================================ scoring (pure)

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
    run; rows of CSVs written before the column count as ``none``), its distractors and, unless clean, its
    appearance (``baxter`` or ``random``, not the random look itself), e.g. ``faults:
    camera.drop_probability=0.2, camera.latency=0.1; distractors: 1 (1 of the target's colour); appearance: random``."""
    same = ' (1 of the target\'s colour)' if row.get('same_colour_distractor') else ''
    look = row.get('appearance') or 'clean'
    return (f"faults: {row.get('faults') or 'none'}; distractors: {row.get('distractors') or 0}{same}"
            + ('' if look == 'clean' else f'; appearance: {look}'))


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
        centring = [r['centring_mm'] for r in verified if r['centring_mm'] is not None]    # None: placed
        pre_close = [r['pre_close_offset_mm'] for r in verified if r['pre_close_offset_mm'] is not None]
        times = [r['time_s'] for r in verified]
        failures = {}
        for r in mine:
            label = failure_label(r)
            if label:
                failures[label] = failures.get(label, 0) + 1
        summary[key] = {'trials': len(mine), 'verified': len(verified),
                        'success_pct': 100.0 * len(verified) / len(mine),
                        'centring_median_mm': percentile(centring, 50), 'centring_p90_mm': percentile(centring, 90),
                        'pre_close_median_mm': percentile(pre_close, 50),
                        'time_median_s': percentile(times, 50), 'time_p90_s': percentile(times, 90),
                        'wall_median_s': percentile([r['wall_s'] for r in mine if r['wall_s'] is not None], 50),
                        'failures': failures}
    return summary


def format_table(summary):
    """A ``summarise`` result as a Markdown table."""
    lines = ['| mode | verified picks | centring error median / p90 (mm) | pre-close offset median (mm) | '
             'time to grasp median / p90 (s, sim) | failures |',
             '|---|---|---|---|---|---|']
    for mode, s in summary.items():
        failures = ', '.join(f'{label} {count}' for label, count in sorted(s['failures'].items())) or 'none'
        lines.append(f"| {mode} | {s['verified']}/{s['trials']} ({s['success_pct']:.0f} %) | "
                     f"{format_number(s['centring_median_mm'])} / {format_number(s['centring_p90_mm'])} | "
                     f"{format_number(s['pre_close_median_mm'])} | "
                     f"{format_number(s['time_median_s'])} / {format_number(s['time_p90_s'])} | {failures} |")
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


# ============================================================================================ runs

def scene_conditions(scene):
    """The row fields a generated scene dict fixes besides its target: distractors (count of the other blocks of
    a block colour), same_colour_distractor, clutter (count of the chessboards, tape, cups and black or white
    cubes), faults (``Faults.summary()``), appearance (``clean``, ``baxter``, or ``random`` for a mapping) and
    appearance_look (a mapping's ``sim.appearance.describe`` label, None for a preset)."""
    target, look = scene['objects'][0], scene.get('appearance', DEFAULT_PRESET)
    colours = [list(rgb) for rgb in COLOURS_RGB.values()]
    others = scene['objects'][1:]
    blocks = [o for o in others if o['shape'] not in ('chessboard', 'tape', 'cup') and list(o['color']) in colours]
    return {'distractors': len(blocks), 'clutter': len(others) - len(blocks),
            'same_colour_distractor': any(o['color'] == target['color'] and o['shape'] != target['shape']
                                          for o in blocks),
            'faults': Scene.from_dict(scene).faults.summary(),
            'appearance': 'random' if isinstance(look, dict) else look,
            'appearance_look': describe(look) if isinstance(look, dict) else None}


def run_trial(master, scene, mode, start_pose, step_fraction, workdir, timeout=300.0, seed=0, trial=0,
              place_xy=None, real_time_factor=0.0):
    """One full pick (and place at ``place_xy``, base x, y in m, if given) on a fresh fake Baxter, scored
    with the ground truth; returns a CSV row dict. A place run is verified when the app succeeded and the
    block ends on the table within ``PLACE_TOLERANCE`` of ``place_xy`` (``place_error_mm``).

    Writes ``scene.yaml`` to ``workdir``, starts ``fake_baxter.py --scene scene.yaml --real-time-factor
    real_time_factor --seed seed`` (default unpaced) on ``master`` (a ``launcher.RosMaster``), runs
    ``scripts/pick_square.py`` (its log ``pick.log``, ``result.json`` and outputs in ``workdir``; interrupted
    after ``timeout`` wall seconds), then reads the block and gripper poses and scores them (:func:`score`). This
    process's rospy node must already run on ``master`` (see :func:`main`).
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
    fake = FakeBaxterProcess(master, ['--scene', scene_path, '--real-time-factor', '%g' % real_time_factor,
                                      '--seed', seed],
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
           'x_m': target['xy'][0], 'y_m': target['xy'][1], **scene_conditions(scene),
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


FIELD_TYPES = {'trial': int, 'seed': int, 'steps': int, 'grasp_attempts': int, 'returncode': int, 'distractors': int,
               'clutter': int,
               'mode': str, 'start_pose': str, 'failure_reason': str, 'trial_dir': str, 'faults': str,
               'appearance': str, 'appearance_look': str,
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
    """``rows`` as a ``trials.csv`` (columns ``CSV_FIELDS``)."""
    write_rows(rows, CSV_FIELDS, path)


# ============================================================================================ command line

SIZE_RANGE_M = (0.03, 0.05)     # m: the side range of the trial scenes' blocks (``trial_scenes.random_scene``)


def _size_range(text):
    """``--sizes MIN,MAX`` (m) -> (min, max); argparse's error unless MIN <= MAX and the pick's gripper grips a square
    of either side (``pick.PickConfig``'s ``gripper_gap``)."""
    try:
        low, high = (float(value) for value in text.split(','))
    except ValueError:
        raise argparse.ArgumentTypeError(f'expected MIN,MAX in metres, got {text!r}') from None
    if not low <= high:
        raise argparse.ArgumentTypeError(f'need MIN <= MAX, got {text!r}')
    for side in (low, high):
        try:
            pick.PickConfig.from_dict({'side_length': side})
        except ParameterError as error:
            raise argparse.ArgumentTypeError(str(error)) from None
    return low, high


def parse_args(argv):
    parser = argparse.ArgumentParser(prog='run_trials.py', description=(
        'Batch pick trials on the fake Baxter: N random scenes per start pose, each picked in each mode, scored '
        'with the ground truth; or a soak: N pick-and-place cycles in one run (docs/trials.md).'))
    parser.add_argument('--trials', type=int, default=10, help='random scenes per start pose (default %(default)s)')
    parser.add_argument('--seed', type=int, default=0, help='seed of the scenes and image noise (default %(default)s)')
    parser.add_argument('--mode', choices=MODES + ('all',), help='default: all (soak: pbvs)')
    parser.add_argument('--start-pose', choices=START_POSES + ('both',), help='default: both (soak: down)')
    parser.add_argument('--step-fraction', type=float, default=0.35, help='PBVS step fraction (default %(default)s)')
    parser.add_argument('--sizes', metavar='MIN,MAX', type=_size_range, default=SIZE_RANGE_M,
                        help='side range (m) the blocks are drawn from, 20 mm tall (default %g,%g; small blocks: '
                             '0.019,0.025, the smallest the gripper grips, pick.GRIP_SQUEEZE_M)' % SIZE_RANGE_M)
    parser.add_argument('--distractors', type=int, default=0, help='other blocks per scene (default %(default)s)')
    parser.add_argument('--distractor-same-colour', action='store_true',
                        help="one more block per scene of the target's colour but not a square")
    parser.add_argument('--faults', metavar='FILE', help="YAML file with a 'faults:' key (as fake_baxter.py "
                        "--faults, docs/fake_baxter.md): the faults of every scene")
    parser.add_argument('--appearance', choices=APPEARANCES, default=DEFAULT_PRESET,
                        help="the fake camera's look (docs/fake_baxter.md \"Appearance\"): a preset for every "
                             "scene, or random: a look per scene drawn from its seed (default %(default)s)")
    parser.add_argument('--timeout', type=float,
                        help='wall seconds per trial, or per soak cycle (default 300; --task sort|stack: 900)')
    parser.add_argument('--place', metavar='X,Y', type=lambda text: [float(v) for v in text.split(',')],
                        help='also place each block at this table position (base, m); scored by where it ends '
                             '(soak: default %g,%g)' % SOAK_PLACE_XY)
    parser.add_argument('--soak', type=int, metavar='N', help='instead of trials: N pick-and-place cycles in one '
                        'run of pick_square.py --cycles N against one fake that respawns the block')
    parser.add_argument('--task', choices=('pick',) + TABLE_TASKS, default='pick',
                        help='pick: pick_square.py on one target; sort, stack: table_task.py on random multi-block '
                             'scenes, one mode (default pbvs), scored by the ground truth (bench/table_trials.py)')
    parser.add_argument('--out', default='trials_out', help='output directory (default %(default)s)')
    parser.add_argument('--from-csv', nargs='+', metavar='CSV', help='run nothing: merge these trials.csv files '
                        'into --out and report them (tables, summary.json, plots)')
    args = parser.parse_args(argv)
    args.timeout = args.timeout or (300.0 if args.task == 'pick' else 900.0)
    if args.task != 'pick':
        if (args.soak is not None or args.place is not None or args.distractors or args.distractor_same_colour
                or args.faults or args.from_csv or args.start_pose or args.sizes != SIZE_RANGE_M):
            parser.error('--task %s takes no --soak, --place, --distractors, --faults, --from-csv, --start-pose or '
                         '--sizes' % args.task)
        args.mode = args.mode or 'pbvs'
        return args
    if args.soak is not None:
        if args.soak < 2:
            parser.error('--soak needs at least 2 cycles')
        if args.mode == 'all' or args.start_pose == 'both':
            parser.error('--soak runs one mode from one start pose')
        if (args.distractors or args.distractor_same_colour or args.from_csv or args.appearance == 'random'
                or args.sizes != SIZE_RANGE_M):
            parser.error('--soak takes no distractors, no --appearance random, no --sizes and no --from-csv')
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
    if args.task != 'pick':
        return table_trials_main(args, out, command)
    if args.soak is not None:
        return soak_main(args, faults, out, command)
    modes = MODES if args.mode == 'all' else (args.mode,)
    start_poses = START_POSES if args.start_pose == 'both' else (args.start_pose,)
    plan = []
    for start_pose in start_poses:
        for trial in range(args.trials):
            scene_seed = args.seed * 100000 + START_POSES.index(start_pose) * 10000 + trial
            scene = random_scene(np.random.default_rng(scene_seed), start_pose, size_range=args.sizes,
                                 distractors=args.distractors,
                                 same_colour_distractor=args.distractor_same_colour, faults=faults,
                                 appearance=trial_appearance(args.appearance, scene_seed),
                                 clutter_rng=trial_clutter_rng(args.appearance, scene_seed), place_xy=args.place)
            plan += [(start_pose, trial, scene_seed, scene, mode) for mode in modes]
    rows = []
    print(f'{len(plan)} runs ({args.trials} scenes x {len(start_poses)} start poses x {len(modes)} modes, '
          f'appearance {args.appearance}) -> {out}',
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
    """Print the tables (per mode, per mode and start pose, and per mode and :func:`condition` when the rows
    ran under more than one); write ``summary.json`` (with ``looks``: 'start_pose trial' -> the random look,
    when there are any) and the plots in ``out``."""
    per_mode, per_start_pose = summarise(rows), summarise(rows, by_start_pose=True)
    per_condition = summarise(rows, by_condition=True)
    looks = {f"{r['start_pose']} {r['trial']}": r['appearance_look'] for r in rows if r.get('appearance_look')}
    with open(os.path.join(out, 'summary.json'), 'w') as f:
        json.dump({'command': command, 'args': args, 'per_mode': per_mode,
                   'per_mode_and_start_pose': per_start_pose, 'per_mode_and_condition': per_condition,
                   **({'looks': looks} if looks else {})}, f, indent=1)
    plot_results(rows, out)
    print(f'\n{command}\n\n{format_table(per_mode)}\n\n{format_table(per_start_pose)}')
    if len({condition(row) for row in rows}) > 1:
        print(f'\n{format_table(per_condition)}')
    placed = [float(r['place_error_mm']) for r in rows if r.get('place_error_mm') not in (None, '')]
    if placed:
        within = sum(e <= 1000 * PLACE_TOLERANCE for e in placed)
        print(f'\nplace error (ground truth): median {np.median(placed):.1f} mm, p90 '
              f'{np.percentile(placed, 90):.1f} mm, within {1000 * PLACE_TOLERANCE:.0f} mm: {within}/{len(rows)}')
