"""``pick_square.py``: Baxter looks, finds the block, servos to it, picks it up (and places it).

The ROS edge of the pick task (``pick.py`` holds the pure logic). It uses only the Baxter SDK's topics
and services (``robot.py``), so the same run works on a real robot and on the fake Baxter:

1. enable the robot, calibrate and open the gripper, open the hand camera, read the hand-eye
   transform from tf (or the URDF), move to the start pose;
2. approach the hover pose above the block with the chosen law: ``pbvs`` (the thesis's dynamic
   look-and-move, IK service + position moves), ``ibvs`` or ``hybrid`` (2.5D) (camera twist ->
   joint velocities through the arm Jacobian, at the camera rate);
3. descend, close, verify with the gripper state and a look, lift; optionally place at ``place_xy``.

Every step is logged (step, error in mm and px, depth estimate). Published for watching:
``/baxter_pnp/debug_image`` (annotated camera view), ``/baxter_pnp/target_pose`` (block pose in
``base``, PoseStamped), tf frame ``block``, and ``/baxter_pnp/result`` (latched JSON). Exit status 0
only on a verified pick (and place, when asked).
"""
import argparse
import json
import os
import time
from typing import NamedTuple, Optional

import numpy as np
import rospy
import yaml
from geometry_msgs.msg import PoseStamped, TransformStamped
from sensor_msgs.msg import Image
from std_msgs.msg import String

from baxter_pnp import perception, pick, robot, servo, vision
from baxter_pnp.camera import CameraModel
from baxter_pnp.kinematics import ArmKinematics, load_start_poses
from baxter_pnp.ros_image import bgr_to_msg
from baxter_pnp.runtime import PACKAGE_ROOT
from baxter_pnp.safety import ArmSafety, UnsafeCommand
from baxter_pnp.transforms import invert, matrix_to_pose_msg, to_xyz_quat

DEFAULT_CONFIG = os.path.join(PACKAGE_ROOT, 'config', 'pick_square.yaml')
SETTLE_TOLERANCE = 0.003        # rad: a position move counts as arrived (and the arm as still) within this
MIN_SETTLE_TOLERANCE = 0.0005   # rad: ... or within a third of a smaller move, but never tighter than this


# Failures after which a multi-cycle run stops: the robot is gone, stopped or broken, not just this pick.
FATAL_REASONS = ('robot_stopped', 'robot_disabled', 'stream_lost', 'service_unavailable', 'robot_error', 'gripper')


class PickFailure(RuntimeError):
    """The run cannot go on; ``reason`` is a short machine-readable cause (result JSON ``failure_reason``)."""

    def __init__(self, reason, detail=''):
        super().__init__('%s: %s' % (reason, detail) if detail else reason)
        self.reason = reason


class Look(NamedTuple):
    """One look through the hand camera and what it found (poses 4x4 in base, metres)."""
    frame: robot.Frame
    T_base_gripper: np.ndarray
    T_base_camera: np.ndarray
    target: Optional[perception.BlockObservation]
    T_base_block: Optional[np.ndarray]


class RobotRestarted(robot.RobotError):
    """The robot came back from a restart (disabled, clock reset): the run can resume after re-enabling."""


class RunClock:
    """Robot time (s) elapsed since the run started, continuous across a robot restart (a restarted fake
    Baxter's simulated clock starts again from zero: the elapsed time carries on from where it was)."""

    def __init__(self):
        self.start = self.last = rospy.get_time()
        self.offset = 0.0
        self._jumps_seen = self.jumps = 0

    def elapsed(self):
        now = rospy.get_time()
        if now < self.last:
            self.offset += self.last - now
            self.jumps += 1
        self.last = now
        return now + self.offset - self.start

    def restarted(self):
        """True once after each time the robot's clock went back (a restart), as seen by ``elapsed``."""
        self.elapsed()
        jumped, self._jumps_seen = self.jumps > self._jumps_seen, self.jumps
        return jumped


class PickApplication:
    """A pick (and place) run of ``config.cycles`` cycles. Construct after ``rospy.init_node``; ``run()``
    returns the cycles' PickResults."""

    def __init__(self, config, vision_config, output_dir=None, result_json=None):
        self.config = config
        self.vision_config = vision_config
        self.output_dir = output_dir
        self.result_json = result_json
        self.model = config.model
        self.result = pick.PickResult(success=False, mode=config.mode)
        self.last_block = None
        self.last_annotated = None
        self._hand_clearance = {}       # camera model key -> servo.hand_clearance_px map
        self.approach = None            # pick.Approach of the current approach (plan_approach)
        self._views_saved = 0
        self._debug_pub = rospy.Publisher('/baxter_pnp/debug_image', Image, queue_size=1)
        self._target_pub = rospy.Publisher('/baxter_pnp/target_pose', PoseStamped, queue_size=1, latch=True)
        self._result_pub = rospy.Publisher('/baxter_pnp/result', String, queue_size=1, latch=True)
        import tf2_ros
        self._tf = tf2_ros.TransformBroadcaster()

    # ================================================================================ set-up
    def connect(self):
        """Connect to the robot: enable, limb with its safety checks, gripper, camera, hand-eye."""
        c = self.config
        rospy.loginfo('pick: connecting to the robot (%s arm)' % c.side)
        self.enabler = robot.RobotEnable()
        self.enabler.enable()
        self.kinematics = ArmKinematics(c.side)
        self.safety = ArmSafety.for_arm(self.kinematics, table_top_z=c.table_top_z, tip_margin=c.tip_margin)
        self.limb = robot.Limb(c.side, self.safety, max_age=c.stream_max_age)
        self.gripper = robot.Gripper(c.side, max_age=c.stream_max_age)
        self.camera = robot.HandCamera(c.side, tuple(c.resolution), c.fps)
        self.calibrated_camera = None
        if c.camera_calibration:
            self.calibrated_camera = CameraModel.from_yaml(c.camera_calibration).scaled(*c.resolution)
            rospy.loginfo('pick: camera model from %s instead of camera_info' % c.camera_calibration)
        self.hand_eye = robot.hand_eye_transform(c.side)
        rospy.loginfo('pick: hand-eye from %s: camera at %s m from the gripper tip'
                      % (self.hand_eye.source, np.round(self.hand_eye.T_gripper_camera[:3, 3], 4).tolist()))
        self.limb.set_speed_ratio(c.speed_ratio)

    def hand_clearance(self, camera):
        """The hand's clearance map in ``camera``'s image (``servo.hand_clearance_px``: each pixel's distance to
        the open fingers, projected from the URDF's gripper solids and the hand-eye transform), computed once
        per camera model."""
        key = (camera.width, camera.height, camera.K.tobytes(), camera.D.tobytes())
        if key not in self._hand_clearance:
            T_camera_gripper = invert(self.hand_eye.T_gripper_camera)
            solids = [solid.moved(T_camera_gripper) for solid in self.kinematics.hand_solids()]
            self._hand_clearance[key] = servo.hand_clearance_px(camera, solids)
            rospy.loginfo('pick: the open fingers hide %.1f %% of the %dx%d image'
                          % (100.0 * np.mean(self._hand_clearance[key] == 0), camera.width, camera.height))
        return self._hand_clearance[key]

    # ================================================================================ the run
    def run(self):
        """Connect, then ``config.cycles`` pick (and place) cycles. Never raises for robot faults: each cycle
        ends in its result's ``failure_reason``; a failed cycle is followed by the next unless the robot
        itself is gone (``FATAL_REASONS``). Returns the cycles' PickResults (the last one is ``self.result``)."""
        c = self.config
        self.results = []
        connected = False
        for cycle in range(1, c.cycles + 1):
            self.result = pick.PickResult(success=False, mode=c.mode)
            self.last_block = None
            self.approach = None
            self.clock = None
            try:
                if not connected:
                    self.connect()
                    connected = True
                if c.cycles > 1:
                    rospy.loginfo('pick: cycle %d of %d' % (cycle, c.cycles))
                if not self.gripper.open(block=True, timeout=3.0):
                    raise PickFailure('gripper', 'the gripper did not open')
                self.move_to_joints(load_start_poses()[c.start_pose] if c.side == 'left'
                                    else self._mirror(load_start_poses()[c.start_pose]),
                                    'start pose %s' % c.start_pose)
                self.clock = RunClock()
                if cycle > 1:
                    self.wait_for_next_block()
                self.pick_with_recovery()
                if c.place_xy is not None:
                    self.place()
                self.result.success = True
            except PickFailure as failure:
                self.fail(failure.reason, str(failure))
            except UnsafeCommand as error:
                self.fail('unsafe_command', str(error))
            except robot.IKFailure as error:
                self.fail('ik_failure', str(error))
            except (robot.StreamLost, RobotRestarted) as error:
                self.fail('stream_lost', str(error))
            except robot.ServiceUnavailable as error:
                self.fail('service_unavailable', str(error))
            except robot.RobotError as error:
                self.fail('robot_error', str(error))
            finally:
                if self.clock is not None:
                    self.result.total_time_s = self.clock.elapsed()
                self.results.append(self.result)
                self.finish()
            if not connected or self.result.failure_reason in FATAL_REASONS:
                break
        if self.output_dir and c.cycles > 1:
            plot_cycles(self.results, os.path.join(self.output_dir, 'cycles.png'))
        return self.results

    def wait_for_next_block(self):
        """Between cycles: look from the start pose until a block to pick (not one already placed) is in
        view, for at most ``next_block_timeout`` s of robot time."""
        c = self.config
        rospy.loginfo('pick: waiting up to %.0f s for a %s %s to pick' % (c.next_block_timeout, c.colour, c.shape))
        deadline = rospy.get_time() + c.next_block_timeout
        while rospy.get_time() < deadline:
            if self.look(after_stamp=rospy.get_time()).target is not None:
                return
        raise PickFailure('no_block', 'no %s %s to pick appeared within %.0f s'
                          % (c.colour, c.shape, c.next_block_timeout))

    def pick_with_recovery(self):
        """``pick``, resumed when the robot went away and came back (restarted, or a network outage: its
        streams stopped) or a camera stream stalled, up to ``max_recoveries`` times; each wait lasts at most
        ``robot_wait_timeout`` s. A service missing on a robot that is otherwise alive is not waited for."""
        c = self.config
        for recovery in range(c.max_recoveries + 1):
            self._clock_jumps_before = self.clock.jumps
            try:
                return self.pick()
            except (robot.StreamLost, robot.ServiceUnavailable, RobotRestarted) as error:
                if recovery == c.max_recoveries or not self.recoverable(error):
                    raise
                rospy.logwarn('pick: %s; waiting up to %.0f s for the robot' % (error, c.robot_wait_timeout))
                self.wait_for_robot()

    def recoverable(self, error):
        """A lost stream or a restart can end; a missing service is waited for only if the whole robot
        went away: its clock went back (it restarted) or its own streams stopped too (a short probe)."""
        if not isinstance(error, robot.ServiceUnavailable):
            return True
        time.sleep(1.0)
        self.clock.elapsed()
        if self.clock.jumps > self._clock_jumps_before:
            return True
        try:
            self.enabler.require_fresh(0.5)
            self.limb.require_fresh(0.5)
            return False
        except robot.StreamLost:
            return True

    def wait_for_robot(self):
        """Wait until the robot streams and serves IK again, then re-enable it (unless it was e-stopped),
        recalibrate the gripper and reopen the camera."""
        c = self.config
        deadline = time.monotonic() + c.robot_wait_timeout
        # Let what the old robot sent age past the freshness limit: a state that is fresh after this comes
        # from the robot that is back (a restarted gripper is uncalibrated, whatever the old one said).
        time.sleep(c.stream_max_age)
        while True:
            try:
                self.enabler.require_fresh(c.stream_max_age)
                self.limb.require_fresh()
                self.gripper.require_fresh()
                rospy.wait_for_service(self.limb.ik_service_name, timeout=max(0.1, deadline - time.monotonic()))
                break
            except (robot.StreamLost, rospy.ROSException):
                if time.monotonic() > deadline or rospy.is_shutdown():
                    raise robot.StreamLost('the robot', c.robot_wait_timeout, c.robot_wait_timeout) from None
                time.sleep(0.2)
        rospy.loginfo('pick: the robot is back: enabling, calibrating the gripper, reopening the camera')
        if self.enabler.state().stopped:
            raise PickFailure('robot_stopped', 'the robot came back stopped (e-stop): not resetting it')
        self.enabler.enable()
        if not self.gripper.calibrated() and not self.gripper.calibrate():
            raise PickFailure('gripper', 'the gripper did not calibrate after the robot came back')
        self.gripper.open(block=True, timeout=3.0)
        self.camera.reopen()
        self.limb.set_speed_ratio(c.speed_ratio)
        self.last_block = None

    def check_robot(self):
        """PickFailure if the robot was stopped (e-stop) or disabled under us: nothing more is commanded.
        RobotRestarted instead when it is disabled because it restarted (its clock went back)."""
        state = self.enabler.state()
        if state.stopped:
            raise PickFailure('robot_stopped', 'the robot was stopped (e-stop, source %d)' % state.estop_source)
        if not state.enabled:
            if self.clock is not None and self.clock.restarted():
                raise RobotRestarted('the robot restarted (its clock went back) and is disabled')
            raise PickFailure('robot_disabled', 'the robot was disabled during the run')

    def pick(self):
        c = self.config
        for attempt in range(1, c.max_grasp_attempts + 1):
            self.result.grasp_attempts = attempt
            T_base_block = self.approach_pbvs() if c.mode == 'pbvs' else self.approach_velocity()
            if self.grasp(T_base_block):
                self.result.time_s = self.clock.elapsed()
                rospy.loginfo('pick: block picked after %.1f s (%d steps, attempt %d)'
                              % (self.result.time_s, self.result.steps, attempt))
                return
            rospy.logwarn('pick: grasp attempt %d missed; opening and trying again' % attempt)
            self.gripper.open(block=True, timeout=3.0)
            self.move_to_pose(pick.raised(self.limb.endpoint_pose(), c.hover_height + c.grasp_depth), 'back up')
        raise PickFailure('grasp_missed', 'no grip after %d attempts' % c.max_grasp_attempts)

    # ================================================================================ perception
    def look(self, after_stamp=None, on_table=True, placed_too=False):
        """Wait for a frame newer than ``after_stamp`` (ROS time), detect and estimate the block (with
        ``on_table``, only estimates that put it on the table are believed; unless ``placed_too``, blocks
        within two sides of ``place_xy`` count as already placed and are not targets)."""
        c = self.config
        self.check_robot()
        try:
            frame = self.camera.wait_for_frame(after_stamp, timeout=c.frame_timeout)
        except robot.RobotTimeout as error:
            raise robot.StreamLost(self.camera.image_topic, c.frame_timeout, c.frame_timeout) from error
        if self.calibrated_camera is not None:
            frame = frame._replace(camera=self.calibrated_camera)
        T_base_gripper = self.limb.endpoint_pose_at(frame.stamp)
        T_base_camera = T_base_gripper @ self.hand_eye.T_gripper_camera
        plane = pick.table_plane_in_camera(T_base_camera, c.table_top_z)
        observations = perception.observe_blocks(frame.image_bgr, frame.camera, self.vision_config, c.side_length,
                                                 c.block_height, shape=c.shape, colour=c.colour,
                                                 method=c.estimator, table_plane=plane)
        target = self._choose(observations, frame, T_base_camera, on_table, placed_too)
        T_base_block = None if target is None else T_base_camera @ target.pose.T_camera_object
        self.publish_view(frame, observations, T_base_block)
        return Look(frame, T_base_gripper, T_base_camera, target, T_base_block)

    def _choose(self, observations, frame, T_base_camera, on_table=True, placed_too=False):
        """The target among the believable estimates (reprojection residual below ``max_residual_px`` and,
        ``on_table``, top face within ``max_height_error`` of where the table puts it; unless ``placed_too``,
        not already at ``place_xy``): the one nearest the last estimate (tracking), else the largest / most
        central (vision.select_target)."""
        c = self.config
        expected_z = c.table_top_z + c.block_height

        def believable(o):
            if o.pose is None or o.pose.residual_px > c.max_residual_px:
                return False
            position = (T_base_camera @ o.pose.T_camera_object)[:3, 3]
            if (not placed_too and c.place_xy is not None
                    and np.linalg.norm(position[:2] - np.asarray(c.place_xy)) < 2 * c.side_length):
                return False
            return not on_table or abs(position[2] - expected_z) <= c.max_height_error
        posed = [o for o in observations if believable(o)]
        if not posed:
            return None
        if self.last_block is not None:
            distances = [np.linalg.norm((T_base_camera @ o.pose.T_camera_object)[:3, 3] - self.last_block[:3, 3])
                         for o in posed]
            if min(distances) < 0.05:
                return posed[int(np.argmin(distances))]
        chosen = vision.select_target([o.detection for o in posed], self.config.shape, self.config.colour,
                                      (frame.camera.width, frame.camera.height))
        return next(o for o in posed if o.detection is chosen)

    def publish_view(self, frame, observations, T_base_block):
        """Annotated view on ``/baxter_pnp/debug_image`` (and, with ``save_views``, as a numbered PNG in the
        output directory); the block's pose on ``/baxter_pnp/target_pose`` and as tf frame ``block``."""
        annotated = perception.annotate(frame.image_bgr, observations, frame.camera)
        self.last_annotated = annotated
        if self.config.save_views and self.output_dir:
            import cv2
            self._views_saved += 1
            views_dir = os.path.join(self.output_dir, 'views')
            os.makedirs(views_dir, exist_ok=True)
            cv2.imwrite(os.path.join(views_dir, 'view_%04d_t%.2f.png' % (self._views_saved, frame.stamp)), annotated)
        stamp = rospy.Time.from_sec(frame.stamp)
        message = bgr_to_msg(annotated, 'bgr8')
        message.header.stamp = stamp
        message.header.frame_id = frame.camera.frame_id
        self._debug_pub.publish(message)
        if T_base_block is None:
            return
        pose = PoseStamped()
        pose.header.stamp, pose.header.frame_id = stamp, 'base'
        matrix_to_pose_msg(T_base_block, pose.pose)
        self._target_pub.publish(pose)
        transform = TransformStamped()
        transform.header.stamp, transform.header.frame_id, transform.child_frame_id = stamp, 'base', 'block'
        xyz, quat = to_xyz_quat(T_base_block)
        t, q = transform.transform.translation, transform.transform.rotation
        t.x, t.y, t.z = (float(v) for v in xyz)
        q.x, q.y, q.z, q.w = (float(v) for v in quat)
        self._tf.sendTransform(transform)

    def look_for_block(self, after_stamp=None):
        """A look that finds the block whole: re-centres on a block cut by the image border and, when it is
        lost, moves to a wider view (:meth:`search_pose`; up to ``max_lost`` times in a row)."""
        c = self.config
        for lost in range(c.max_lost + 1):
            self.check_deadline()
            look = self.look(after_stamp)
            if look.target is not None and not look.target.detection.touches_border:
                self.last_block = look.T_base_block
                return look
            if look.target is not None:
                rospy.logwarn('pick: block cut by the image border: re-centring on it')
                T_next = self.recentred(look)
            else:
                if lost == c.max_lost:
                    break
                T_next = self.search_pose(look, lost)
            self.move_to_pose(T_next, 're-acquire')
            after_stamp = rospy.get_time()
        raise PickFailure('block_lost', 'no whole %s %s in view after %d re-acquisition moves'
                          % (c.colour, c.shape, c.max_lost))

    def search_pose(self, look, lost):
        """Where to look from after ``lost`` + 1 looks in a row without the block: above where it was last
        seen (the view pose of the velocity laws, ``view_depth`` from it, clear of the fingers), each further
        try ``backoff_height`` higher; never seen yet, or that view out of reach: ``backoff_height`` above
        the current pose."""
        c = self.config
        if self.last_block is not None:
            T_reference = look.T_base_gripper if self.approach is None else self.approach.T_reference
            T_hover = pick.hover_pose(self.last_block, c, T_reference)
            T_view = pick.raised(pick.view_pose(self.last_block, T_hover, self.hand_eye.T_gripper_camera,
                                                look.frame.camera, c), lost * c.backoff_height)
            if self.kinematics.ik(T_view, seed=self.limb.joint_positions()) is not None:
                rospy.logwarn('pick: block not in view (re-acquisition %d of %d): looking from above where it was '
                              'last seen, at %s mm' % (lost + 1, c.max_lost,
                                                       np.round(1000 * self.last_block[:3, 3], 1).tolist()))
                return T_view
        rospy.logwarn('pick: block not in view (re-acquisition %d of %d): backing off %.0f mm upward'
                      % (lost + 1, c.max_lost, 1000 * c.backoff_height))
        return pick.raised(look.T_base_gripper, c.backoff_height)

    def recentred(self, look):
        """Gripper pose translated so the camera looks at the (partly visible) block's estimated centre."""
        T_base_block = look.T_base_block
        T_base_camera = look.T_base_camera
        axis = T_base_camera[:3, 2]
        plane_z = T_base_block[2, 3]
        hit = T_base_camera[:3, 3] + axis * (plane_z - T_base_camera[2, 3]) / axis[2] if abs(axis[2]) > 1e-3 \
            else T_base_camera[:3, 3]
        T = look.T_base_gripper.copy()
        T[:2, 3] += (T_base_block[:2, 3] - hit[:2])
        T[2, 3] += self.config.backoff_height / 2
        return T

    # ================================================================================ approach laws
    def record(self, step, look, T_goal, error_px):
        translation, rotation = pick.pose_error(look.T_base_gripper, T_goal)
        depth = look.target.pose.depth_m
        block_in_gripper = (invert(look.T_base_gripper) @ look.T_base_block)[:3, 3]
        self.result.history.append(pick.StepRecord(step, self.clock.elapsed(), 1000 * translation,
                                                   np.degrees(rotation), error_px, depth,
                                                   np.round(look.T_base_block[:3, 3], 5).tolist(),
                                                   np.round(1000 * block_in_gripper, 2).tolist()))
        self.result.steps = step
        self.result.final_error_mm_est = 1000 * translation
        rospy.loginfo('pick [%s] step %d: error %.1f mm, %.1f deg, %.1f px; block depth %.1f mm, at %s mm in base'
                      % (self.config.mode, step, 1000 * translation, np.degrees(rotation), error_px, 1000 * depth,
                         np.round(1000 * look.T_base_block[:3, 3], 1).tolist()))
        return translation, rotation

    def image_error_px(self, look, T_goal):
        """Pixel distance between the block centre now and where it appears from the goal pose."""
        camera = look.frame.camera
        now = camera.project(look.target.pose.T_camera_object[:3, 3][None])[0]
        at_goal = camera.project(pick.camera_goal(T_goal, look.T_base_block, self.hand_eye.T_gripper_camera)
                                 [:3, 3][None])[0]
        return float(np.linalg.norm(now - at_goal))

    def approach_pbvs(self):
        """The thesis's dynamic look-and-move, fixed: yaw aligned, block kept in view, plane prior, undistorted."""
        c = self.config
        look = self.look_for_block()
        approach = self.approach = self.plan_approach(look)
        for step in range(c.max_steps + 1):
            T_goal = pick.hover_pose(look.T_base_block, c, approach.T_reference)
            self.record(step, look, T_goal, self.image_error_px(look, T_goal))
            if pick.converged(look.T_base_gripper, T_goal, c):
                return look.T_base_block
            T_next, T_toward = pick.pbvs_target(look.T_base_gripper, T_goal, look.T_base_block, c, look.frame.camera,
                                                self.hand_eye.T_gripper_camera, self.hand_clearance(look.frame.camera),
                                                approach.view_depth)
            self.move_to_pose(T_next, 'servo step %d%s' % (step + 1, '' if T_toward is T_goal else
                                                            ' (via the view pose: a straight path would pass '
                                                            'the block behind a finger)'))
            look = self.look_for_block(after_stamp=rospy.get_time())
        raise PickFailure('not_converged', 'still %.1f mm from the hover pose after %d steps'
                          % (self.result.final_error_mm_est, c.max_steps))

    def approach_velocity(self):
        """IBVS or 2.5D at the camera rate: camera twist -> joint velocities (arm Jacobian from the URDF)."""
        c = self.config
        gain = pick.make_gain(c)
        camera_frame = '%s_hand_camera' % c.side
        velocity_limits = c.speed_ratio * self.kinematics.velocity_limits * 2.0
        look = self.look_for_block()
        approach = self.approach = self.plan_approach(look)
        at_view = False         # first goal: the view pose (block low in the image); then the hover pose
        for iteration in range(10 * c.max_steps + 1):
            camera = look.frame.camera
            T_hover = pick.hover_pose(look.T_base_block, c, approach.T_reference)
            T_goal = T_hover if at_view else pick.view_pose(look.T_base_block, T_hover, self.hand_eye.T_gripper_camera,
                                                            camera, c, approach.view_depth)
            T_camera_goal_block = pick.camera_goal(T_goal, look.T_base_block, self.hand_eye.T_gripper_camera)
            vertices_xy = camera.undistort_points(look.target.detection.vertices_px)
            twist, error = pick.servo_twist(c.mode, look.target.pose.T_camera_object, T_camera_goal_block,
                                            vertices_xy, self.model, gain)
            translation, rotation = self.record(iteration, look, T_hover, error * camera.fx)
            if not at_view and error * camera.fx <= c.view_tolerance_px:
                rospy.loginfo('pick [%s]: view reached (%.1f px): now up between the fingers to the hover pose'
                              % (c.mode, error * camera.fx))
                at_view = True
                continue
            if at_view and error * camera.fx <= c.feature_tolerance_px and translation <= 2 * c.position_tolerance:
                self.limb.exit_control_mode()
                return look.T_base_block
            twist = pick.view_kept_twist(pick.bounded_twist(twist, c.max_linear_speed, c.max_angular_speed),
                                         look.T_base_camera, look.T_base_block, c, camera,
                                         self.hand_clearance(camera))
            twist_base = servo.camera_twist_to_base(twist, look.T_base_camera)
            q = self.limb.joint_positions()
            qdot = servo.joint_velocities(self.kinematics.jacobian(q, camera_frame), twist_base,
                                          qdot_limits=velocity_limits, q=q, lower=self.kinematics.lower,
                                          upper=self.kinematics.upper, horizon=robot.COMMAND_TIMEOUT)
            self.limb.set_joint_velocities(qdot)
            try:
                look = self.look_for_velocity_loop(look.frame.stamp)
            except PickFailure:
                self.limb.exit_control_mode()
                raise
        self.limb.exit_control_mode()
        raise PickFailure('not_converged', 'feature error still %.1f px after %d iterations'
                          % (error * camera.fx, 10 * c.max_steps))

    def plan_approach(self, look):
        """``pick.plan_approach`` from this look, reachability by the URDF's IK from the current angles."""
        c = self.config
        q = self.limb.joint_positions()
        approach = pick.plan_approach(look.T_base_block, look.T_base_gripper, c, look.frame.camera,
                                      self.hand_eye.T_gripper_camera,
                                      lambda T: self.kinematics.ik(T, seed=q) is not None)
        if approach.rank < 0:
            rospy.logwarn('pick [%s]: no grasp orientation with a reachable hover and view pose: trying the nearest'
                          % c.mode)
        else:
            T_hover = pick.hover_pose(look.T_base_block, c, approach.T_reference)
            rospy.loginfo('pick [%s]: approach planned: grasp orientation %d (%.0f deg from the current one), view '
                          'from %.0f mm' % (c.mode, approach.rank + 1,
                                            np.degrees(pick.pose_error(look.T_base_gripper, T_hover)[1]),
                                            1000 * approach.view_depth))
        return approach

    def look_for_velocity_loop(self, after_stamp):
        """Next look of the velocity loop; on a lost or cut block the arm stops and re-acquires first."""
        self.check_deadline()
        look = self.look(after_stamp)
        if look.target is not None and not look.target.detection.touches_border:
            self.last_block = look.T_base_block
            return look
        self.limb.exit_control_mode()
        return self.look_for_block(after_stamp=rospy.get_time())

    # ================================================================================ grasp and place
    def grasp(self, T_base_block):
        """Descend, close, verify (gripper state, then lift and look). True on a verified grasp."""
        c = self.config
        T_grasp = pick.grasp_pose(T_base_block, c, self.limb.endpoint_pose())
        self.move_to_pose(T_grasp, 'descend to grasp')
        self.gripper.close(block=True, timeout=3.0)
        if not self.gripper.gripping() or self.gripper.missed():
            rospy.logwarn('pick: gripper reports %s (position %.1f %%)'
                          % ('missed' if self.gripper.missed() else 'no grip', self.gripper.position()))
            return False
        self.T_gripper_block = invert(T_grasp) @ T_base_block
        self.move_to_pose(pick.raised(self.limb.endpoint_pose(), c.lift_height), 'lift')
        if not self.gripper.gripping():
            rospy.logwarn('pick: the block slipped out while lifting')
            return False
        return self.verify_hold(T_base_block)

    def verify_hold(self, T_base_block_before):
        """The look after lifting: the grip is refuted only if the block is seen still lying where it was;
        a block seen in the hand confirms it; anything else (occluded by the fingers, an odd estimate)
        leaves the gripper's word (gripping) standing, with a warning."""
        c = self.config
        look = self.look(after_stamp=rospy.get_time(), on_table=False)
        if look.target is None:
            rospy.logwarn('pick: the look after lifting does not see the block (occluded?); gripper reports gripping')
            return True
        left_behind = (abs(look.T_base_block[2, 3] - (c.table_top_z + c.block_height)) < 0.01 and
                       np.linalg.norm(look.T_base_block[:2, 3] - T_base_block_before[:2, 3]) < 0.02)
        if left_behind:
            rospy.logwarn('pick: a look finds the block still on the table: the gripper holds something else')
            return False
        T_gripper_block_seen = invert(look.T_base_gripper) @ look.T_base_block
        offset = float(np.linalg.norm(T_gripper_block_seen[:3, 3] - self.T_gripper_block[:3, 3]))
        if offset <= 0.02:
            self.T_gripper_block = T_gripper_block_seen
            rospy.loginfo('pick: grasp verified by a look (block %.1f mm from the expected place in the hand)'
                          % (1000 * offset))
        else:
            rospy.logwarn('pick: the look after lifting is inconclusive (block estimated %.1f mm from its expected '
                          'place in the hand); gripper reports gripping' % (1000 * offset))
        return True

    def place(self):
        """Carry the block to ``place_xy``, lower it to the table, open, retreat."""
        c = self.config
        holding = self.limb.endpoint_pose()
        rospy.loginfo('pick: placing the block at (%.3f, %.3f) m' % tuple(c.place_xy))
        self.move_to_pose(pick.place_pose(holding, self.T_gripper_block, c.place_xy, c, c.lift_height),
                          'carry to the place position')
        self.move_to_pose(pick.place_pose(self.limb.endpoint_pose(), self.T_gripper_block, c.place_xy, c,
                                          c.place_clearance), 'lower to the table')
        if not self.gripper.open(block=True, timeout=3.0):
            raise PickFailure('gripper', 'the gripper did not open to release the block')
        self.move_to_pose(pick.raised(self.limb.endpoint_pose(), c.lift_height), 'retreat')
        self.result.placed = True
        look = self.look(after_stamp=rospy.get_time(), placed_too=True)
        if look.target is None:
            rospy.logwarn('pick: the look after placing does not find the block')
            return
        self.result.place_error_mm_est = 1000 * float(np.linalg.norm(look.T_base_block[:2, 3] - np.asarray(c.place_xy)))
        rospy.loginfo('pick: block placed %.1f mm from the requested position (estimated by a look)'
                      % self.result.place_error_mm_est)

    # ================================================================================ motion
    def move_to_pose(self, T_base_gripper, what, max_intermediate=3):
        """Move the gripper to ``T_base_gripper`` (IK, then a safety-checked joint move).

        IK is seeded with the current angles, then with the robot's automatic seeding. If neither finds a
        solution, the arm first goes to the pose halfway there (same two tries) and then tries the target
        again from there, up to ``max_intermediate`` times; IKFailure when even that fails.
        """
        xyz, quat = to_xyz_quat(T_base_gripper)
        rospy.loginfo('pick: %s: gripper to %s mm, quaternion %s' % (what, np.round(1000 * xyz, 1).tolist(),
                                                                  np.round(quat, 3).tolist()))
        for _ in range(max_intermediate):
            path = self.plan_joints(T_base_gripper, what)
            if path is not None:
                return self.follow_path(path, what)
            q = self.solve_ik(T_base_gripper, what)
            if q is not None:
                return self.move_to_joints(q, what)
            halfway = servo.interpolate_pose(self.limb.endpoint_pose(), T_base_gripper, 0.5)
            q_halfway = self.solve_ik(halfway, what + ' (halfway)')
            if q_halfway is None:
                break
            rospy.logwarn('pick: %s: no IK solution for the target: going halfway first' % what)
            self.move_to_joints(q_halfway, what + ' (halfway)')
        raise robot.IKFailure('%s: no IK solution for the gripper at %s mm (nor for intermediate poses)'
                              % (what, np.round(1000 * xyz, 1).tolist()))

    def plan_joints(self, T_base_gripper, what):
        """Joint-space waypoints (dicts) of the straight Cartesian path to ``T_base_gripper`` on the arm's
        current branch: IK every ``waypoint_spacing`` (and 10 deg at most), each seeded with the previous
        solution. Followed without stopping, the gripper stays within a millimetre or so of the straight
        line (a descent cannot swing the fingers into the block, even near the elbow's singularity).
        None when a waypoint has no solution."""
        T_start = self.limb.endpoint_pose()
        translation, rotation = pick.pose_error(T_start, T_base_gripper)
        count = max(1, int(np.ceil(max(translation / self.config.waypoint_spacing, rotation / np.radians(10.0)))))
        path = [self.limb.joint_angles()]
        for k in range(1, count + 1):
            try:
                path.append(self.limb.solve_ik(servo.interpolate_pose(T_start, T_base_gripper, k / count),
                                               seed=path[-1]))
            except robot.IKFailure as error:
                rospy.logwarn('pick: %s: waypoint %d/%d has no IK solution on this branch (%s)'
                              % (what, k, count, error))
                return None
        return path[1:]

    def solve_ik(self, T_base_gripper, what):
        """Joint angles for ``T_base_gripper`` from the IK service (seeded with the current angles, then
        the robot's automatic seeding), or None when neither finds a solution."""
        for seed, description in ((self.limb.joint_angles(), 'current angles'), (None, 'automatic seed')):
            try:
                return self.limb.solve_ik(T_base_gripper, seed=seed)
            except robot.IKFailure as error:
                rospy.logwarn('pick: %s: no IK solution with the %s (%s)' % (what, description, error))
        return None

    def move_to_joints(self, q, what):
        """Safety-checked position move along the straight joint-space line, cut into segments of at most
        the safety's joint step (the start-pose move is longer than one servo step may be)."""
        q_start = self.limb.joint_angles()
        names = list(q_start)
        q_target = np.array([q[name] for name in names], dtype=float)
        q_from = np.array([q_start[name] for name in names], dtype=float)
        segments = max(1, int(np.ceil(np.max(np.abs(q_target - q_from)) / self.safety.limits.max_joint_step)))
        self.follow_path([dict(zip(names, q_from + (q_target - q_from) * k / segments))
                          for k in range(1, segments + 1)], what)

    def follow_path(self, waypoints, what):
        """Stream a joint-space path (safety-checked segment by segment), watching the robot state.

        Arrival needs every joint within SETTLE_TOLERANCE of the end, or within a third of the move's
        largest joint change when that is smaller (a small servo step must actually be made)."""
        timeout = 10.0 + 2.0 * len(waypoints)
        start = self.limb.joint_angles()
        change = max(abs(waypoints[-1][name] - start[name]) for name in start)
        tolerance = max(MIN_SETTLE_TOLERANCE, min(SETTLE_TOLERANCE, change / 3.0))
        if not self.limb.follow_joint_path(waypoints, timeout=timeout, tolerance=tolerance,
                                           check=self.check_robot):
            raise PickFailure('motion_timeout', '%s: the arm did not arrive' % what)

    def check_deadline(self):
        if self.clock.elapsed() > self.config.timeout:
            raise PickFailure('timeout', 'the run exceeded %.0f s' % self.config.timeout)

    @staticmethod
    def _mirror(left_angles):
        """The right arm's mirror image of left-arm angles (s0, e0, w0, w2 change sign)."""
        signs = {'s0': -1, 's1': 1, 'e0': -1, 'e1': 1, 'w0': -1, 'w1': 1, 'w2': -1}
        return {'right_' + name[5:]: signs[name[5:]] * angle for name, angle in left_angles.items()}

    # ================================================================================ ending
    def fail(self, reason, detail):
        """Abort cleanly: log, open the gripper if nothing is held, retreat upward if that is safe."""
        self.result.success = False
        self.result.failure_reason = reason
        rospy.logerr('pick: FAILED (%s): %s' % (reason, detail))
        try:
            if getattr(self, 'gripper', None) is not None and not self.gripper.gripping():
                self.gripper.open(block=False)
            if getattr(self, 'limb', None) is not None and reason not in ('robot_stopped', 'robot_disabled'):
                self.limb.exit_control_mode()
                self.move_to_pose(pick.raised(self.limb.endpoint_pose(), 0.05), 'retreat', max_intermediate=1)
        except (PickFailure, robot.RobotError, UnsafeCommand, ValueError) as error:
            rospy.logwarn('pick: could not retreat after the failure: %s' % error)

    def finish(self):
        r = self.result
        summary = ('pick: %s in %.1f s (%d steps, mode %s, final estimated error %s mm%s)'
                   % ('SUCCESS' if r.success else 'FAILURE', r.time_s, r.steps, r.mode,
                      'n/a' if r.final_error_mm_est is None else '%.1f' % r.final_error_mm_est,
                      '' if r.success else ', reason: %s' % r.failure_reason))
        (rospy.loginfo if r.success else rospy.logerr)(summary)
        self._result_pub.publish(String(json.dumps(r.to_json())))
        if self.result_json:
            with open(self.result_json, 'w') as f:
                json.dump(results_json(self.results, self.config), f, indent=1)
        if self.output_dir and self.config.cycles == 1:
            write_outputs(self.output_dir, r, self.last_annotated)
        elif self.output_dir:   # no plot per cycle: matplotlib's caches grow ~20 MiB over its first ~20 figures
            write_outputs(os.path.join(self.output_dir, 'cycle_%03d' % len(self.results)), r, self.last_annotated,
                          plot=False)


def results_json(results, config):
    """The ``--result-json`` content: one run's result dict; with ``cycles`` > 1 ``{"cycles": [result dicts
    of the finished cycles], "successes", "success" (all cycles so far succeeded), "mode", "cycles_planned"}``."""
    if config.cycles == 1:
        return results[-1].to_json()
    successes = sum(r.success for r in results)
    return {'cycles': [r.to_json() for r in results], 'successes': successes,
            'success': successes == len(results) == config.cycles, 'mode': config.mode,
            'cycles_planned': config.cycles}


def write_outputs(output_dir, result, annotated, plot=True):
    """result.json, final_view.png (last annotated camera view) and, with ``plot``, errors.png (error vs step)."""
    import cv2
    os.makedirs(output_dir, exist_ok=True)
    with open(os.path.join(output_dir, 'result.json'), 'w') as f:
        json.dump(result.to_json(), f, indent=1)
    if annotated is not None:
        cv2.imwrite(os.path.join(output_dir, 'final_view.png'), annotated)
    if plot and result.history:
        plot_errors(result, os.path.join(output_dir, 'errors.png'))


def plot_errors(result, path):
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt
    steps = [h.step for h in result.history]
    figure, (ax_mm, ax_px) = plt.subplots(2, 1, figsize=(7, 6), sharex=True)
    ax_mm.plot(steps, [h.error_mm for h in result.history], 'o-', label='position error (mm)')
    ax_mm.plot(steps, [h.error_deg for h in result.history], 's--', label='orientation error (deg)')
    ax_mm.set_yscale('log')
    ax_mm.set_ylabel('estimated error to hover pose')
    ax_mm.legend()
    ax_mm.set_title('pick_square, mode %s: %s' % (result.mode, 'success' if result.success else result.failure_reason))
    ax_px.plot(steps, [h.error_px for h in result.history], 'o-', color='tab:green')
    ax_px.set_ylabel('image error (px)')
    ax_px.set_xlabel('step' if result.mode == 'pbvs' else 'iteration (camera frame)')
    figure.tight_layout()
    figure.savefig(path, dpi=100)
    plt.close(figure)


def plot_cycles(results, path):
    """A multi-cycle run at a glance: each cycle's time to grasp (s) and final estimated error (mm), failed
    cycles marked with their reason."""
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt
    cycles = np.arange(1, len(results) + 1)
    colours = ['tab:green' if r.success else 'tab:red' for r in results]
    figure, (ax_time, ax_error) = plt.subplots(2, 1, figsize=(8, 6), sharex=True)
    ax_time.bar(cycles, [r.time_s for r in results], color=colours)
    ax_time.set_ylabel('time to grasp (s)')
    ax_time.set_title('pick_square, mode %s: %d of %d cycles succeeded'
                      % (results[0].mode, sum(r.success for r in results), len(results)))
    for cycle, r in zip(cycles, results):
        if not r.success:
            ax_time.annotate(r.failure_reason, (cycle, 0), rotation=90, fontsize=7, va='bottom', ha='center')
    ax_error.plot(cycles, [np.nan if r.final_error_mm_est is None else r.final_error_mm_est for r in results], 'o')
    ax_error.set_ylabel('final estimated error (mm)')
    ax_error.set_xlabel('cycle')
    figure.tight_layout()
    figure.savefig(path, dpi=100)
    plt.close(figure)


# ==================================================================================== entry point
def parse_args(argv):
    parser = argparse.ArgumentParser(prog='pick_square.py', description=__doc__.split('\n')[0].strip('`: '))
    parser.add_argument('--config', default=DEFAULT_CONFIG, help='pick parameters YAML (default %(default)s)')
    parser.add_argument('--mode', choices=pick.MODES)
    parser.add_argument('--arm', dest='side', choices=['left', 'right'])
    parser.add_argument('--shape', help='target shape (triangle, square, pentagon, hexagon)')
    parser.add_argument('--side-length', type=float, help='block side (m)')
    parser.add_argument('--colour', '--color', dest='colour', help='block colour (a name in config/vision.yaml)')
    parser.add_argument('--step-fraction', type=float, help='PBVS step fraction (thesis: 0.35 or 0.12)')
    parser.add_argument('--start-pose', help='start pose name in config/start_poses.yaml (down, angled)')
    parser.add_argument('--table-top-z', type=float, help='table top height in base (m)')
    parser.add_argument('--estimator', choices=['sqp', 'ippe', 'sqpnp'])
    parser.add_argument('--camera-calibration', metavar='YAML',
                        help="camera calibration to use instead of the robot's camera_info")
    parser.add_argument('--speed-ratio', type=float, help='arm speed ratio (0, 1]')
    parser.add_argument('--place', metavar='X,Y', help='place the block at this table position (base, m)')
    parser.add_argument('--cycles', type=int, help='pick (and place) this many blocks, one after the other; '
                        'after the first, wait for each next block (blocks at the place position are done)')
    parser.add_argument('--result-json', metavar='FILE', help='write the result JSON here')
    parser.add_argument('--output-dir', metavar='DIR', help='write result.json, final_view.png and errors.png here')
    parser.add_argument('--save-views', action='store_true', default=None,
                        help='save every annotated camera view as a PNG in OUTPUT_DIR/views')
    parser.add_argument('--vision-config', metavar='YAML', help='vision parameters (default config/vision.yaml)')
    return parser.parse_args(argv)


def build_config(args):
    """Defaults <- the YAML <- private ROS parameters (~name, e.g. from the launch file) <- command line."""
    values = {}
    if args.config:
        with open(args.config) as f:
            values.update(yaml.safe_load(f) or {})
    for name in pick.PickConfig.__dataclass_fields__:
        if rospy.has_param('~' + name):
            values[name] = rospy.get_param('~' + name)
    for name in ('mode', 'side', 'shape', 'side_length', 'colour', 'step_fraction', 'start_pose', 'table_top_z',
                 'estimator', 'speed_ratio', 'camera_calibration', 'cycles', 'save_views'):
        if getattr(args, name) is not None:
            values[name] = getattr(args, name)
    if args.place:
        try:
            values['place_xy'] = [float(v) for v in args.place.split(',')]
        except ValueError:
            raise ValueError('--place: expected X,Y in metres, got %r' % args.place) from None
    return pick.PickConfig.from_dict(values)


def main(argv=None):
    args = parse_args(rospy.myargv()[1:] if argv is None else argv)
    rospy.init_node('pick_square', disable_signals=False)
    try:
        config = build_config(args)
        vision_config = vision.VisionConfig.from_yaml(args.vision_config)
        if config.colour not in vision_config.colour_names():
            raise ValueError('colour: %r is not in the vision configuration (known: %s)'
                             % (config.colour, ', '.join(vision_config.colour_names())))
    except (OSError, ValueError, TypeError) as error:
        rospy.logerr('pick_square: bad configuration: %s' % error)
        return 2
    rospy.loginfo('pick_square: %s' % json.dumps(config.as_dict()))
    application = PickApplication(config, vision_config, args.output_dir, args.result_json)
    started = time.monotonic()
    results = application.run()
    successes = sum(r.success for r in results)
    rospy.loginfo('pick_square: wall time %.1f s' % (time.monotonic() - started))
    if config.cycles > 1:
        rospy.loginfo('pick_square: %d of %d cycles succeeded' % (successes, config.cycles))
    return 0 if successes == len(results) == config.cycles else 1
