"""``make bench-real-time``: the fake Baxter's real-time factor while its hand camera streams 640x400 at 20 fps
and ``pick_square.py`` picks, paced (``--real-time-factor 1``): robot time over wall time between the pick's
first and last log lines (rospy stamps each line with both). README, "Fake Baxter".
"""
import argparse
import os
import re
import tempfile

import yaml

from baxter_pnp.sim.launcher import FakeBaxterProcess, RosMaster, run_script
from baxter_pnp.sim.scene import DEFAULT_SCENE_YAML

STAMPS = re.compile(r'\] \[(\d+\.\d+), (\d+\.\d+)\]: ')
CASES = {'pbvs-clean-down': ('pbvs', 'down', 'clean'), 'hybrid-baxter-angled': ('hybrid', 'angled', 'baxter')}


def factor_of_log(text):
    """(robot s, wall s, robot/wall) between the first and the last stamped log line of a rospy node's log."""
    stamps = [(float(wall), float(robot)) for wall, robot in STAMPS.findall(text) if float(robot) > 0]
    (wall0, robot0), (wall1, robot1) = stamps[0], stamps[-1]
    return robot1 - robot0, wall1 - wall0, (robot1 - robot0) / (wall1 - wall0)


def run_case(mode, start_pose, look, work):
    """One paced pick on a fresh master and fake: (robot s, wall s, factor, pick exit status)."""
    with open(DEFAULT_SCENE_YAML) as f:
        scene = yaml.safe_load(f)
    scene['appearance'] = look
    scene_path = os.path.join(work, 'scene_%s.yaml' % look)
    with open(scene_path, 'w') as f:
        yaml.safe_dump(scene, f)
    log_path = os.path.join(work, 'pick_%s_%s_%s.log' % (mode, start_pose, look))
    with RosMaster(log_dir=os.path.join(work, 'ros_log')) as master:
        with FakeBaxterProcess(master, ['--scene', scene_path, '--real-time-factor', '1'],
                               log_path=os.path.join(work, 'fake.log')):
            run = run_script(master, 'pick_square.py', ['--mode', mode, '--start-pose', start_pose], timeout=300,
                             log_path=log_path)
    with open(log_path) as f:
        return (*factor_of_log(f.read()), run.returncode)


def main(argv=None):
    parser = argparse.ArgumentParser(prog='bench_real_time.py', description=__doc__.split('\n')[0].strip('`: '))
    parser.add_argument('--runs', type=int, default=3, help='runs per case')
    parser.add_argument('--cases', default=','.join(CASES), help='comma-separated of: %s' % ', '.join(CASES))
    args = parser.parse_args(argv)
    print('| case | run | robot s | wall s | real-time factor | pick exit |')
    print('|---|---|---|---|---|---|')
    with tempfile.TemporaryDirectory() as work:
        for name in args.cases.split(','):
            for k in range(1, args.runs + 1):
                robot_s, wall_s, factor, status = run_case(*CASES[name], work)
                print('| %s | %d | %.1f | %.1f | %.2f | %d |' % (name, k, robot_s, wall_s, factor, status), flush=True)
    return 0
