"""The soak: many pick-and-place cycles in one application run against one fake Baxter, watching memory.

:func:`run_soak` starts the fake on a scene whose block it respawns after every place (:func:`soak_scene`),
runs ``pick_square.py --cycles N`` once, and while it runs reads the application's result JSON and the
resident memory (``VmRSS``, MiB) of both Python processes (:class:`SoakWatcher`). Each cycle is scored with
the ground truth (:func:`score_cycles`: lifted, verified) and summarised (:func:`summarise_soak`). Positions
in metres in the ``base`` frame, yaw in radians; times in simulated seconds unless named ``wall``.
``scripts/run_trials.py --soak N`` (docs/trials.md#soak).
"""
import csv
import json
import os
import threading
import time

import numpy as np
import yaml

from baxter_pnp.bench.ground_truth import GroundTruthMonitor, lift_times, write_ground_truth
from baxter_pnp.bench.records import csv_value, format_number, percentile, write_rows
from baxter_pnp.bench.trial_scenes import (BLOCK_HEIGHT, PLACE_CLEARANCE, TARGET, block_entry, draw_placement,
                                           scene_dict)
from baxter_pnp.sim.scene import RESPAWN_DELAY, Table

SOAK_PLACE_XY = (0.62, 0.12)      # m (base): default place position of a soak (as in the place trials)
SOAK_POLL = 0.25                  # wall s between looks at the application's result JSON
SOAK_MEMORY_INTERVAL = 10.0       # wall s between the periodic memory samples
SOAK_FIELDS = ('cycle', 'app_success', 'failure_reason', 'lifted', 'verified', 'time_s', 'total_time_s', 'steps',
               'grasp_attempts', 'final_error_mm_est', 'place_error_mm_est', 'end_sim_s', 'cycle_sim_s', 'end_wall_s',
               'respawns', 'app_rss_mib', 'fake_rss_mib')
SOAK_MEMORY_FIELDS = ('wall_s', 'sim_s', 'cycles_done', 'app_rss_mib', 'fake_rss_mib')


def soak_poses(rng, start_pose, count, place_xy, table=None, size_range=(0.03, 0.05)):
    """(side (m), [(x (m), y (m), yaw (rad))] * ``count``): one green square's side and ``count`` poses of it
    on the table, each drawn by ``trial_scenes.draw_placement`` (whole top face in view from ``start_pose``,
    pickable) with its centre at least ``PLACE_CLEARANCE`` from ``place_xy`` (m, base)."""
    side, poses = None, []
    for _ in range(count):
        side, yaw, xy = draw_placement(rng, TARGET[0], start_pose, table, side=side, size_range=size_range,
                                       require_pickable=True, avoid=[(place_xy, PLACE_CLEARANCE)])
        poses.append((round(float(xy[0]), 5), round(float(xy[1]), 5), round(yaw, 5)))
    return side, poses


def soak_scene(side, poses, start_pose, table=None, faults=None, respawn_delay=RESPAWN_DELAY, appearance=None):
    """Scene dict of a soak: the green square of ``side`` (m) at ``poses[0]``, respawned by the fake at
    ``poses[1:]`` in turn (``respawn:`` key, ``respawn_delay`` s) after each pick and place; ``faults``: the
    ``faults:`` mapping or None; ``appearance``: a preset name or None (the fake's default look). Needs at least
    two poses."""
    if len(poses) < 2:
        raise ValueError('a soak needs at least two poses (the first, then the respawns)')
    table = table or Table()
    x, y, yaw = poses[0]
    extra = {'respawn': {'poses': [list(pose) for pose in poses[1:]], 'delay': respawn_delay, 'object': 0}}
    if faults is not None:
        extra['faults'] = faults
    if appearance is not None:
        extra['appearance'] = appearance
    return scene_dict([block_entry(*TARGET, side, yaw, (x, y))], start_pose, table, **extra)


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


def score_cycles(results, ends, lifts, start):
    """Per-cycle rows of a soak: the application's result of each finished cycle (``results``, in order), the
    simulated time at which the runner saw each one finished (``ends``, s), the lift start times (``lifts``,
    s, ``ground_truth.lift_times``) and the time the application started (``start``, s). Cycle k spans (end of k - 1,
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
            'time_to_grasp_median_s': percentile(grasp_times, 50), 'time_to_grasp_p90_s': percentile(grasp_times, 90),
            'cycle_median_s': percentile(lengths, 50), 'cycle_p90_s': percentile(lengths, 90),
            'app_memory': _memory_change(rows, 'app_rss_mib'), 'fake_memory': _memory_change(rows, 'fake_rss_mib')}


def format_soak(summary):
    """A ``summarise_soak`` result as a few lines of text."""
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
        f"time to grasp (verified, s sim): median {format_number(s['time_to_grasp_median_s'])}, "
        f"p90 {format_number(s['time_to_grasp_p90_s'])}; cycle (s sim): median {format_number(s['cycle_median_s'])}, "
        f"p90 {format_number(s['cycle_p90_s'])}",
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
                    csv.writer(f).writerow([csv_value(sample[k]) for k in SOAK_MEMORY_FIELDS])
                next_sample = wall + SOAK_MEMORY_INTERVAL


def run_soak(master, cycles, mode, start_pose, place_xy, out, seed=0, step_fraction=0.35, timeout_per_cycle=300.0,
             faults=None, appearance=None):
    """``cycles`` pick-and-place cycles in one ``pick_square.py --cycles`` run against one fake Baxter that
    respawns the block (:func:`soak_scene`), scored per cycle with the ground truth; returns (cycle rows,
    summary dict). Writes ``scene.yaml``, ``fake_baxter.log``, ``pick.log``, ``result.json`` (the
    application's), ``ground_truth.csv``, ``soak_memory.csv`` (periodic memory samples), ``soak.csv`` (one
    row per cycle) and ``soak_memory.png`` to ``out``. The run is interrupted after ``timeout_per_cycle`` x
    ``cycles`` wall seconds. This process's rospy node must already run on ``master`` (see :func:`soak_main`).
    """
    import rospy
    from rosgraph_msgs.msg import Clock
    from baxter_pnp.sim.launcher import FakeBaxterProcess, start_script
    os.makedirs(out, exist_ok=True)
    side, poses = soak_poses(np.random.default_rng(seed), start_pose, cycles, place_xy)
    scene = soak_scene(side, poses, start_pose, faults=faults, appearance=appearance)
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
    write_rows(rows, SOAK_FIELDS, os.path.join(out, 'soak.csv'))
    plot_soak_memory(rows, watcher.series, os.path.join(out, 'soak_memory.png'))
    summary = summarise_soak(rows, cycles)
    summary.update({'returncode': run.returncode, 'timed_out': run.timed_out, 'wall_s': round(run.wall_seconds, 1),
                    'respawns': monitor.respawns, 'side_m': side, 'poses': poses})
    return rows, summary


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
                              step_fraction=args.step_fraction, timeout_per_cycle=args.timeout, faults=faults,
                              appearance=args.appearance)
        rospy.signal_shutdown('soak finished')
    with open(os.path.join(out, 'soak.json'), 'w') as f:
        json.dump({'command': command, 'args': vars(args), **summary}, f, indent=1)
    print(f'\n{command}\n\n{format_soak(summary)}')
    return 1 if summary['returncode'] is None else summary['returncode']
