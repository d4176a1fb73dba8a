"""The pick's steps on the task layer, shared by every task that picks a block up: find the block (re-centre,
re-acquire, survey), approach its hover pose with a servo law (``pbvs``: look-and-move through the IK service;
``ibvs`` / ``hybrid``: camera twist -> joint velocities), descend, close, verify the grip (gripper state, then a
look), and put a held block down at a table position. The laws and the geometry are the pure ``pick`` core.

Frames: ``T_base_gripper`` (the ``<side>_gripper`` tip), ``T_base_camera``, ``T_base_block`` (docs/ARCHITECTURE.md's
block frame), ``T_gripper_block`` (the held block in the hand); 4x4, metres. ROS edge.
"""
import dataclasses

import numpy as np
import rospy

from baxter_pnp import pick, robot, servo
from baxter_pnp.task import target
from baxter_pnp.task.session import TaskFailure
from baxter_pnp.transforms import invert, pose_error

GRASP_FLOOR_CLEARANCE = 0.001    # m above the table + tip_margin a grasp is raised to (the arm's IK lands within it)
# the log's note on a pose taken on the table (perception.ON_THE_TABLE_METHODS)
_ON_THE_TABLE = {'on_table': ' (posed by its top face on the table)',
                 'silhouette': ' (posed by its silhouette on the table)'}


class Picker:
    """Picks one block at a time with a connected ``RobotSession``, its ``Motion`` and ``Eye``: ``config`` a
    ``pick.PickConfig`` (what to pick and how), ``survey`` a ``task.survey.Survey`` to search the table with when
    the block is not in view (None: never). ``result`` (a ``pick.PickResult``) records the current pick."""

    def __init__(self, session, motion, eye, config, survey=None):
        self.session, self.motion, self.eye = session, motion, eye
        self.config = config
        self.rules = target.TargetRules.of(config, session.table)
        self.survey = survey
        self.surveyed = False           # this pick's survey was made
        self.result = pick.PickResult(success=False, mode=config.mode)
        self.T_base_last_block = None   # the block's last believed pose (tracking, search)
        self.approach = None            # pick.Approach of the current approach
        self.T_gripper_block = None     # the held block in the gripper frame
        self.stay_on_block = False      # True: only the block within TRACK_RADIUS of the last believed pose is
                                        # the target (a table with several alike blocks); False: else the
                                        # largest / most central

    def retarget(self, shape, colour, T_base_block=None):
        """The next pick is of a ``shape`` ``colour`` block believed at ``T_base_block`` (4x4 in base, e.g. from a
        table map; None: not known); a fresh ``result``."""
        self.config = dataclasses.replace(self.config, shape=shape, colour=colour)
        self.rules = target.TargetRules.of(self.config, self.session.table)
        self.result = pick.PickResult(success=False, mode=self.config.mode)
        self.T_base_last_block, self.approach, self.surveyed = T_base_block, None, False

    def pick(self):
        """Approach the block with the mode's law, grasp and verify, up to ``max_grasp_attempts`` times; the block
        held (``T_gripper_block``) or TaskFailure('grasp_missed')."""
        c = self.config
        for attempt in range(1, c.max_grasp_attempts + 1):
            self.result.grasp_attempts = attempt
            look = self.approach_pbvs() if c.mode == 'pbvs' else self.approach_velocity()
            if target.grasp_height_suspect(look.target.pose, look.T_base_camera, self.rules):
                self.warn_off_height(look.target, look.T_base_camera, 'the grasp goes by the estimate')
            if self.grasp(look.T_base_block):
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
        rules = self.rules

        def near_last(observation, T_base_camera):
            return observation.pose is not None and np.linalg.norm(
                (T_base_camera @ observation.pose.T_camera_object)[:3, 3] - self.T_base_last_block[:3, 3]
            ) < target.TRACK_RADIUS

        def choose(observations, T_base_camera, camera):
            wanted = [o for o in observations if (o.detection.shape, o.detection.colour) == (rules.shape, rules.colour)]
            if self.stay_on_block and self.T_base_last_block is not None:
                wanted = [o for o in wanted if near_last(o, T_base_camera)]
            return target.choose_target(wanted, T_base_camera, rules, (camera.width, camera.height),
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
            if look.target is None:
                self.warn_rejected_for_height(look.observations, look.T_base_camera, 'in view')
            if look.target is not None:
                rospy.logwarn('pick: block cut by the image border: re-centring on it')
                T_next = target.recentred(look.T_base_gripper, look.T_base_camera, look.T_base_block,
                                          c.backoff_height / 2)
            elif self.survey is not None and not self.surveyed and (self.T_base_last_block is None
                                                                    or lost == c.max_lost):
                T_seen_from = self.survey_for_block(look)
                T_view = self.view_of_last_block(look)
                if self.reachable(T_view):
                    self.motion.move_to_pose(T_view, 'view the block the survey found')
                else:                   # far out: back where the survey saw it (visited, so reachable)
                    self.motion.move_to_pose(T_seen_from, 'view the block from the survey view that saw it (the '
                                                          'view over it is out of reach)')
                return self.look_for_block(rospy.get_time())
            else:
                if lost == c.max_lost:
                    break
                T_next = self.search_pose(look, lost)
            self.motion.move_to_pose(T_next, 're-acquire')
            after_stamp = rospy.get_time()
        raise TaskFailure('block_lost', 'no whole %s %s in view after %d re-acquisition moves%s'
                          % (c.colour, c.shape, c.max_lost, ' and a survey' if self.surveyed else ''))

    def warn_rejected_for_height(self, observations, T_base_camera, where):
        """``warn_off_height`` for each of ``observations`` that only its height keeps from being the target."""
        for o in target.rejected_for_height(observations, T_base_camera, self.rules):
            self.warn_off_height(o, T_base_camera, '%s, not believed: tolerance %.0f mm'
                                 % (where, 1000 * target.height_tolerance(o.pose, T_base_camera, self.rules)))

    def warn_off_height(self, observation, T_base_camera, why):
        """Log that ``observation``'s estimate is off its height on the table (``why``), with the side length that
        would put it there: a ``side_length`` unlike the real block's moves every estimate along its ray by the
        ratio of the two."""
        rules = self.rules
        error = target.height_error(observation.pose, T_base_camera, rules)
        side = target.implied_side_length(observation.pose, T_base_camera, rules)
        rospy.logwarn('pick: the %s %s is estimated %.1f mm %s its height on the table (%s); at %.1f mm a side it '
                      'would lie on it: is side_length (%.1f mm) the blocks\' size?'
                      % (rules.colour, rules.shape, 1000 * abs(error), 'above' if error > 0 else 'below', why,
                         1000 * (side or float('nan')), 1000 * rules.side_length))

    def survey_for_block(self, look):
        """Survey the table (``task.survey``) and take the nearest block of the target's shape and colour (not
        one already placed) as the last-seen block; TaskFailure('block_lost') when the table has none. Returns the
        gripper pose (4x4, base) of the survey view nearest the block among those that saw it."""
        c = self.config
        rospy.logwarn('pick: the %s %s is not in view: surveying the table' % (c.colour, c.shape))
        self.surveyed = True
        def believed(observation, T_base_camera):
            self.warn_rejected_for_height([observation], T_base_camera, 'seen by the survey')
            return target.believable(observation, T_base_camera, self.rules)
        found = self.survey.run(believed, look.frame.camera)
        block = found.nearest(look.T_base_gripper[:2, 3], c.shape, c.colour)
        if block is None:
            raise TaskFailure('block_lost', 'no %s %s on the table (survey of %d views, %d other block(s) seen)'
                              % (c.colour, c.shape, len(self.survey.viewpoints(look.frame.camera)), len(found)))
        rospy.loginfo('pick: the survey found the %s %s at %s mm' % (c.colour, c.shape,
                                                                     np.round(1000 * block.position, 1).tolist()))
        self.T_base_last_block = block.T_base_block
        seen_from = [self.survey.view_poses[view] for view in block.view_ids if view in self.survey.view_poses]
        return min(seen_from, key=lambda T: np.linalg.norm(T[:2, 3] - block.position[:2]))

    def view_of_last_block(self, look):
        """The velocity laws' view pose over the last-seen block (``pick.view_pose``), None if none was seen."""
        if self.T_base_last_block is None:
            return None
        T_reference = look.T_base_gripper if self.approach is None else self.approach.T_reference
        return self.view_pose_of(self.T_base_last_block, T_reference, look.frame.camera)

    def view_pose_of(self, T_base_block, T_reference, camera):
        """``pick.view_pose`` of a block at ``T_base_block``: ``camera`` (a ``CameraModel``) sees it low in the image
        ``view_depth`` away, the gripper in the grasp orientation nearest ``T_reference``'s."""
        c = self.config
        return pick.view_pose(T_base_block, pick.hover_pose(T_base_block, c, T_reference),
                              self.session.hand_eye.T_gripper_camera, camera, c)

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
        depth, std = look.target.pose.depth_m, look.target.pose.position_std_m
        block_in_gripper = (invert(look.T_base_gripper) @ look.T_base_block)[:3, 3]
        self.result.history.append(pick.StepRecord(step, self.session.elapsed(), 1000 * translation,
                                                   np.degrees(rotation), error_px, depth,
                                                   np.round(look.T_base_block[:3, 3], 5).tolist(),
                                                   np.round(1000 * block_in_gripper, 2).tolist(),
                                                   None if std is None else round(1000 * std, 2),
                                                   look.target.pose.method))
        self.result.steps = step
        self.result.final_error_mm_est = 1000 * translation
        rospy.loginfo('pick [%s] step %d: error %.1f mm, %.1f deg, %.1f px; block depth %.1f mm, at %s mm in base%s%s'
                      % (self.config.mode, step, 1000 * translation, np.degrees(rotation), error_px, 1000 * depth,
                         np.round(1000 * look.T_base_block[:3, 3], 1).tolist(),
                         '' if std is None else ' (+- %.1f mm)' % (1000 * std),
                         ' (not believably in view: its last estimate)' if look.predicted else
                         _ON_THE_TABLE.get(look.target.pose.method, '')))
        return translation, rotation

    def approach_pbvs(self):
        """The thesis's dynamic look-and-move, fixed: yaw aligned, block kept in view, plane prior, undistorted,
        toward the block's steady position over the last looks (``steadied``). Returns the look at the hover pose."""
        c, T_gripper_camera = self.config, self.session.hand_eye.T_gripper_camera
        look = self.look_for_block()
        approach = self.approach = self.plan_approach(look)
        seen = []                           # (position in base, std) of the looks that saw the block
        for step in range(c.max_steps + 1):
            look = steadied(look, seen)
            T_goal = pick.hover_pose(look.T_base_block, c, approach.T_reference)
            self.record(step, look, T_goal, pick.image_error_px(look.frame.camera, look.target.pose.T_camera_object,
                                                                T_goal, look.T_base_block, T_gripper_camera))
            if pick.converged(look.T_base_gripper, T_goal, c):
                return look
            T_next, T_toward = pick.pbvs_target(look.T_base_gripper, T_goal, look.T_base_block, c, look.frame.camera,
                                                T_gripper_camera, self.eye.hand_clearance(look.frame.camera),
                                                approach.view_depth, look.target.pose.position_std_m,
                                                self.reachable)
            if T_toward is T_goal:
                why = ''
            elif T_next is T_toward:
                why = ' (straight to the view pose: no step toward it keeps the block in view)'
            else:
                why = ' (via the view pose: a straight path would pass the block behind a finger)'
            self.motion.move_to_pose(T_next, 'servo step %d%s' % (step + 1, why))
            look = self.look_for_block(after_stamp=rospy.get_time())
        raise TaskFailure('not_converged', 'still %.1f mm from the hover pose after %d steps'
                          % (self.result.final_error_mm_est, c.max_steps))

    def approach_velocity(self):
        """IBVS or 2.5D at the camera rate: camera twist -> joint velocities (arm Jacobian from the URDF).

        A stall (the feature error not down by ``stall_progress`` within ``stall_time`` s of robot time: the arm
        crawling along a joint limit or a finger's edge) is followed by a position move (``move_after_stall``),
        then the velocity law resumes. Looks without the block believably in view are bridged by its last estimate
        (``look_for_velocity_loop``); the view and hover poses are reached only on a look that sees it. Returns the
        look at the hover pose."""
        c, session = self.config, self.session
        T_gripper_camera, kinematics, limb = session.hand_eye.T_gripper_camera, session.kinematics, session.limb
        gain = pick.make_gain(c)
        camera_frame = '%s_hand_camera' % session.config.side
        velocity_limits = session.config.speed_ratio * kinematics.velocity_limits * 2.0
        look = self.look_for_block()
        approach = self.approach = self.plan_approach(look)
        at_view = False         # first goal: the view pose (block low in the image); then the hover pose
        stall = pick.StallWatch(c.stall_time, c.stall_progress)
        predicted = 0           # looks in a row whose target is the last estimate carried over
        for iteration in range(10 * c.max_steps + 1):
            camera = look.frame.camera
            T_hover = pick.hover_pose(look.T_base_block, c, approach.T_reference)
            T_goal = T_hover if at_view else pick.view_pose(look.T_base_block, T_hover, T_gripper_camera, camera, c,
                                                            approach.view_depth)
            T_camera_goal_block = pick.camera_goal(T_goal, look.T_base_block, T_gripper_camera)
            vertices_xy = camera.undistort_points(look.target.detection.vertices_px)
            twist, error = pick.servo_twist(c.mode, look.target.pose.T_camera_object, T_camera_goal_block,
                                            vertices_xy, c.seen_model, gain)
            translation, rotation = self.record(iteration, look, T_hover, error * camera.fx)
            seen = not look.predicted
            if seen and not at_view and error * camera.fx <= c.view_tolerance_px:
                rospy.loginfo('pick [%s]: view reached (%.1f px): now up between the fingers to the hover pose'
                              % (c.mode, error * camera.fx))
                at_view = True
                continue
            if (seen and at_view and error * camera.fx <= c.feature_tolerance_px
                    and translation <= 2 * c.position_tolerance):
                limb.exit_control_mode()
                return look
            if stall.stalled(rospy.get_time(), error * camera.fx, at_view):
                look = self.move_after_stall(look, T_goal, at_view, approach, stall)
                approach, predicted = self.approach, 0
                continue
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
                look = self.look_for_velocity_loop(look, predicted)
                predicted = predicted + 1 if look.predicted else 0
            except TaskFailure:
                limb.exit_control_mode()
                raise
        limb.exit_control_mode()
        raise TaskFailure('not_converged', 'feature error still %.1f px after %d iterations'
                          % (error * camera.fx, 10 * c.max_steps))

    def move_after_stall(self, look, T_goal, at_view, approach, stall):
        """After a stall of the velocity law: a position move straight to the view pose ``T_goal`` (before it is
        reached), else one PBVS step toward ``T_goal`` (``pick.pbvs_target``, the block kept in view), the first
        with an IK solution from the current angles. Before the view pose is reached and with neither in reach (a
        far block's view pose at the edge of the arm's reach, the estimate having moved since the plan), the
        approach is planned again from this look (``self.approach``) and the arm goes to its view pose; nothing in
        reach: the law goes on. Returns the next look."""
        c = self.config
        self.session.limb.exit_control_mode()
        camera, T_gripper_camera = look.frame.camera, self.session.hand_eye.T_gripper_camera
        T_step, _ = pick.pbvs_target(look.T_base_gripper, T_goal, look.T_base_block, c, camera, T_gripper_camera,
                                     self.eye.hand_clearance(camera), approach.view_depth)
        moves = ([] if at_view else [('the view pose', T_goal)]) + [('one PBVS step', T_step)]
        reachable = [(what, T) for what, T in moves if self.reachable(T)]
        if not reachable and not at_view:
            replanned = self.plan_approach(look)
            if replanned.rank >= 0:
                self.approach = replanned
                T_hover = pick.hover_pose(look.T_base_block, c, replanned.T_reference)
                reachable = [('the view pose of the approach planned again',
                              pick.view_pose(look.T_base_block, T_hover, T_gripper_camera, camera, c,
                                             replanned.view_depth))]
        rospy.logwarn('pick [%s]: the feature error has not fallen by %.0f %% in %.1f s (stall %d): %s'
                      % (c.mode, 100 * c.stall_progress, c.stall_time, stall.count,
                         reachable[0][0] if reachable else 'no reachable move, the velocity law goes on'))
        if reachable:
            self.motion.move_to_pose(reachable[0][1], 'after a stall: %s' % reachable[0][0])
        stall.reset()
        return self.look_for_block(after_stamp=rospy.get_time())

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

    def look_for_velocity_loop(self, previous, predicted):
        """The velocity loop's look after ``previous`` (a look with a target), ``predicted`` looks in a row having
        carried the last estimate over. A look without the block believably in view (a shadow or a glare over it,
        a frame or two) carries it over again (``target.predicted_target``; ``Look.predicted``), up to
        ``max_predicted_looks`` in a row: the block lies still, the arm's pose comes from its joint angles. Then,
        or on a block cut by the image border, the arm stops and re-acquires."""
        self.session.check_deadline()
        look = self.look(previous.frame.stamp)
        if look.target is not None and not look.target.detection.touches_border:
            self.T_base_last_block = look.T_base_block
            return look
        if look.target is None and predicted < self.config.max_predicted_looks:
            carried = target.predicted_target(previous.target, self.T_base_last_block, look.T_base_camera,
                                              look.frame.camera, self.config.seen_model)
            return look._replace(target=carried, T_base_block=self.T_base_last_block, predicted=True)
        self.session.limb.exit_control_mode()
        return self.look_for_block(after_stamp=rospy.get_time())

    # ================================================================================ grasp and place
    def grasp(self, T_base_block):
        """Descend, close, verify (gripper state, then lift and look). True on a verified grasp."""
        c, gripper, limb = self.config, self.session.gripper, self.session.limb
        floor_z = (self.session.table.z_at(T_base_block[:2, 3]) + self.session.config.tip_margin
                   + GRASP_FLOOR_CLEARANCE)
        T_grasp = pick.grasp_pose(T_base_block, c, limb.endpoint_pose(), floor_z)
        if T_grasp[2, 3] == floor_z:
            rospy.loginfo('pick: the block is estimated lower than grasp_depth allows: the grasp raised to %.1f mm '
                          'above the table (tip_margin + %.0f mm)'
                          % (1000.0 * (self.session.config.tip_margin + GRASP_FLOOR_CLEARANCE),
                             1000.0 * GRASP_FLOOR_CLEARANCE))
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

    def put_down(self, xy, support_z, what='the block'):
        """Carry the held block ``lift_height`` above ``support_z`` (m in base: what it will stand on, the table top
        or a block's top face) to ``xy`` (m in base), lower it to ``place_clearance`` above, open, and rise
        ``lift_height`` (lift before lateral moves: nothing on the table is swept)."""
        c, limb = self.config, self.session.limb
        self.motion.move_to_pose(pick.place_pose(limb.endpoint_pose(), self.T_gripper_block, xy, c, support_z,
                                                 c.lift_height), 'carry %s over (%.3f, %.3f) m' % (what, *xy))
        self.motion.move_to_pose(pick.place_pose(limb.endpoint_pose(), self.T_gripper_block, xy, c, support_z,
                                                 c.place_clearance), 'lower %s' % what)
        if not self.session.gripper.open(block=True, timeout=3.0):
            raise TaskFailure('gripper', 'the gripper did not open to release %s' % what)
        self.T_gripper_block = None
        self.motion.move_up(c.lift_height, 'retreat')


def steadied(look, seen):
    """``look`` with its block at ``target.steady_position`` of the looks that saw it (``seen``, this one appended;
    its orientation this look's); a look that did not see the block (predicted) as it is."""
    if look.predicted:
        return look
    seen.append((look.T_base_block[:3, 3].copy(), look.target.pose.position_std_m))
    T_base_block = look.T_base_block.copy()
    T_base_block[:3, 3] = target.steady_position(seen)
    return look._replace(T_base_block=T_base_block)
