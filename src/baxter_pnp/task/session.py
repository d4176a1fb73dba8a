"""The robot session every task runs in: connect to the robot (enable, arm with its safety checks, gripper, hand
camera, hand-eye transform), check it is still enabled and not e-stopped, wait for a restarted robot and resume,
and the run's clock. ROS edge; only the Baxter SDK's topics and services (``baxter_pnp.robot``).

Failures: a task raises :class:`TaskFailure` (a machine-readable ``reason``) or lets a robot error through;
:func:`failure_reason` names any of them for the result JSON, and :data:`FATAL_REASONS` are those after which a
multi-cycle run stops (the robot is gone, not just this task).
"""
import time

import numpy as np
import rospy

from baxter_pnp import robot
from baxter_pnp.kinematics import ArmKinematics, load_start_poses
from baxter_pnp.safety import ArmSafety, UnsafeCommand

# Failures after which a multi-cycle run stops: the robot is gone, stopped or broken, not just this task.
FATAL_REASONS = ('robot_stopped', 'robot_disabled', 'stream_lost', 'service_unavailable', 'robot_error', 'gripper')
GRIPPER_TIMEOUT = 3.0     # s: a blocking open or close of the gripper waits this long
RESTART_GRACE = 0.5       # s (wall): a disabled state waits this long for the clock jump of a restart
LIVENESS_WINDOW = 2.0     # s (wall): a lost service is judged against the robot's streams and clock this long


class TaskFailure(RuntimeError):
    """The task cannot go on; ``reason`` is a short machine-readable cause (result JSON ``failure_reason``)."""

    def __init__(self, reason, detail=''):
        super().__init__('%s: %s' % (reason, detail) if detail else reason)
        self.reason = reason


class RobotRestarted(robot.RobotError):
    """The robot came back from a restart (disabled, clock reset): the run can resume after re-enabling."""


def failure_reason(error):
    """The result JSON's ``failure_reason`` of an exception that ended a task, or None if it is no task or robot
    failure (a bug: let it through)."""
    if isinstance(error, TaskFailure):
        return error.reason
    for kind, reason in ((UnsafeCommand, 'unsafe_command'), (robot.IKFailure, 'ik_failure'),
                         (robot.StreamLost, 'stream_lost'), (RobotRestarted, 'stream_lost'),
                         (robot.ServiceUnavailable, 'service_unavailable'), (robot.RobotError, 'robot_error')):
        if isinstance(error, kind):
            return reason
    return None


def mirrored(left_angles):
    """The right arm's mirror image of left-arm joint angles (rad; s0, e0, w0, w2 change sign)."""
    signs = {'s0': -1, 's1': 1, 'e0': -1, 'e1': 1, 'w0': -1, 'w1': 1, 'w2': -1}
    return {'right_' + name[5:]: signs[name[5:]] * angle for name, angle in left_angles.items()}


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


class RobotSession:
    """One arm of one robot, connected by :meth:`connect` (``config`` a ``task.settings.SessionConfig``).

    Attributes after ``connect``: ``enabler`` (robot.RobotEnable), ``kinematics`` (URDF ArmKinematics),
    ``safety`` (ArmSafety: table floor and limits), ``limb``, ``gripper``, ``camera`` (robot.HandCamera),
    ``camera_override`` (a CameraModel from ``camera_calibration``, or None), ``hand_eye`` (robot.HandEye: from
    ``config.hand_eye``'s calibration, else tf / the URDF), ``table`` (the table top in base, a ``models.Plane``:
    ``config.table()``).
    ``clock`` is the current run's RunClock (:meth:`start_clock`)."""

    def __init__(self, config, log_name='task'):
        self.config = config
        self.log_name = log_name
        self.clock = None
        self.connected = False
        self.enabler = self.kinematics = self.safety = self.limb = self.gripper = None
        self.camera = self.camera_override = self.hand_eye = None
        self.table = config.table()

    def connect(self):
        c = self.config
        rospy.loginfo('%s: connecting to the robot (%s arm)' % (self.log_name, c.side))
        self.enabler = robot.RobotEnable(timeout=c.robot_wait_timeout)   # a loaded machine can take over 2 s
        self.enabler.enable()
        self.kinematics = ArmKinematics(c.side)
        rospy.loginfo('%s: table top %.4f m under the base origin, tilted %.2f deg (%s)'
                      % (self.log_name, self.table.z_at((0.0, 0.0)), np.degrees(self.table.tilt()),
                         'the plane of %s' % c.hand_eye if c.table_calibrated() else 'table_top_z'))
        self.safety = ArmSafety.for_arm(self.kinematics, table_top_z=c.table_top_z, table_plane=self.table,
                                        tip_margin=c.tip_margin)
        # the same wait for the first state and for the command topics' subscribers (a loaded machine)
        self.limb = robot.Limb(c.side, self.safety, timeout=c.robot_wait_timeout, max_age=c.stream_max_age)
        self.gripper = robot.Gripper(c.side, timeout=c.robot_wait_timeout, max_age=c.stream_max_age)
        self.camera = robot.HandCamera(c.side, tuple(c.resolution), c.fps, exposure=c.camera_exposure,
                                       gain=c.camera_gain)
        if c.camera_calibration:
            self.camera_override = c.calibrated_camera()
            rospy.loginfo('%s: camera model from %s instead of camera_info' % (self.log_name, c.camera_calibration))
        if c.hand_eye:
            calibration = c.hand_eye_calibration()
            self.hand_eye = robot.hand_eye_from_calibration(c.side, calibration.T_parent_child,
                                                            'calibration %s' % c.hand_eye)
        else:
            self.hand_eye = robot.hand_eye_transform(c.side)
        rospy.loginfo('%s: hand-eye from %s: camera at %s m from the gripper tip'
                      % (self.log_name, self.hand_eye.source,
                         np.round(self.hand_eye.T_gripper_camera[:3, 3], 4).tolist()))
        self.limb.set_speed_ratio(c.speed_ratio)
        self.connected = True

    def start_pose(self, name):
        """Joint angles (rad, by joint name) of the start pose ``name`` (config/start_poses.yaml) for this arm."""
        angles = load_start_poses()[name]
        return angles if self.config.side == 'left' else mirrored(angles)

    def start_clock(self):
        self.clock = RunClock()
        return self.clock

    def elapsed(self):
        """Robot time (s) since :meth:`start_clock`, 0 before it."""
        return 0.0 if self.clock is None else self.clock.elapsed()

    def check_deadline(self):
        """TaskFailure('timeout') once the run has taken more than ``config.timeout`` s of robot time."""
        if self.clock is not None and self.clock.elapsed() > self.config.timeout:
            raise TaskFailure('timeout', 'the run exceeded %.0f s' % self.config.timeout)

    def check_robot(self):
        """TaskFailure if the robot was stopped (e-stop) or disabled under us: nothing more is commanded.
        RobotRestarted instead when it is disabled because it restarted (its clock went back): a restarted robot's
        first state can arrive before its clock, so a disabled state is judged after up to ``RESTART_GRACE`` s."""
        state = self.enabler.state()
        if state.stopped:
            raise TaskFailure('robot_stopped', 'the robot was stopped (e-stop, source %d)' % state.estop_source)
        if not state.enabled:
            deadline = time.monotonic() + RESTART_GRACE
            while self.clock is not None:
                if self.clock.restarted():
                    raise RobotRestarted('the robot restarted (its clock went back) and is disabled')
                if time.monotonic() >= deadline:
                    break
                time.sleep(0.02)
            raise TaskFailure('robot_disabled', 'the robot was disabled during the run')

    def open_gripper(self):
        """Open and wait (TaskFailure 'gripper' if it does not)."""
        if not self.gripper.open(block=True, timeout=GRIPPER_TIMEOUT):
            raise TaskFailure('gripper', 'the gripper did not open')

    # ------------------------------------------------------------------------------------------ recovery
    def run_resuming(self, body, on_resume=None):
        """``body()``, run again when the robot went away and came back (restarted, or a network outage: its
        streams stopped) or a camera stream stalled, up to ``max_recoveries`` times; each wait lasts at most
        ``robot_wait_timeout`` s, then ``on_resume()`` (forget what the task believed about the scene). A
        service missing on a robot that is otherwise alive is not waited for."""
        c = self.config
        for recovery in range(c.max_recoveries + 1):
            jumps_before = self.clock.jumps
            try:
                return body()
            except (robot.StreamLost, robot.ServiceUnavailable, RobotRestarted) as error:
                if recovery == c.max_recoveries or not self.recoverable(error, jumps_before):
                    raise
                rospy.logwarn('%s: %s; waiting up to %.0f s for the robot' % (self.log_name, error,
                                                                            c.robot_wait_timeout))
                self.wait_for_robot()
                if on_resume is not None:
                    on_resume()

    def recoverable(self, error, clock_jumps_before):
        """A lost stream or a restart can end; a missing service is waited for only if the whole robot went
        away within ``LIVENESS_WINDOW`` s: its clock went back since ``clock_jumps_before`` (it restarted) or its
        own streams stopped too. Watched over a window, not once: a robot killed and at once restarted has its
        old streams fresh for their max age and the new clock's jump can come a moment later."""
        if not isinstance(error, robot.ServiceUnavailable):
            return True
        deadline = time.monotonic() + LIVENESS_WINDOW
        while not rospy.is_shutdown():
            self.clock.elapsed()
            if self.clock.jumps > clock_jumps_before:
                return True
            try:
                self.enabler.require_fresh(0.5)
                self.limb.require_fresh(0.5)
            except robot.StreamLost:
                return True
            if time.monotonic() >= deadline:
                return False
            time.sleep(0.05)
        return False

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
        rospy.loginfo('%s: the robot is back: enabling, calibrating the gripper, reopening the camera'
                      % self.log_name)
        if self.enabler.state().stopped:
            raise TaskFailure('robot_stopped', 'the robot came back stopped (e-stop): not resetting it')
        self.enabler.enable()
        if not self.gripper.calibrated() and not self.gripper.calibrate():
            raise TaskFailure('gripper', 'the gripper did not calibrate after the robot came back')
        self.gripper.open(block=True, timeout=GRIPPER_TIMEOUT)
        self.camera.reopen()
        self.limb.set_speed_ratio(c.speed_ratio)
