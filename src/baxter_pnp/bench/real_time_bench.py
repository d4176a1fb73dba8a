"""``make bench-real-time``: the fake Baxter's real-time factor while its hand camera streams 640x400 at 20 fps
and ``pick_square.py`` picks, paced (``--real-time-factor 1``), on either clock (``--clock sim`` or ``wall``): the
fake's simulated seconds over wall seconds from the camera's opening (by the pick) to the fake's stop right after
the pick, from the fake's own last log line; with the sim clock also robot time over wall time between the pick's
first and last log lines (rospy stamps each line with both). The load average is printed beside each run: the
factor depends on what else the machine runs. README, "Fake Baxter"; docs/fake_baxter.md, "Time".
"""
import argparse
import os
import re
import tempfile

import yaml

from baxter_pnp.sim.clock import CLOCKS
from baxter_pnp.sim.launcher import FakeBaxterProcess, RosMaster, run_script
from baxter_pnp.sim.scene import DEFAULT_SCENE_YAML

STAMPS = re.compile(r'\] \[(\d+\.\d+), (\d+\.\d+)\]: ')
STREAMING = re.compile(r'stopped after .*?, ([\d.]+) since the first camera opened ([\d.]+) simulated s ago')
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


def run_case(mode, start_pose, look, clock, work):
    """One paced pick on a fresh master and fake: dict of the fake's streaming factor, the pick log's factor
    (sim clock only), the pick's exit status and the 1-minute load average at the end."""
    with open(DEFAULT_SCENE_YAML) as f:
        scene = yaml.safe_load(f)
    scene['appearance'] = look
    scene_path = os.path.join(work, 'scene_%s.yaml' % look)
    with open(scene_path, 'w') as f:
        yaml.safe_dump(scene, f)
    log_path = os.path.join(work, 'pick_%s_%s_%s_%s.log' % (mode, start_pose, look, clock))
    fake_log = os.path.join(work, 'fake_%s.log' % clock)
    with RosMaster(clock=clock, log_dir=os.path.join(work, 'ros_log')) as master:
        with FakeBaxterProcess(master, ['--scene', scene_path, '--real-time-factor', '1', '--clock', clock],
                               log_path=fake_log, ready_timeout=120) as fake:
            run = run_script(master, 'pick_square.py', ['--mode', mode, '--start-pose', start_pose], timeout=300,
                             log_path=log_path)
            fake.stop()
            fake_text = fake.log()
    with open(log_path) as f:
        pick_factor = factor_of_log(f.read())[2] if clock == 'sim' else None
    return {'streaming': streaming_factor(fake_text), 'pick_log': pick_factor, 'status': run.returncode,
            'load': os.getloadavg()[0]}


def main(argv=None):
    parser = argparse.ArgumentParser(prog='bench_real_time.py', description=__doc__.split('\n')[0].strip('`: '))
    parser.add_argument('--runs', type=int, default=3, help='runs per case and clock')
    parser.add_argument('--cases', default=','.join(CASES), help='comma-separated of: %s' % ', '.join(CASES))
    parser.add_argument('--clocks', default=','.join(CLOCKS), help='comma-separated of: %s' % ', '.join(CLOCKS))
    args = parser.parse_args(argv)
    print('| case | clock | run | simulated s streaming | real-time factor (fake) | factor (pick log) | pick exit '
          '| load avg |')
    print('|---|---|---|---|---|---|---|---|')
    with tempfile.TemporaryDirectory() as work:
        for name in args.cases.split(','):
            for k in range(1, args.runs + 1):
                for clock in args.clocks.split(','):      # interleaved: both clocks see the same load
                    row = run_case(*CASES[name], clock, work)
                    simulated, factor = row['streaming'] or (float('nan'), float('nan'))
                    pick = '—' if row['pick_log'] is None else '%.2f' % row['pick_log']
                    print('| %s | %s | %d | %.1f | %.2f | %s | %d | %.1f |' % (
                        name, clock, k, simulated, factor, pick, row['status'], row['load']), flush=True)
    return 0
