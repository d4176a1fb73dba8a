"""Safe arm motion for every task: the gripper to a pose through the robot's IK service (seeded, with
intermediate poses), straight Cartesian paths as chained IK, joint moves cut into safety-checked segments, and
arrival (settling). Every command passes the session's ``ArmSafety`` (in ``robot.Limb``) before it is sent.

Poses are ``T_base_gripper``: the ``<side>_gripper`` tip frame in ``base`` (4x4, metres); joint angles in rad,
by joint name. One log line per arm command.
"""
import numpy as np
import rospy

from baxter_pnp import robot
from baxter_pnp.servo import interpolate_pose
from baxter_pnp.task.session import TaskFailure
from baxter_pnp.transforms import pose_error, raised, to_xyz_quat

SETTLE_TOLERANCE = 0.003        # rad: a position move counts as arrived (and the arm as still) within this
MIN_SETTLE_TOLERANCE = 0.0005   # rad: ... or within a third of a smaller move, but never tighter than this
WAYPOINT_MAX_ROTATION = np.radians(10.0)   # rad between the IK waypoints of a straight Cartesian path
RETREAT_HEIGHT = 0.05           # m the gripper rises after a failure


class Motion:
    """Arm motion of a connected ``task.session.RobotSession``."""

    def __init__(self, session):
        self.session = session
        self.log_name = session.log_name

    @property
    def limb(self):
        return self.session.limb

    def move_to_pose(self, T_base_gripper, what, max_intermediate=3):
        """Move the gripper to ``T_base_gripper``: the straight Cartesian path when every waypoint has an IK
        solution on the arm's current branch, else IK for the target (seeded with the current angles, then the
        robot's automatic seeding) and a joint move. If neither finds a solution, the arm first goes to the pose
        halfway there and tries the target again from there, up to ``max_intermediate`` times; IKFailure when
        even that fails."""
        xyz, quat = to_xyz_quat(T_base_gripper)
        rospy.loginfo('%s: %s: gripper to %s mm, quaternion %s' % (self.log_name, what,
                                                                np.round(1000 * xyz, 1).tolist(),
                                                                np.round(quat, 3).tolist()))
        for _ in range(max_intermediate):
            path = self.plan_joints(T_base_gripper, what)
            if path is not None:
                return self.follow_path(path, what)
            q = self.solve_ik(T_base_gripper, what)
            if q is not None:
                return self.move_to_joints(q, what)
            halfway = interpolate_pose(self.limb.endpoint_pose(), T_base_gripper, 0.5)
            q_halfway = self.solve_ik(halfway, what + ' (halfway)')
            if q_halfway is None:
                break
            rospy.logwarn('%s: %s: no IK solution for the target: going halfway first' % (self.log_name, what))
            self.move_to_joints(q_halfway, what + ' (halfway)')
        raise robot.IKFailure('%s: no IK solution for the gripper at %s mm (nor for intermediate poses)'
                              % (what, np.round(1000 * xyz, 1).tolist()))

    def move_up(self, height, what, max_intermediate=3):
        """The gripper ``height`` m straight up from where it is (lift, retreat, back off)."""
        self.move_to_pose(raised(self.limb.endpoint_pose(), height), what, max_intermediate)

    def plan_joints(self, T_base_gripper, what):
        """Joint-space waypoints (dicts) of the straight Cartesian path to ``T_base_gripper`` on the arm's
        current branch: IK every ``waypoint_spacing`` (and 10 deg at most), each seeded with the previous
        solution. Followed without stopping, the gripper stays within a millimetre or so of the straight
        line (a descent cannot swing the fingers into the block, even near the elbow's singularity).
        None when a waypoint has no solution, or when one jumps to another branch (a joint turning more than the
        safety's joint step between two waypoints, e.g. the wrist past its limit: a joint move instead)."""
        T_start = self.limb.endpoint_pose()
        translation, rotation = pose_error(T_start, T_base_gripper)
        spacing = self.session.config.waypoint_spacing
        count = max(1, int(np.ceil(max(translation / spacing, rotation / WAYPOINT_MAX_ROTATION))))
        path = [self.limb.joint_angles()]
        for k in range(1, count + 1):
            try:
                path.append(self.limb.solve_ik(interpolate_pose(T_start, T_base_gripper, k / count), seed=path[-1]))
            except robot.IKFailure as error:
                rospy.logwarn('%s: %s: waypoint %d/%d has no IK solution on this branch (%s)'
                              % (self.log_name, what, k, count, error))
                return None
            jump = max(abs(path[-1][name] - path[-2][name]) for name in path[-1])
            if jump > self.session.safety.limits.max_joint_step:
                rospy.logwarn('%s: %s: waypoint %d/%d is on another IK branch (a joint turns %.2f rad)'
                              % (self.log_name, what, k, count, jump))
                return None
        return path[1:]

    def solve_ik(self, T_base_gripper, what):
        """Joint angles for ``T_base_gripper`` from the IK service (seeded with the current angles, then the
        robot's automatic seeding), or None when neither finds a solution."""
        for seed, description in ((self.limb.joint_angles(), 'current angles'), (None, 'automatic seed')):
            try:
                return self.limb.solve_ik(T_base_gripper, seed=seed)
            except robot.IKFailure as error:
                rospy.logwarn('%s: %s: no IK solution with the %s (%s)' % (self.log_name, what, description, error))
        return None

    def move_to_joints(self, q, what):
        """Safety-checked position move along the straight joint-space line to ``q`` (rad by joint name), cut
        into segments of at most the safety's joint step (a start-pose move is longer than one servo step) along
        which the gripper tip travels at most half the safety's Cartesian step (a long move across the table)."""
        q_start = self.limb.joint_angles()
        names = list(q_start)
        q_target = np.array([q[name] for name in names], dtype=float)
        q_from = np.array([q_start[name] for name in names], dtype=float)
        limits, kinematics = self.session.safety.limits, self.session.kinematics
        order = [names.index(name) for name in kinematics.joint_names]
        tips = [kinematics.fk((q_from + (q_target - q_from) * s)[order])[:3, 3] for s in np.linspace(0, 1, 21)]
        tip_travel = sum(np.linalg.norm(b - a) for a, b in zip(tips, tips[1:]))
        segments = max(1, int(np.ceil(np.max(np.abs(q_target - q_from)) / limits.max_joint_step)),
                       int(np.ceil(tip_travel / (0.5 * limits.max_cartesian_step))))
        rospy.loginfo('%s: %s: joint move in %d segment(s)' % (self.log_name, what, segments))
        self.follow_path([dict(zip(names, q_from + (q_target - q_from) * k / segments))
                          for k in range(1, segments + 1)], what)

    def follow_path(self, waypoints, what):
        """Stream a joint-space path (safety-checked segment by segment), watching the robot's state.

        Arrival needs every joint within SETTLE_TOLERANCE of the end, or within a third of the move's largest
        joint change when that is smaller (a small servo step must actually be made)."""
        timeout = 10.0 + 2.0 * len(waypoints)
        start = self.limb.joint_angles()
        change = max(abs(waypoints[-1][name] - start[name]) for name in start)
        tolerance = max(MIN_SETTLE_TOLERANCE, min(SETTLE_TOLERANCE, change / 3.0))
        if not self.limb.follow_joint_path(waypoints, timeout=timeout, tolerance=tolerance,
                                           check=self.session.check_robot):
            raise TaskFailure('motion_timeout', '%s: the arm did not arrive' % what)

    def retreat(self, reason):
        """After a failure: open the gripper unless it holds something, stop velocity control and move up
        ``RETREAT_HEIGHT`` if that is safe. After an e-stop or a disable nothing at all is commanded; without
        the IK service the arm stays where it is (no wait for the service). Never raises: a retreat that fails
        is logged."""
        session = self.session
        if reason in ('robot_stopped', 'robot_disabled'):
            rospy.loginfo('%s: the robot is stopped: nothing more is commanded' % self.log_name)
            return
        try:
            if session.gripper is not None and not session.gripper.gripping():
                session.gripper.open(block=False)
            if session.limb is not None:
                session.limb.exit_control_mode()
                if reason == 'service_unavailable':
                    rospy.logwarn('%s: no IK service: the arm stays where it is' % self.log_name)
                    return
                self.move_up(RETREAT_HEIGHT, 'retreat', max_intermediate=1)
        except (TaskFailure, robot.RobotError, ValueError) as error:     # UnsafeCommand is a ValueError
            rospy.logwarn('%s: could not retreat after the failure: %s' % (self.log_name, error))
