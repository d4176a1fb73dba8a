"""``make demo``: the whole system headless: a private rosmaster, the fake Baxter on the default scene,
and ``pick_square.py`` picking the green square and placing it elsewhere on the table.

Prints the application's log and its result, and leaves in ``OUT`` (default ``out/demo``):
``result.json``, ``final_view.png`` (the last annotated hand-camera view), ``errors.png`` (error vs
step), and the two processes' logs.
"""
import argparse
import json
import os
import sys

from baxter_pnp.runtime import command_summary
from baxter_pnp.sim.launcher import FakeBaxterProcess, RosMaster, run_script


def main(argv=None):
    parser = argparse.ArgumentParser(prog='demo.py', description=command_summary(__doc__))
    parser.add_argument('--out', default='out/demo')
    parser.add_argument('--mode', default='pbvs', choices=['pbvs', 'ibvs', 'hybrid'])
    parser.add_argument('--place', default='0.62,0.12', help='X,Y (m, base) to put the block down; "" = pick only')
    parser.add_argument('--real-time-factor', default='0', help='of the fake Baxter (0 = as fast as possible)')
    args = parser.parse_args(argv)
    out = os.path.abspath(args.out)
    os.makedirs(out, exist_ok=True)
    with RosMaster(log_dir=out) as master:
        print('demo: rosmaster on %s' % master.uri)
        with FakeBaxterProcess(master, ['--real-time-factor', args.real_time_factor],
                               log_path=os.path.join(out, 'fake_baxter.log')):
            print('demo: fake Baxter ready (log: %s)' % os.path.join(out, 'fake_baxter.log'))
            pick_args = ['--mode', args.mode, '--output-dir', out]
            if args.place:
                pick_args += ['--place', args.place]
            log_path = os.path.join(out, 'pick_square.log')
            run = run_script(master, 'pick_square.py', pick_args, timeout=300, log_path=log_path)
    with open(log_path) as log:      # the node's own log lines, not rospy's internal logging
        sys.stdout.writelines(line for line in log if line.startswith(('[INFO]', '[WARN]', '[ERROR]', 'Traceback')))
    result_path = os.path.join(out, 'result.json')
    if os.path.exists(result_path):
        with open(result_path) as f:
            result = json.load(f)
        result.pop('history', None)
        print('demo: result %s' % json.dumps(result))
    print('demo: outputs in %s (final_view.png, errors.png, result.json, logs)' % out)
    return run.returncode if not run.timed_out else 1
