"""One arm of the fake Baxter, the ROS edge (as ``baxter_interface.Limb`` sees it, interfaces §3-6): joint commands
in every mode with speed ratio and command timeout, the endpoint state with its twist, the IK service, the hand's
range sensor, and the collision avoidance state with ``suppress_collision_avoidance``.

``LimbNode(side, ...)`` serves ``/robot/limb/<side>/...``, ``/ExternalTools/<side>/PositionKinematicsNode/IKService``
and ``/robot/range/<side>_hand_range/state`` around the ``SimWorld``; ``sim.node.FakeBaxterNode`` makes one per arm.
Threading as in ``sim.node``: subscriber callbacks are queued for the main loop (``queued``); the IK service runs in
its own thread on its own ``ArmKinematics`` under a lock, with the last published joint angles. Units: rad, rad/s,
m, simulated seconds; poses in ``base``.
"""
import math
import threading

import numpy as np
import rospy
from sensor_msgs.msg import JointState, Range
from std_msgs.msg import Empty, Float64

from baxter_pnp.kinematics import ArmKinematics
from baxter_pnp.msgs import msg, srv
from baxter_pnp.robot import sdk
from baxter_pnp.sim import fastmath
from baxter_pnp.sim.publishers import state_publisher
from baxter_pnp.sim.arm import IK_MAP_SEEDS, TORQUE_MODE, ArmCommander, ik_stages, parse_joint_command, seed_vector
from baxter_pnp.transforms import pose_msg_to_matrix

# simulated Hz (the robot publishes its state at 100 Hz)
RATES_HZ = {'endpoint_state': 100.0, 'range': 100.0, 'collision_avoidance_state': 100.0}
RANGE_LIMITS = (0.004, 0.4)                     # m, the hand range sensor's min and max range
RESULT_INVALID = srv.SolvePositionIKResponse.RESULT_INVALID


class LimbNode:
    """The ``side`` arm's topics and IK service. ``robot`` is the shared ``RobotEnableState`` (commands act only
    while enabled); ``delayed_commands`` the ``DelayLine`` of the ``joint_command_delay`` fault; ``ik_fault_rng``
    this arm's generator of IK-fault draws; ``T_base(frame)`` T_base_frame from the published tf (None if unknown);
    ``current_angles()`` {joint: rad} last published; ``ros_time(now)`` the stamp of simulated time ``now`` (s)."""

    def __init__(self, side, world, robot, faults, queued, delayed_commands, ik_fault_rng, T_base, current_angles,
                 ros_time):
        self.side, self.world, self.robot, self.faults = side, world, robot, faults
        self.arm = ArmCommander(world, side)
        self._delayed_commands = delayed_commands
        self._ik_fault_rng = ik_fault_rng
        self._T_base, self._current_angles, self._ros_time = T_base, current_angles, ros_time
        self._kinematics = ArmKinematics(side)
        self._kinematics_lock = threading.Lock()
        self.topics = sdk.limb_topics(side)
        self.ik_service_name = sdk.ik_service(side)
        frames = sdk.arm_frames(side)
        self._endpoint_link, self._range_link = frames.gripper, frames.hand_range
        namespace = f'/robot/limb/{side}'
        self._pub = {
            'endpoint_state': state_publisher(self.topics.endpoint_state, msg.EndpointState),
            'range': state_publisher(sdk.range_topic(side), Range),
            'collision_avoidance_state': state_publisher(f'{namespace}/collision_avoidance_state',
                                                         msg.CollisionAvoidanceState),
        }
        rospy.Subscriber(self.topics.joint_command, msg.JointCommand, queued(self._on_joint_command),
                         queue_size=10, tcp_nodelay=True)
        rospy.Subscriber(self.topics.speed_ratio, Float64, queued(self._on_speed_ratio), queue_size=10)
        rospy.Subscriber(self.topics.command_timeout, Float64, queued(self._on_command_timeout), queue_size=10)
        # tuck_arms.py suppresses the avoidance to fold the arms past the head: accepted, there is none to suppress
        rospy.Subscriber(f'{namespace}/suppress_collision_avoidance', Empty, lambda message: None, queue_size=10)
        if not faults.ik.absent:
            rospy.Service(self.ik_service_name, srv.SolvePositionIK, self._solve_ik)

    def schedules(self):
        """[(rate Hz, publish(header))] of the periodic publications."""
        return [(rate, getattr(self, '_publish_' + key)) for key, rate in RATES_HZ.items()]

    def tick(self, now):
        """The command timeout at simulated time ``now`` (s)."""
        if self.arm.tick(now):
            rospy.logdebug(f'{self.side} arm: velocity command timed out, holding position')

    def hold(self):
        """Hold the current angles (disable, stop, reset)."""
        self.arm.hold()

    # ------------------------------------------------------------------ commands
    def _on_joint_command(self, message):
        try:
            values = parse_joint_command(message.mode, message.names, message.command, self.arm.joint_names)
        except ValueError as error:
            rospy.logerr_throttle_identical(1.0, f'{self.topics.joint_command} ignored: {error}')
            return
        self._delayed_commands.put(self.world.time, lambda: self._apply_joint_command(message.mode, values))

    def _apply_joint_command(self, mode, values):
        """Execute a validated JointCommand (after the ``joint_command_delay`` fault, if any)."""
        if not self.robot.enabled:
            rospy.logwarn_throttle(2.0, f'{self.topics.joint_command} ignored: the robot is not enabled')
            return
        if mode == TORQUE_MODE:
            rospy.logwarn_throttle(2.0, f'{self.topics.joint_command}: torque mode is not emulated (ignored)')
            return
        self.arm.command(mode, values, self.world.time)

    def _on_speed_ratio(self, message):
        if not math.isfinite(message.data):
            rospy.logerr(f'{self.topics.speed_ratio} ignored: {message.data}')
            return
        self.arm.set_speed_ratio(message.data)

    def _on_command_timeout(self, message):
        try:
            self.arm.set_command_timeout(message.data)
        except ValueError as error:
            rospy.logerr(f'{self.topics.command_timeout} ignored: {error}')

    # ------------------------------------------------------------------ periodic publications
    def _publish_endpoint_state(self, header):
        if not self._pub['endpoint_state'].get_num_connections():
            return
        header.frame_id = sdk.BASE_FRAME
        message = msg.EndpointState(header=header)
        twist = self.world.link_twist(self._endpoint_link)
        fastmath.matrix_to_pose_msg(self.world.link_pose(self._endpoint_link), message.pose)
        (message.twist.linear.x, message.twist.linear.y, message.twist.linear.z,
         message.twist.angular.x, message.twist.angular.y, message.twist.angular.z) = (float(v) for v in twist)
        self._pub['endpoint_state'].publish(message)

    def _publish_range(self, header):
        if not self._pub['range'].get_num_connections():
            return
        header.frame_id = self._range_link
        distance = self.world.range_at(self._range_link, *RANGE_LIMITS)
        self._pub['range'].publish(Range(header=header, radiation_type=Range.INFRARED, field_of_view=0.0,
                                         min_range=RANGE_LIMITS[0], max_range=RANGE_LIMITS[1],
                                         range=float(distance)))

    def _publish_collision_avoidance_state(self, header):
        """No avoidance is modelled: never near the other arm, no collision object."""
        if not self._pub['collision_avoidance_state'].get_num_connections():
            return
        self._pub['collision_avoidance_state'].publish(msg.CollisionAvoidanceState(header=header, other_arm=False,
                                                                                   collision_object=[]))

    # ------------------------------------------------------------------ IK service
    def _solve_ik(self, request):
        """SolvePositionIK: one JointState, isValid and result_type per requested pose (see ``ik_stages``).

        A pose the IK faults fail (``IKFaults.fails``: one draw per pose) is answered like an unreachable one."""
        names = self.arm.joint_names
        current_map = self._current_angles()
        current = np.array([current_map[n] for n in names])
        if request.seed_angles and len(request.seed_angles) != len(request.pose_stamp):
            raise rospy.ServiceException(f'{len(request.seed_angles)} seed_angles for '
                                         f'{len(request.pose_stamp)} poses (give one per pose or none)')
        joints, valid, result_types = [], [], []
        for i, pose_stamped in enumerate(request.pose_stamp):
            user_seed = seed_vector(request.seed_angles[i], names, current_map) if request.seed_angles else None
            try:
                stages = ik_stages(request.seed_mode, user_seed, current)
            except ValueError as error:
                raise rospy.ServiceException(str(error))
            solution, result_type = None, RESULT_INVALID
            T_base_target = self._pose_in_base(pose_stamped)
            with self._kinematics_lock:
                fault = self._ik_fault_rng.random()
                if T_base_target is not None and self.faults.ik.fails(T_base_target[:3, 3], fault):
                    rospy.loginfo_throttle(1.0, f'{self.ik_service_name}: fault injected, pose at '
                                                f'{np.round(T_base_target[:3, 3], 3).tolist()} m marked invalid')
                elif T_base_target is not None:
                    for stage_type, seed in stages:
                        solution = self._kinematics.ik(T_base_target, seed=seed,
                                                       n_random_seeds=0 if seed is not None else IK_MAP_SEEDS)
                        if solution is not None:
                            result_type = stage_type
                            break
            solution_state = JointState(name=list(names), position=[] if solution is None else list(solution))
            solution_state.header.stamp = self._ros_time(self.world.time)
            joints.append(solution_state)
            valid.append(solution is not None)
            result_types.append(result_type)
        return srv.SolvePositionIKResponse(joints=joints, isValid=valid, result_type=result_types)

    def _pose_in_base(self, pose_stamped):
        """T_base_target of a PoseStamped in 'base' (or '') or any URDF frame; None for an unknown frame."""
        frame = pose_stamped.header.frame_id.lstrip('/') or sdk.BASE_FRAME
        T_base_frame = self._T_base(frame)
        if T_base_frame is None:
            rospy.logwarn(f'{self.ik_service_name}: unknown frame {frame!r}, pose marked invalid')
            return None
        return T_base_frame @ pose_msg_to_matrix(pose_stamped.pose)
