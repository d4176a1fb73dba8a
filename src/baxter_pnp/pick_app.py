"""``pick_square.py``: Baxter looks, finds the block, servos to it, picks it up (and places it).

The pick task's sequence on the task layer (``baxter_pnp.task``: session, motion, eye, target choice, outputs);
its geometry and laws are the pure ``pick`` core. Only the Baxter SDK's topics and services, so the same run
works on a real robot and on the fake Baxter:

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

from baxter_pnp import pick, robot, servo, vision
from baxter_pnp.params import ParameterError
from baxter_pnp.runtime import PACKAGE_ROOT
from baxter_pnp.task import cli, target
from baxter_pnp.task.eye import BlockQuery, Eye
from baxter_pnp.task.motion import Motion
from baxter_pnp.task.outputs import Outputs
from baxter_pnp.task.session import FATAL_REASONS, RobotSession, TaskFailure, failure_reason
from baxter_pnp.task.survey import Survey
from baxter_pnp.transforms import invert, pose_error

DEFAULT_CONFIG = os.path.join(PACKAGE_ROOT, 'config', 'pick_square.yaml')


class PickApplication:
    """A pick (and place) run of ``session_config.cycles`` cycles: ``config`` a ``pick.PickConfig``,
    ``session_config`` a ``task.settings.SessionConfig``. Construct after ``rospy.init_node``; ``run()`` returns
    the cycles' PickResults."""

    def __init__(self, config, session_config, vision_config, output_dir=None, result_json=None):
        self.config = config
        self.session = RobotSession(session_config, log_name='pick')
        self.motion = Motion(self.session)
        self.outputs = Outputs(output_dir, result_json, session_config.cycles, config.mode)
        self.eye = Eye(self.session, vision_config,
                       BlockQuery(config.shape, config.colour, config.side_length, config.block_height,
                                  config.estimator, self.session.table),
                       views_dir=self.outputs.views_dir if session_config.save_views else None)
        self.rules = target.TargetRules.of(config, self.session.table)
        self.survey = Survey(self.session, self.motion, self.eye, session_config.table_area) if config.survey else None
        self.surveyed = False           # this cycle's survey was made
        self.result = pick.PickResult(success=False, mode=config.mode)
        self.results = []
        self.T_base_last_block = None   # the block's last believed pose (tracking, search)
        self.approach = None            # pick.Approach of the current approach
        self.T_gripper_block = None     # the held block in the gripper frame

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

    def pick(self):
        c = self.config
        for attempt in range(1, c.max_grasp_attempts + 1):
            self.result.grasp_attempts = attempt
            T_base_block = self.approach_pbvs() if c.mode == 'pbvs' else self.approach_velocity()
            if self.grasp(T_base_block):
                self.result.time_s = self.session.elapsed()
                rospy.loginfo('pick: block picked after %.1f s (%d steps, attempt %d)'
                              % (self.result.time_s, self.result.steps, attempt))
                return
            rospy.logwarn('pick: grasp attempt %d missed; opening and trying again' % attempt)
            self.session.gripper.open(block=True, timeout=3.0)
            self.motion.move_up(c.hover_height + c.grasp_depth, 'back up')
        raise TaskFailure('grasp_missed', 'no grip after %d attempts' % c.max_grasp_attempts)

    # ================================================================================ looking
    def look(self, after_stamp=None, on_table=True, placed_too=False):
        """A look for the block (``task.target.choose_target``: believable estimates only; ``on_table`` checks
        the height; unless ``placed_too``, blocks at ``place_xy`` are not targets)."""
        def choose(observations, T_base_camera, camera):
            return target.choose_target(observations, T_base_camera, self.rules, (camera.width, camera.height),
                                        self.T_base_last_block, on_table, placed_too)
        return self.eye.look(after_stamp, choose)

    def look_for_block(self, after_stamp=None):
        """A look that finds the block whole: re-centres on a block cut by the image border and, when it is
        lost, looks from above where it was last seen, or higher (up to ``max_lost`` times in a row). A block
        never seen, or lost that long, is searched for by a survey of the table (once a cycle, ``survey``)."""
        c = self.config
        for lost in range(c.max_lost + 1):
            self.session.check_deadline()
            look = self.look(after_stamp)
            if look.target is not None and not look.target.detection.touches_border:
                self.T_base_last_block = look.T_base_block
                return look
            if look.target is not None:
                rospy.logwarn('pick: block cut by the image border: re-centring on it')
                T_next = target.recentred(look.T_base_gripper, look.T_base_camera, look.T_base_block,
                                          c.backoff_height / 2)
            elif self.survey is not None and not self.surveyed and (self.T_base_last_block is None
                                                                    or lost == c.max_lost):
                self.survey_for_block(look)
                T_view, _ = target.search_pose(look.T_base_gripper, 0, c.backoff_height, self.view_of_last_block(look),
                                               self.reachable)
                self.motion.move_to_pose(T_view, 'view the block the survey found')
                return self.look_for_block(rospy.get_time())
            else:
                if lost == c.max_lost:
                    break
                T_next = self.search_pose(look, lost)
            self.motion.move_to_pose(T_next, 're-acquire')
            after_stamp = rospy.get_time()
        raise TaskFailure('block_lost', 'no whole %s %s in view after %d re-acquisition moves%s'
                          % (c.colour, c.shape, c.max_lost, ' and a survey' if self.surveyed else ''))

    def survey_for_block(self, look):
        """Survey the table (``task.survey``) and take the nearest block of the target's shape and colour (not
        one already placed) as the last-seen block; TaskFailure('block_lost') when the table has none."""
        c = self.config
        rospy.logwarn('pick: the %s %s is not in view: surveying the table' % (c.colour, c.shape))
        self.surveyed = True
        found = self.survey.run(lambda observation, T_base_camera: target.believable(
            observation, T_base_camera, self.rules), look.frame.camera)
        block = found.nearest(look.T_base_gripper[:2, 3], c.shape, c.colour)
        if block is None:
            raise TaskFailure('block_lost', 'no %s %s on the table (survey of %d views, %d other block(s) seen)'
                              % (c.colour, c.shape, len(self.survey.viewpoints(look.frame.camera)), len(found)))
        rospy.loginfo('pick: the survey found the %s %s at %s mm' % (c.colour, c.shape,
                                                                     np.round(1000 * block.position, 1).tolist()))
        self.T_base_last_block = block.T_base_block

    def view_of_last_block(self, look):
        """The velocity laws' view pose over the last-seen block (``pick.view_pose``), None if none was seen."""
        if self.T_base_last_block is None:
            return None
        c = self.config
        T_reference = look.T_base_gripper if self.approach is None else self.approach.T_reference
        T_hover = pick.hover_pose(self.T_base_last_block, c, T_reference)
        return pick.view_pose(self.T_base_last_block, T_hover, self.session.hand_eye.T_gripper_camera,
                              look.frame.camera, c)

    def reachable(self, T_base_gripper):
        """True if the URDF's IK solves ``T_base_gripper`` from the arm's current angles."""
        session = self.session
        return session.kinematics.ik(T_base_gripper, seed=session.limb.joint_positions()) is not None

    def search_pose(self, look, lost):
        """``task.target.search_pose`` from the view pose of the velocity laws over the last-seen block."""
        c = self.config
        T_next, over_block = target.search_pose(look.T_base_gripper, lost, c.backoff_height,
                                                self.view_of_last_block(look), self.reachable)
        if over_block:
            rospy.logwarn('pick: block not in view (re-acquisition %d of %d): looking from above where it was '
                          'last seen, at %s mm' % (lost + 1, c.max_lost,
                                                   np.round(1000 * self.T_base_last_block[:3, 3], 1).tolist()))
        else:
            rospy.logwarn('pick: block not in view (re-acquisition %d of %d): backing off %.0f mm upward'
                          % (lost + 1, c.max_lost, 1000 * c.backoff_height))
        return T_next

    # ================================================================================ approach laws
    def record(self, step, look, T_goal, error_px):
        translation, rotation = pose_error(look.T_base_gripper, T_goal)
        depth = look.target.pose.depth_m
        block_in_gripper = (invert(look.T_base_gripper) @ look.T_base_block)[:3, 3]
        self.result.history.append(pick.StepRecord(step, self.session.elapsed(), 1000 * translation,
                                                   np.degrees(rotation), error_px, depth,
                                                   np.round(look.T_base_block[:3, 3], 5).tolist(),
                                                   np.round(1000 * block_in_gripper, 2).tolist()))
        self.result.steps = step
        self.result.final_error_mm_est = 1000 * translation
        rospy.loginfo('pick [%s] step %d: error %.1f mm, %.1f deg, %.1f px; block depth %.1f mm, at %s mm in base'
                      % (self.config.mode, step, 1000 * translation, np.degrees(rotation), error_px, 1000 * depth,
                         np.round(1000 * look.T_base_block[:3, 3], 1).tolist()))
        return translation, rotation

    def approach_pbvs(self):
        """The thesis's dynamic look-and-move, fixed: yaw aligned, block kept in view, plane prior, undistorted."""
        c, T_gripper_camera = self.config, self.session.hand_eye.T_gripper_camera
        look = self.look_for_block()
        approach = self.approach = self.plan_approach(look)
        for step in range(c.max_steps + 1):
            T_goal = pick.hover_pose(look.T_base_block, c, approach.T_reference)
            self.record(step, look, T_goal, pick.image_error_px(look.frame.camera, look.target.pose.T_camera_object,
                                                                T_goal, look.T_base_block, T_gripper_camera))
            if pick.converged(look.T_base_gripper, T_goal, c):
                return look.T_base_block
            T_next, T_toward = pick.pbvs_target(look.T_base_gripper, T_goal, look.T_base_block, c, look.frame.camera,
                                                T_gripper_camera, self.eye.hand_clearance(look.frame.camera),
                                                approach.view_depth)
            self.motion.move_to_pose(T_next, 'servo step %d%s' % (step + 1, '' if T_toward is T_goal else
                                                                   ' (via the view pose: a straight path would pass '
                                                                   'the block behind a finger)'))
            look = self.look_for_block(after_stamp=rospy.get_time())
        raise TaskFailure('not_converged', 'still %.1f mm from the hover pose after %d steps'
                          % (self.result.final_error_mm_est, c.max_steps))

    def approach_velocity(self):
        """IBVS or 2.5D at the camera rate: camera twist -> joint velocities (arm Jacobian from the URDF)."""
        c, session = self.config, self.session
        T_gripper_camera, kinematics, limb = session.hand_eye.T_gripper_camera, session.kinematics, session.limb
        gain = pick.make_gain(c)
        camera_frame = '%s_hand_camera' % session.config.side
        velocity_limits = session.config.speed_ratio * kinematics.velocity_limits * 2.0
        look = self.look_for_block()
        approach = self.approach = self.plan_approach(look)
        at_view = False         # first goal: the view pose (block low in the image); then the hover pose
        for iteration in range(10 * c.max_steps + 1):
            camera = look.frame.camera
            T_hover = pick.hover_pose(look.T_base_block, c, approach.T_reference)
            T_goal = T_hover if at_view else pick.view_pose(look.T_base_block, T_hover, T_gripper_camera, camera, c,
                                                            approach.view_depth)
            T_camera_goal_block = pick.camera_goal(T_goal, look.T_base_block, T_gripper_camera)
            vertices_xy = camera.undistort_points(look.target.detection.vertices_px)
            twist, error = pick.servo_twist(c.mode, look.target.pose.T_camera_object, T_camera_goal_block,
                                            vertices_xy, c.model, gain)
            translation, rotation = self.record(iteration, look, T_hover, error * camera.fx)
            if not at_view and error * camera.fx <= c.view_tolerance_px:
                rospy.loginfo('pick [%s]: view reached (%.1f px): now up between the fingers to the hover pose'
                              % (c.mode, error * camera.fx))
                at_view = True
                continue
            if at_view and error * camera.fx <= c.feature_tolerance_px and translation <= 2 * c.position_tolerance:
                limb.exit_control_mode()
                return look.T_base_block
            twist = pick.view_kept_twist(pick.bounded_twist(twist, c.max_linear_speed, c.max_angular_speed),
                                         look.T_base_camera, look.T_base_block, c, camera,
                                         self.eye.hand_clearance(camera))
            twist_base = servo.camera_twist_to_base(twist, look.T_base_camera)
            q = limb.joint_positions()
            qdot = servo.joint_velocities(kinematics.jacobian(q, camera_frame), twist_base,
                                          qdot_limits=velocity_limits, q=q, lower=kinematics.lower,
                                          upper=kinematics.upper, horizon=robot.COMMAND_TIMEOUT)
            limb.set_joint_velocities(qdot)
            try:
                look = self.look_for_velocity_loop(look.frame.stamp)
            except TaskFailure:
                limb.exit_control_mode()
                raise
        limb.exit_control_mode()
        raise TaskFailure('not_converged', 'feature error still %.1f px after %d iterations'
                          % (error * camera.fx, 10 * c.max_steps))

    def plan_approach(self, look):
        """``pick.plan_approach`` from this look, reachability by the URDF's IK from the current angles."""
        c, session = self.config, self.session
        q = session.limb.joint_positions()
        approach = pick.plan_approach(look.T_base_block, look.T_base_gripper, c, look.frame.camera,
                                      session.hand_eye.T_gripper_camera,
                                      lambda T: session.kinematics.ik(T, seed=q) is not None)
        if approach.rank < 0:
            rospy.logwarn('pick [%s]: no grasp orientation with a reachable hover and view pose: trying the nearest'
                          % c.mode)
        else:
            T_hover = pick.hover_pose(look.T_base_block, c, approach.T_reference)
            rospy.loginfo('pick [%s]: approach planned: grasp orientation %d (%.0f deg from the current one), view '
                          'from %.0f mm' % (c.mode, approach.rank + 1,
                                            np.degrees(pose_error(look.T_base_gripper, T_hover)[1]),
                                            1000 * approach.view_depth))
        return approach

    def look_for_velocity_loop(self, after_stamp):
        """Next look of the velocity loop; on a lost or cut block the arm stops and re-acquires first."""
        self.session.check_deadline()
        look = self.look(after_stamp)
        if look.target is not None and not look.target.detection.touches_border:
            self.T_base_last_block = look.T_base_block
            return look
        self.session.limb.exit_control_mode()
        return self.look_for_block(after_stamp=rospy.get_time())

    # ================================================================================ grasp and place
    def grasp(self, T_base_block):
        """Descend, close, verify (gripper state, then lift and look). True on a verified grasp."""
        c, gripper, limb = self.config, self.session.gripper, self.session.limb
        T_grasp = pick.grasp_pose(T_base_block, c, limb.endpoint_pose())
        self.motion.move_to_pose(T_grasp, 'descend to grasp')
        gripper.close(block=True, timeout=3.0)
        if not gripper.gripping() or gripper.missed():
            rospy.logwarn('pick: gripper reports %s (position %.1f %%)'
                          % ('missed' if gripper.missed() else 'no grip', gripper.position()))
            return False
        self.T_gripper_block = invert(T_grasp) @ T_base_block
        self.motion.move_up(c.lift_height, 'lift')
        if not gripper.gripping():
            rospy.logwarn('pick: the block slipped out while lifting')
            return False
        return self.verify_hold(T_base_block)

    def verify_hold(self, T_base_block_before):
        """The look after lifting: the grip is refuted only if the block is seen still lying where it was; a
        block seen in the hand confirms it; anything else (occluded by the fingers, an odd estimate) leaves the
        gripper's word (gripping) standing, with a warning."""
        look = self.look(after_stamp=rospy.get_time(), on_table=False)
        if look.target is None:
            rospy.logwarn('pick: the look after lifting does not see the block (occluded?); gripper reports gripping')
            return True
        table_z = self.session.table.z_at(look.T_base_block[:2, 3])
        if pick.left_behind(look.T_base_block, T_base_block_before, table_z, self.config.block_height):
            rospy.logwarn('pick: a look finds the block still on the table: the gripper holds something else')
            return False
        T_gripper_block_seen = invert(look.T_base_gripper) @ look.T_base_block
        offset = float(np.linalg.norm(T_gripper_block_seen[:3, 3] - self.T_gripper_block[:3, 3]))
        if offset <= pick.HOLD_CONFIRM_DISTANCE:
            self.T_gripper_block = T_gripper_block_seen
            rospy.loginfo('pick: grasp verified by a look (block %.1f mm from the expected place in the hand)'
                          % (1000 * offset))
        else:
            rospy.logwarn('pick: the look after lifting is inconclusive (block estimated %.1f mm from its expected '
                          'place in the hand, at %s mm in base); gripper reports gripping'
                          % (1000 * offset, np.round(1000 * look.T_base_block[:3, 3], 1).tolist()))
        return True

    def place(self):
        """Carry the block to ``place_xy``, lower it to the table, open, retreat, look where it went."""
        c, limb = self.config, self.session.limb
        table_z = self.session.table.z_at(c.place_xy)
        rospy.loginfo('pick: placing the block at (%.3f, %.3f) m' % tuple(c.place_xy))
        self.motion.move_to_pose(pick.place_pose(limb.endpoint_pose(), self.T_gripper_block, c.place_xy, c,
                                                 table_z, c.lift_height), 'carry to the place position')
        self.motion.move_to_pose(pick.place_pose(limb.endpoint_pose(), self.T_gripper_block, c.place_xy, c,
                                                 table_z, c.place_clearance), 'lower to the table')
        if not self.session.gripper.open(block=True, timeout=3.0):
            raise TaskFailure('gripper', 'the gripper did not open to release the block')
        self.motion.move_up(c.lift_height, 'retreat')
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
    parser = argparse.ArgumentParser(prog='pick_square.py', description=__doc__.split('\n')[0].strip('`: '))
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
