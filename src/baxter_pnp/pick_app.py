"""``pick_square.py``: Baxter looks, finds the block, servos to it, picks it up (and places it).

The pick task's cycles on the task layer (``baxter_pnp.task``: session, motion, eye, the pick's steps in
``task.picker``, outputs); its geometry and laws are the pure ``pick`` core. Only the Baxter SDK's topics and
services, so the same run works on a real robot and on the fake Baxter:

1. connect (enable, calibrate and open the gripper, open the hand camera, hand-eye from tf or the URDF), move to
   the start pose;
2. approach the hover pose above the block with the chosen law: ``pbvs`` (the thesis's dynamic look-and-move,
   IK service + position moves), ``ibvs`` or ``hybrid`` (2.5D) (camera twist -> joint velocities through the
   arm Jacobian, at the camera rate);
3. descend, close, verify with the gripper state and a look, lift; optionally place at ``place_xy``.

One log line per servo step and per arm command. Exit status 0 only on a verified pick (and place).
"""
import argparse
import os
import time

import numpy as np
import rospy

from baxter_pnp import pick, vision
from baxter_pnp.params import ParameterError
from baxter_pnp.runtime import PACKAGE_ROOT, command_summary
from baxter_pnp.task import cli
from baxter_pnp.task.eye import BlockQuery, Eye
from baxter_pnp.task.motion import Motion
from baxter_pnp.task.outputs import Outputs
from baxter_pnp.task.picker import Picker
from baxter_pnp.task.session import FATAL_REASONS, RobotSession, TaskFailure, failure_reason
from baxter_pnp.task.survey import Survey

DEFAULT_CONFIG = os.path.join(PACKAGE_ROOT, 'config', 'pick_square.yaml')


class PickApplication(Picker):
    """A pick (and place) run of ``session_config.cycles`` cycles: ``config`` a ``pick.PickConfig``,
    ``session_config`` a ``task.settings.SessionConfig``. Construct after ``rospy.init_node``; ``run()`` returns
    the cycles' PickResults."""

    def __init__(self, config, session_config, vision_config, output_dir=None, result_json=None):
        session = RobotSession(session_config, log_name='pick')
        motion = Motion(session)
        self.outputs = Outputs(output_dir, result_json, session_config.cycles, config.mode)
        eye = Eye(session, vision_config,
                  BlockQuery(config.shape, config.colour, config.side_length, config.block_height, config.estimator,
                             session.table, config.edge_radius),
                  views_dir=self.outputs.views_dir if session_config.save_views else None)
        survey = Survey(session, motion, eye, session_config.table_area) if config.survey else None
        super().__init__(session, motion, eye, config, survey)
        self.results = []

    # ================================================================================ the run
    def run(self):
        """``cycles`` pick (and place) cycles. Never raises for robot faults: each cycle ends in its result's
        ``failure_reason``; a failed cycle is followed by the next unless the robot itself is gone
        (``FATAL_REASONS``). Returns the cycles' PickResults."""
        session, cycles = self.session, self.session.config.cycles
        for cycle in range(1, cycles + 1):
            self.result = pick.PickResult(success=False, mode=self.config.mode)
            self.T_base_last_block = self.approach = None
            self.surveyed = False
            session.clock = None
            try:
                if not session.connected:
                    session.connect()
                if cycles > 1:
                    rospy.loginfo('pick: cycle %d of %d' % (cycle, cycles))
                session.open_gripper()
                self.motion.move_to_joints(session.start_pose(self.config.start_pose),
                                           'start pose %s' % self.config.start_pose)
                if cycle > 1:
                    self.wait_for_next_block()
                session.start_clock()           # a cycle's times count from its block being there
                session.run_resuming(self.pick, on_resume=self.forget_block)
                if self.config.place_xy is not None:
                    self.place()
                self.result.success = True
            except Exception as error:      # noqa: BLE001 - a task or robot failure ends the cycle; others raise
                if failure_reason(error) is None:
                    raise
                self.fail(failure_reason(error), str(error))
            finally:
                self.result.total_time_s = session.elapsed()
                self.results.append(self.result)
                self.finish()
            if not session.connected or self.result.failure_reason in FATAL_REASONS:
                break
        self.outputs.run_done(self.results)
        return self.results

    def forget_block(self):
        self.T_base_last_block = None

    def wait_for_next_block(self):
        """Between cycles: look from the start pose until a block to pick (not one already placed) is in view,
        for at most ``next_block_timeout`` s of robot time."""
        c, timeout = self.config, self.session.config.next_block_timeout
        rospy.loginfo('pick: waiting up to %.0f s for a %s %s to pick' % (timeout, c.colour, c.shape))
        deadline = rospy.get_time() + timeout
        while rospy.get_time() < deadline:
            if self.look(after_stamp=rospy.get_time()).target is not None:
                return
        raise TaskFailure('no_block', 'no %s %s to pick appeared within %.0f s' % (c.colour, c.shape, timeout))

    def place(self):
        """Carry the block to ``place_xy``, put it down on the table, retreat, look where it went."""
        c = self.config
        rospy.loginfo('pick: placing the block at (%.3f, %.3f) m' % tuple(c.place_xy))
        self.put_down(c.place_xy, self.session.table.z_at(c.place_xy))
        self.result.placed = True
        look = self.look(after_stamp=rospy.get_time(), placed_too=True)
        if look.target is None:
            rospy.logwarn('pick: the look after placing does not find the block')
            return
        self.result.place_error_mm_est = 1000 * float(np.linalg.norm(look.T_base_block[:2, 3] - np.asarray(c.place_xy)))
        rospy.loginfo('pick: block placed %.1f mm from the requested position (estimated by a look)'
                      % self.result.place_error_mm_est)

    # ================================================================================ ending
    def fail(self, reason, detail):
        """Abort cleanly: log, then ``Motion.retreat`` (gripper opened unless it holds something, arm up)."""
        self.result.success = False
        self.result.failure_reason = reason
        rospy.logerr('pick: FAILED (%s): %s' % (reason, detail))
        self.motion.retreat(reason)

    def finish(self):
        r = self.result
        (rospy.loginfo if r.success else rospy.logerr)(
            'pick: %s in %.1f s (%d steps, mode %s, final estimated error %s mm%s)'
            % ('SUCCESS' if r.success else 'FAILURE', r.time_s, r.steps, r.mode,
               'n/a' if r.final_error_mm_est is None else '%.1f' % r.final_error_mm_est,
               '' if r.success else ', reason: %s' % r.failure_reason))
        self.outputs.cycle_done(self.results, self.eye.last_annotated)


# ==================================================================================== entry point
def parse_args(argv):
    parser = argparse.ArgumentParser(prog='pick_square.py', description=command_summary(__doc__))
    parser.add_argument('--mode', choices=pick.MODES)
    parser.add_argument('--shape', help='target shape (triangle, square, pentagon, hexagon)')
    parser.add_argument('--side-length', type=float, help='block side (m)')
    parser.add_argument('--colour', '--color', dest='colour', help='block colour (a name in config/vision.yaml)')
    parser.add_argument('--step-fraction', type=float, help='PBVS step fraction (thesis: 0.35 or 0.12)')
    parser.add_argument('--start-pose', help='start pose name in config/start_poses.yaml (down, angled)')
    parser.add_argument('--estimator', choices=['sqp', 'ippe', 'sqpnp'])
    parser.add_argument('--place', metavar='X,Y', help='place the block at this table position (base, m)')
    parser.add_argument('--no-survey', dest='survey', action='store_false', default=None,
                        help="never survey the table: a block not in view is searched for as the thesis did")
    cli.add_session_arguments(parser, DEFAULT_CONFIG, cycles=True)
    return parser.parse_args(argv)


TASK_KEYS = ('mode', 'shape', 'side_length', 'colour', 'step_fraction', 'start_pose', 'estimator', 'survey')


def build_config(args, private_params=None):
    """(PickConfig, SessionConfig): defaults <- the YAML <- ``private_params`` (the ``~name`` ROS parameters,
    read from the parameter server when None) <- the command line; ParameterError names the bad key."""
    extra = {}
    if args.place:
        try:
            extra['place_xy'] = [float(v) for v in args.place.split(',')]
        except ValueError:
            raise ParameterError('--place', 'expected X,Y in metres, got %r' % args.place) from None
    config, session_config = cli.read_configs(pick.PickConfig, args, TASK_KEYS, extra, private_params)
    if config.block_height - config.grasp_depth < session_config.tip_margin:
        raise ParameterError('grasp_depth', 'leaves the gripper tip closer to the table than tip_margin (got %r)'
                             % config.grasp_depth)
    return config, session_config


def build_run(args):
    """(PickConfig, SessionConfig, VisionConfig) of the command line ``args``; ParameterError names a bad key."""
    config, session_config = build_config(args)
    vision_config = vision.VisionConfig.from_yaml(args.vision_config)
    if config.colour not in vision_config.colour_names():
        raise ParameterError('colour', '%r is not in the vision configuration (known: %s)'
                             % (config.colour, ', '.join(vision_config.colour_names())))
    return config, session_config, vision_config


def main(argv=None):
    args, configs = cli.start('pick_square', argv, parse_args, build_run)
    if configs is None:
        return 2
    config, session_config, vision_config = configs
    application = PickApplication(config, session_config, vision_config, args.output_dir, args.result_json)
    started = time.monotonic()
    results = application.run()
    successes = sum(r.success for r in results)
    rospy.loginfo('pick_square: wall time %.1f s' % (time.monotonic() - started))
    if session_config.cycles > 1:
        rospy.loginfo('pick_square: %d of %d cycles succeeded' % (successes, session_config.cycles))
    return 0 if successes == len(results) == session_config.cycles else 1
