"""Batch trials of the multi-block tasks (``run_trials.py --task sort|stack``): random scenes
(``trial_scenes.random_table_scene``), the unmodified ``table_task.py`` on each against a fresh fake Baxter, scored
with the fake's ground truth (``/fake_baxter/object_poses``: every block's final pose; the runner only).

Scores (metres in, millimetres out):

- **sort** (``--bin green:... --bin red:...``, ``trial_scenes.SORT_BINS``): each named square (green, red) stands
  upright on the table within ``PLACE_TOLERANCE`` of one of its bin's first slots (a row from the bin, 8 cm
  apart along -y: ``table_plan.slots``), no two in one slot, and the distractor has not moved (``UNTOUCHED``);
- **stack** (``--at STACK_AT --order red,green,blue``): a standing tower: each block upright with its top face
  on its level (``LEVEL_TOLERANCE``), the bottom within ``PLACE_TOLERANCE`` of ``--at``, each next block within
  ``STACK_TOLERANCE`` (xy) of the one below;
- a trial is *verified* when the scores say so AND the application exited 0.
"""
import json
import math
import os

import numpy as np
import yaml

from baxter_pnp import pick, table_plan
from baxter_pnp.bench.records import format_number, write_rows
from baxter_pnp.bench.trial_scenes import (COLOURS_RGB, SORT_BINS, STACK_AT, STACK_ORDER, random_table_scene,
                                           table_task_places, trial_appearance)
from baxter_pnp.sim.appearance import DEFAULT_PRESET

PLACE_TOLERANCE = 0.015     # m: a block this close (xy) to its slot (the tower's place) is there
STACK_TOLERANCE = 0.01      # m: each stacked block this close (xy) to the one below (the 1 cm)
LEVEL_TOLERANCE = 0.004     # m: a top face this close to its level's height stands on that level
UNTOUCHED = 0.003           # m: a block that should not move moved less than this
UPRIGHT = math.radians(5.0)  # rad: a block tilted less than this stands upright
CSV_FIELDS = ('task', 'mode', 'trial', 'seed', 'appearance', 'app_success', 'failure_reason', 'verified',
              'blocks_in_place', 'blocks_named', 'worst_place_mm', 'distractor_moved_mm', 'tower_levels',
              'worst_stack_offset_mm', 'steps', 'steps_verified', 'time_s', 'wall_s', 'returncode', 'timed_out',
              'trial_dir')


def colour_of(entry):
    """The colour name of a scene object (its RGB one of ``COLOURS_RGB``)."""
    return next(name for name, rgb in COLOURS_RGB.items() if np.allclose(rgb, entry['color']))


def upright_on(T_base_block, top_z, level, height):
    """True if the block stands upright with its top face on ``level`` above the table top ``top_z`` (m)."""
    tilt = math.acos(min(1.0, abs(float(T_base_block[2, 2]))))
    return tilt < UPRIGHT and abs(T_base_block[2, 3] - (top_z + level * height)) < LEVEL_TOLERANCE


def score_sort(scene, T_end, bins=SORT_BINS):
    """Ground-truth scores of a sort: ``T_end`` the blocks' final poses (scene order, 4x4 base m)."""
    top_z = scene['table']['top_z']
    named = [k for k, o in enumerate(scene['objects']) if o['shape'] == 'square' and colour_of(o) in bins]
    in_place, worst, used = 0, 0.0, set()
    for k in named:
        colour = colour_of(scene['objects'][k])
        count = sum(colour_of(scene['objects'][j]) == colour for j in named)
        slots = [s for s, _ in zip(table_plan.slots(bins[colour]), range(count))]
        distances = [float(np.linalg.norm(T_end[k][:2, 3] - s)) for s in slots]
        best = int(np.argmin(distances))
        worst = max(worst, distances[best])
        if distances[best] <= PLACE_TOLERANCE and (colour, best) not in used and \
                upright_on(T_end[k], top_z, 1, scene['objects'][k]['height']):
            in_place += 1
            used.add((colour, best))
    others = [k for k in range(len(scene['objects'])) if k not in named]
    moved = max((float(np.linalg.norm(T_end[k][:2, 3] - scene['objects'][k]['xy'])) for k in others), default=0.0)
    return {'blocks_in_place': in_place, 'blocks_named': len(named), 'worst_place_mm': 1000 * worst,
            'distractor_moved_mm': 1000 * moved,
            'ok': in_place == len(named) and moved < UNTOUCHED}


def score_stack(scene, T_end, at=STACK_AT, order=STACK_ORDER):
    """Ground-truth scores of a stack: ``T_end`` the blocks' final poses (scene order, 4x4 base m)."""
    top_z = scene['table']['top_z']
    by_colour = {colour_of(o): k for k, o in enumerate(scene['objects'])}
    tower = [by_colour[colour] for colour in order]
    levels = 0
    for level, k in enumerate(tower, start=1):
        if not upright_on(T_end[k], top_z, level, scene['objects'][k]['height']):
            break
        levels = level
    offsets = [float(np.linalg.norm(T_end[upper][:2, 3] - T_end[lower][:2, 3]))
               for lower, upper in zip(tower, tower[1:])]
    bottom = float(np.linalg.norm(T_end[tower[0]][:2, 3] - np.asarray(at)))
    return {'tower_levels': levels, 'worst_stack_offset_mm': 1000 * max(offsets), 'worst_place_mm': 1000 * bottom,
            'ok': levels == len(order) and max(offsets) <= STACK_TOLERANCE and bottom <= PLACE_TOLERANCE}


def task_arguments(task):
    """``table_task.py`` arguments of a trial of ``task``."""
    if task == 'sort':
        return ['sort'] + [a for colour, (x, y) in SORT_BINS.items() for a in ('--bin', '%s:%g,%g' % (colour, x, y))]
    return ['stack', '--at', '%g,%g' % STACK_AT, '--order', ','.join(STACK_ORDER)]


def run_table_trial(master, scene, task, mode, workdir, timeout=900.0, seed=0, trial=0):
    """One ``table_task.py`` run of ``task`` on ``scene`` against a fresh fake Baxter (``--real-time-factor 0
    --seed seed``), scored with the ground truth; returns a CSV row dict. This process's rospy node must run on
    ``master``."""
    import rospy
    from geometry_msgs.msg import PoseArray

    from baxter_pnp.sim.launcher import FakeBaxterProcess, run_script
    from baxter_pnp.transforms import pose_msg_to_matrix
    os.makedirs(workdir, exist_ok=True)
    scene_path = os.path.join(workdir, 'scene.yaml')
    with open(scene_path, 'w') as f:
        yaml.safe_dump(scene, f, default_flow_style=None, sort_keys=False)
    result_path = os.path.join(workdir, 'task.json')
    if os.path.exists(result_path):
        os.remove(result_path)
    fake = FakeBaxterProcess(master, ['--scene', scene_path, '--real-time-factor', '0', '--seed', seed],
                             log_path=os.path.join(workdir, 'fake_baxter.log'))
    run, T_end, error = None, None, None
    try:
        fake.start()
        run = run_script(master, 'table_task.py', task_arguments(task) + [
            '--mode', mode, '--result-json', result_path, '--output-dir', workdir], timeout=timeout,
            log_path=os.path.join(workdir, 'table_task.log'))
        poses = rospy.wait_for_message('/fake_baxter/object_poses', PoseArray, timeout=10.0)
        T_end = [pose_msg_to_matrix(p) for p in poses.poses]
    except (RuntimeError, rospy.ROSException) as problem:      # the fake did not start, or no ground truth came
        error = str(problem)
    finally:
        fake.stop()
    result = None
    if os.path.exists(result_path):
        with open(result_path) as f:
            result = json.load(f)
    scores = {'ok': False} if T_end is None else (score_sort if task == 'sort' else score_stack)(scene, T_end)
    look = scene.get('appearance', DEFAULT_PRESET)
    row = {'task': task, 'mode': mode, 'trial': trial, 'seed': seed,
           'appearance': 'random' if isinstance(look, dict) else look,
           'app_success': None if result is None else bool(result['success']),
           'failure_reason': error if result is None else result['failure_reason'],
           'steps': None if result is None else len(result['steps']),
           'steps_verified': None if result is None else sum(s['verified'] for s in result['steps']),
           'time_s': None if result is None else result['total_time_s'],
           'wall_s': None if run is None else round(run.wall_seconds, 2),
           'returncode': None if run is None else run.returncode, 'timed_out': bool(run and run.timed_out),
           'trial_dir': workdir, **{k: v for k, v in scores.items() if k != 'ok'}}
    row['verified'] = bool(scores['ok']) and row['returncode'] == 0
    return row


def summarise(rows):
    """Per (task, mode): runs, verified, rate, ground-truth success regardless of the exit code, median robot
    time (s)."""
    summary = []
    for key in sorted({(r['task'], r['mode']) for r in rows}):
        group = [r for r in rows if (r['task'], r['mode']) == key]
        times = [r['time_s'] for r in group if r['time_s'] is not None]
        summary.append({'task': key[0], 'mode': key[1], 'runs': len(group),
                        'verified': sum(r['verified'] for r in group),
                        'rate': sum(r['verified'] for r in group) / len(group),
                        'app_success': sum(bool(r['app_success']) for r in group),
                        'median_time_s': float(np.median(times)) if times else None})
    return summary


def format_table(summary):
    lines = ['| task | mode | runs | verified | rate | app exit 0 | median robot time (s) |',
             '|---|---|---|---|---|---|---|']
    for s in summary:
        lines.append('| %s | %s | %d | %d | %.0f %% | %d | %s |' % (s['task'], s['mode'], s['runs'], s['verified'],
                                                                  100 * s['rate'], s['app_success'],
                                                                  format_number(s['median_time_s'])))
    return '\n'.join(lines)


def table_trials_main(args, out, command):
    """``run_trials.py --task sort|stack``: ``args.trials`` random scenes (seeds ``args.seed * 100000 + trial``),
    each run in each of ``args.mode`` ('all': every mode), on a private master; ``trials.csv`` and
    ``summary.json`` in ``out``. Returns 0."""
    import rospy

    from baxter_pnp.sim.launcher import RosMaster
    modes = pick.MODES if args.mode == 'all' else (args.mode,)
    plan = []
    for trial in range(args.trials):
        seed = args.seed * 100000 + trial
        scene = random_table_scene(np.random.default_rng(seed), args.task,
                                   appearance=trial_appearance(args.appearance, seed))
        plan += [(trial, seed, scene, mode) for mode in modes]
    print(f'{len(plan)} {args.task} runs ({args.trials} scenes x {len(modes)} modes, places '
          f'{table_task_places(args.task)}) -> {out}', flush=True)
    rows = []
    with RosMaster(log_dir=os.path.join(out, 'ros_log')) as master, master.environment():
        rospy.init_node('run_trials', anonymous=True, disable_signals=True)
        for k, (trial, seed, scene, mode) in enumerate(plan):
            row = run_table_trial(master, scene, args.task, mode, os.path.join(out, f'{args.task}_{trial:03d}_{mode}'),
                                  timeout=args.timeout, seed=seed, trial=trial)
            rows.append(row)
            write_rows(rows, CSV_FIELDS, os.path.join(out, 'trials.csv'))
            print(f"[{k + 1}/{len(plan)}] {args.task} {mode:6s} scene {trial:3d}: "
                  f"{'verified' if row['verified'] else 'FAILED (%s)' % (row['failure_reason'] or 'ground truth')}; "
                  f"time {format_number(row['time_s'])} s, worst place {format_number(row.get('worst_place_mm'))} mm, "
                  f"wall {row['wall_s']} s", flush=True)
        rospy.signal_shutdown('trials finished')
    summary = summarise(rows)
    with open(os.path.join(out, 'summary.json'), 'w') as f:
        json.dump({'command': command, 'args': vars(args), 'per_task_and_mode': summary}, f, indent=1)
    print(f'\n{command}\n\n{format_table(summary)}')
    return 0
