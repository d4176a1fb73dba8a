"""``make bench-real-time``: the fake Baxter's real-time factor while its hand camera streams 640x400 at 20 fps
and ``pick_square.py`` picks, paced (``--real-time-factor 1``, either clock: ``--clock sim`` or ``wall``) or unpaced
(``--real-time-factor 0``, sim clock): the fake's simulated seconds over wall seconds from the camera's opening (by
the pick) to its last step, from the fake's own last log line, with the times it fell behind by more than its
0.1 s catch-up limit; with the sim clock also robot time over wall time between the pick's first and last log lines
(rospy stamps each line with both). The load average is printed beside each run: the factor depends on what else
the machine runs. README, "Fake Baxter"; docs/fake_baxter.md, "Time".
"""
import argparse
import os
import re
import tempfile

import yaml

from baxter_pnp.runtime import command_summary
from baxter_pnp.sim.clock import CLOCKS
from baxter_pnp.sim.launcher import FakeBaxterProcess, RosMaster, run_script
from baxter_pnp.sim.scene import DEFAULT_SCENE_YAML

STAMPS = re.compile(r'\] \[(\d+\.\d+), (\d+\.\d+)\]: ')
STREAMING = re.compile(r'stopped after .*?, ([\d.]+) since the first camera opened ([\d.]+) simulated s ago')
BEHIND = re.compile(r'fell behind (\d+) times')
CASES = {'pbvs-clean-down': ('pbvs', 'down', 'clean'), 'hybrid-baxter-angled': ('hybrid', 'angled', 'baxter')}


def factor_of_log(text):
    """(robot s, wall s, robot/wall) between the first and the last stamped log line of a rospy node's log."""
    stamps = [(float(wall), float(robot)) for wall, robot in STAMPS.findall(text) if float(robot) > 0]
    (wall0, robot0), (wall1, robot1) = stamps[0], stamps[-1]
    return robot1 - robot0, wall1 - wall0, (robot1 - robot0) / (wall1 - wall0)


def streaming_factor(fake_log):
    """(simulated s, factor) of the fake's log while a camera streamed (its stop line), or None if absent."""
    match = STREAMING.search(fake_log)
    return None if match is None else (float(match.group(2)), float(match.group(1)))


def run_case(mode, start_pose, look, clock, work, real_time_factor=1.0):
    """One pick on a fresh master and fake at ``real_time_factor`` (0: unpaced): dict of the fake's streaming
    factor, how often it fell behind, the pick log's factor (sim clock only), the pick's exit status and the
    1-minute load average at the end."""
    with open(DEFAULT_SCENE_YAML) as f:
        scene = yaml.safe_load(f)
    scene['appearance'] = look
    scene_path = os.path.join(work, 'scene_%s.yaml' % look)
    with open(scene_path, 'w') as f:
        yaml.safe_dump(scene, f)
    log_path = os.path.join(work, 'pick_%s_%s_%s_%s.log' % (mode, start_pose, look, clock))
    fake_log = os.path.join(work, 'fake_%s.log' % clock)
    with RosMaster(clock=clock, log_dir=os.path.join(work, 'ros_log')) as master:
        with FakeBaxterProcess(master, ['--scene', scene_path, '--real-time-factor', '%g' % real_time_factor,
                                        '--clock', clock],
                               log_path=fake_log, ready_timeout=120) as fake:
            run = run_script(master, 'pick_square.py', ['--mode', mode, '--start-pose', start_pose], timeout=300,
                             log_path=log_path)
            fake.stop()
            fake_text = fake.log()
    with open(log_path) as f:
        pick_factor = factor_of_log(f.read())[2] if clock == 'sim' else None
    behind = BEHIND.search(fake_text)
    return {'streaming': streaming_factor(fake_text), 'behind': int(behind.group(1)) if behind else 0,
            'pick_log': pick_factor, 'status': run.returncode, 'load': os.getloadavg()[0]}


def main(argv=None):
    parser = argparse.ArgumentParser(prog='bench_real_time.py', description=command_summary(__doc__))
    parser.add_argument('--runs', type=int, default=3, help='runs per case and clock')
    parser.add_argument('--cases', default=','.join(CASES), help='comma-separated of: %s' % ', '.join(CASES))
    parser.add_argument('--clocks', default=','.join(CLOCKS), help='comma-separated of: %s' % ', '.join(CLOCKS))
    parser.add_argument('--unpaced', action='store_true',
                        help='also run each case unpaced (--real-time-factor 0, sim clock)')
    args = parser.parse_args(argv)
    settings = [(clock, 1.0) for clock in args.clocks.split(',')] + ([('sim', 0.0)] if args.unpaced else [])
    print('| case | clock | pacing | run | simulated s streaming | real-time factor (fake) | fell behind '
          '| factor (pick log) | pick exit | load avg |')
    print('|---|---|---|---|---|---|---|---|---|---|')
    with tempfile.TemporaryDirectory() as work:
        for name in args.cases.split(','):
            for k in range(1, args.runs + 1):
                for clock, factor in settings:      # interleaved: every setting sees the same load
                    row = run_case(*CASES[name], clock, work, factor)
                    simulated, measured = row['streaming'] or (float('nan'), float('nan'))
                    pick = '—' if row['pick_log'] is None else '%.3f' % row['pick_log']
                    print('| %s | %s | %s | %d | %.1f | %.3f | %d | %s | %d | %.1f |' % (
                        name, clock, 'paced 1x' if factor else 'unpaced', k, simulated, measured, row['behind'], pick,
                        row['status'], row['load']), flush=True)
    return 0
