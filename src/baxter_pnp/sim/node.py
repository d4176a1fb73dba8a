"""The fake Baxter ROS node: serves the real robot's topics and services from a PyBullet ``SimWorld``.

One node, ``fake_baxter``, emulates what the Baxter SDK 1.2.0 clients use (reference/baxter_interfaces.md,
section 10) for the left arm, and publishes the right arm's joints too. It owns simulated time: each
loop iteration advances the physics by one fixed step, publishes ``/clock`` and whatever is due in
simulated time (``clock.RateSchedule``), then sleeps just enough to run at ``--real-time-factor``
(``clock.RealTimePacer``). Rates therefore hold in simulated time whatever the CPU speed; a slow CPU
only lowers the achieved real-time factor.

Names: the SDK's topic, service and frame names and constants come from ``baxter_pnp.robot.sdk``, which
the robot clients use too; nothing else of ``baxter_pnp.robot`` is imported here.

Threading: rospy runs subscriber and service callbacks in their own threads while PyBullet belongs
to the main loop. Subscriber callbacks only queue work (``self._inbox``) that the loop executes between
steps; the IK service uses its own ``ArmKinematics`` (own PyBullet client, own lock) and the last joint
angles published; the camera services only touch ``CameraBank`` under its lock.

Faults (``scene.faults``, ``sim.faults``; docs/fake_baxter.md "Fault injection") acted out here: camera
frame drops, latency, stall, blackout and brightness; IK failures and an absent IK service; delayed
joint commands; the e-stop at a given time. Random decisions draw from generators seeded with ``seed``.

docs/fake_baxter.md lists every topic and service, the options, and how this differs from the
official Gazebo simulator. Run it with ``rosrun baxter_pnp fake_baxter.py`` or
``roslaunch baxter_pnp fake_baxter.launch``.
"""
import argparse
import collections
import dataclasses
import errno
import math
import os
import sys
import threading
import xml.etree.ElementTree as ElementTree

import numpy as np
import rosgraph
import rospy
import yaml
from geometry_msgs.msg import Pose, PoseArray, TransformStamped
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import CameraInfo, Image, JointState, Range
from std_msgs.msg import Bool, Empty, Float64, Header, UInt32
from tf2_msgs.msg import TFMessage

from baxter_pnp.kinematics import DEFAULT_URDF, ArmKinematics
from baxter_pnp.msgs import msg, srv
from baxter_pnp.robot import sdk
from baxter_pnp.ros_image import bgr_to_msg
from baxter_pnp.sim import fastmath
from baxter_pnp.sim.cameras import (MAX_OPEN_CAMERAS, RESOLUTION_HALF_CONTROL, CameraBank, camera_settings_problem,
                                     image_model, parse_camera_option)
from baxter_pnp.sim.clock import RateSchedule, RealTimePacer
from baxter_pnp.sim.faults import DelayLine
from baxter_pnp.sim.gripper import ElectricGripperProtocol, GripperCommandError
from baxter_pnp.sim.render import RENDERERS, RendererUnavailable
from baxter_pnp.sim.scene import DEFAULT_SCENE_YAML, SceneError, load_faults, load_scene
from baxter_pnp.sim.world import SimWorld
from baxter_pnp.transforms import invert, pose_msg_to_matrix

NODE_NAME = 'fake_baxter'
SOFTWARE_VERSION = '1.2.0'
SIDE = 'left'                                   # the fully emulated arm
LIMB_TOPICS = sdk.limb_topics(SIDE)
GRIPPER_TOPICS = sdk.gripper_topics(SIDE)
IK_SERVICE = sdk.ik_service(SIDE)
RANGE_LINK = sdk.arm_frames(SIDE).hand_range
ENDPOINT_LINK = sdk.arm_frames(SIDE).gripper

# Publication rates in simulated Hz (the real robot publishes its state at 100 Hz; robot_state_publisher
# sends /tf at 50 Hz; ground truth is for tests and benchmarks).
RATES_HZ = {'robot_state': 100.0, 'joint_states': 100.0, 'endpoint_state': 100.0, 'gripper_state': 100.0,
            'range': 100.0, 'tf': 50.0, 'object_poses': 30.0, 'gripper_properties': 1.0}
RANGE_LIMITS = (0.004, 0.4)                     # m, the hand range sensor's min and max range

IMAGE_ENCODINGS = ('bgra8', 'bgr8', 'rgb8', 'mono8')

POSITION_MODE, VELOCITY_MODE = msg.JointCommand.POSITION_MODE, msg.JointCommand.VELOCITY_MODE
TORQUE_MODE, RAW_POSITION_MODE = msg.JointCommand.TORQUE_MODE, msg.JointCommand.RAW_POSITION_MODE
ESTOP_BUTTON_UNPRESSED = msg.AssemblyState.ESTOP_BUTTON_UNPRESSED
ESTOP_SOURCE_NONE, ESTOP_SOURCE_UNKNOWN = msg.AssemblyState.ESTOP_SOURCE_NONE, msg.AssemblyState.ESTOP_SOURCE_UNKNOWN
SEED_AUTO, SEED_USER = srv.SolvePositionIKRequest.SEED_AUTO, srv.SolvePositionIKRequest.SEED_USER
SEED_CURRENT, SEED_NS_MAP = srv.SolvePositionIKRequest.SEED_CURRENT, srv.SolvePositionIKRequest.SEED_NS_MAP
RESULT_INVALID = srv.SolvePositionIKResponse.RESULT_INVALID
IK_MAP_SEEDS = 30                               # random seeds of our stand-in for the robot's null-space map


# ================================================================================ pure parts (no ROS)
class RobotEnableState:
    """The robot's AssemblyState and its reaction to set_super_enable / reset / stop (interfaces §2).

    Unlike the official simulator, ``ready`` is true, and an enable request while stopped is refused
    (baxter_interface resets before enabling a stopped robot, as it must on the real one).
    """

    def __init__(self, enabled=False):
        self.ready = True
        self.enabled = bool(enabled)
        self.stopped = False
        self.error = False
        self.estop_button = ESTOP_BUTTON_UNPRESSED
        self.estop_source = ESTOP_SOURCE_NONE

    def request_enable(self, enable):
        """Enable (True) or disable (False); returns False when an enable is refused because stopped."""
        if enable and self.stopped:
            return False
        self.enabled = bool(enable)
        return True

    def stop(self):
        self.enabled, self.stopped = False, True
        self.estop_button, self.estop_source = ESTOP_BUTTON_UNPRESSED, ESTOP_SOURCE_UNKNOWN

    def reset(self):
        self.enabled = self.stopped = self.error = False
        self.estop_button, self.estop_source = ESTOP_BUTTON_UNPRESSED, ESTOP_SOURCE_NONE

    def fields(self):
        """Field values of the AssemblyState message."""
        return {'ready': self.ready, 'enabled': self.enabled, 'stopped': self.stopped, 'error': self.error,
                'estop_button': self.estop_button, 'estop_source': self.estop_source}


def parse_joint_command(mode, names, command, joint_names):
    """Validated ``{joint: value}`` of a JointCommand for an arm with ``joint_names``; ValueError otherwise.

    Rejects unknown modes, unknown or repeated joint names, a length mismatch and NaN/inf values.
    """
    if mode not in (POSITION_MODE, VELOCITY_MODE, TORQUE_MODE, RAW_POSITION_MODE):
        raise ValueError(f'unknown mode {mode} (expected 1 position, 2 velocity, 3 torque or 4 raw position)')
    names, command = list(names), list(command)
    if len(names) != len(command):
        raise ValueError(f'{len(names)} names but {len(command)} command values')
    unknown = [n for n in names if n not in joint_names]
    if unknown:
        raise ValueError(f'unknown joint name(s) {unknown} (expected some of {list(joint_names)})')
    if len(set(names)) != len(names):
        raise ValueError(f'repeated joint names in {names}')
    bad = [n for n, v in zip(names, command) if not math.isfinite(v)]
    if bad:
        raise ValueError(f'non-finite command value for {bad}')
    return dict(zip(names, (float(v) for v in command)))


class ArmCommander:
    """Turns validated JointCommands into ``SimWorld`` arm commands for one side.

    Position and raw-position targets are followed at ``speed_ratio`` x the velocity limits (a new ratio
    applies to the current targets at once). Velocity commands hold for ``command_timeout`` simulated
    seconds; after that the arm falls back to holding its current angles, as on the real robot.
    """

    def __init__(self, world, side):
        self.world, self.side = world, side
        self.joint_names = list(world.arm_joint_names(side))
        self.speed_ratio = sdk.DEFAULT_SPEED_RATIO
        self.command_timeout = sdk.COMMAND_TIMEOUT
        self.mode = None                 # None = holding
        self._last_velocity_command = None

    def command(self, mode, values, now):
        """Send validated ``values`` ({joint: rad or rad/s}) of a JointCommand ``mode`` at time ``now`` (s).

        Position targets of joints not named are kept (the world keeps them); velocities of joints not
        named are 0.
        """
        if mode in (POSITION_MODE, RAW_POSITION_MODE):
            self.mode = POSITION_MODE
            self.world.command_arm_positions(self.side, values, speed_ratio=self.speed_ratio)
        elif mode == VELOCITY_MODE:
            self.mode = VELOCITY_MODE
            self._last_velocity_command = now
            self.world.command_arm_velocities(self.side, {j: values.get(j, 0.0) for j in self.joint_names})

    def set_speed_ratio(self, ratio):
        self.speed_ratio = min(max(float(ratio), 0.0), 1.0)
        if self.mode == POSITION_MODE:
            self.world.command_arm_positions(self.side, {}, speed_ratio=self.speed_ratio)

    def set_command_timeout(self, timeout):
        if not (math.isfinite(timeout) and timeout > 0):
            raise ValueError(f'joint command timeout must be a positive number of seconds, got {timeout}')
        self.command_timeout = float(timeout)

    def hold(self):
        """Hold the current angles (timeout, disable, stop)."""
        self.mode = None
        self.world.hold_arm(self.side)

    def tick(self, now):
        """Apply the command timeout at simulated time ``now`` (s); True when it just expired."""
        if self.mode == VELOCITY_MODE and now - self._last_velocity_command > self.command_timeout:
            self.hold()
            return True
        return False


def urdf_tree(urdf_text):
    """[(parent link, child link, joint type)] of every joint of a URDF document."""
    root = ElementTree.fromstring(urdf_text)
    return [(j.find('parent').get('link'), j.find('child').get('link'), j.get('type')) for j in root.iter('joint')]


def seed_vector(joint_state, joint_names, current):
    """Arm angles (7,) from a seed JointState: named joints, others from ``current`` (dict name -> rad).

    A seed without names but with 7 positions is taken in ``joint_names`` order.
    """
    if not joint_state.name and len(joint_state.position) == len(joint_names):
        return np.array(joint_state.position, dtype=float)
    given = dict(zip(joint_state.name, joint_state.position))
    return np.array([given.get(name, current[name]) for name in joint_names], dtype=float)


def ik_stages(seed_mode, user_seed, current):
    """[(result_type, seed or None)] to try for one pose, per interfaces §6 / simulator notes §3.

    SEED_AUTO tries the user seed (if any), the current angles, then the null-space map (here: neutral
    and ``IK_MAP_SEEDS`` reproducible random seeds); SEED_USER only the user seed; SEED_CURRENT only
    the current angles; SEED_NS_MAP only the map.
    """
    if seed_mode not in (SEED_AUTO, SEED_USER, SEED_CURRENT, SEED_NS_MAP):
        raise ValueError(f'unknown seed_mode {seed_mode}')
    if seed_mode == SEED_USER and user_seed is None:
        raise ValueError('seed_mode SEED_USER needs seed_angles')
    stages = []
    if user_seed is not None and seed_mode in (SEED_AUTO, SEED_USER):
        stages.append((SEED_USER, user_seed))
    if seed_mode in (SEED_AUTO, SEED_CURRENT):
        stages.append((SEED_CURRENT, current))
    if seed_mode in (SEED_AUTO, SEED_NS_MAP):
        stages.append((SEED_NS_MAP, None))
    return stages


# ================================================================================ the ROS node
class FakeBaxterNode:
    """Publishes, subscribes and serves Baxter's interfaces around a ``SimWorld``; ``run()`` is the loop."""

    def __init__(self, world, urdf_text, real_time_factor=1.0, image_encoding='bgra8', enable=False,
                 open_cameras=(), seed=0):
        self.world = world
        self.image_encoding = image_encoding
        self.faults = world.scene.faults
        # Independent streams, so that e.g. the IK calls an application makes do not change the image noise.
        self._noise_rng, self._frame_fault_rng, self._ik_fault_rng = (
            np.random.default_rng([seed, stream]) for stream in range(3))
        self._inbox = collections.deque()        # callables queued by ROS threads, run by the loop
        self._delayed_commands = DelayLine(self.faults.joint_command_delay)   # JointCommands not yet applied
        self._delayed_frames = DelayLine(self.faults.camera.latency)           # (name, Image, CameraInfo) captured
        self._estop_done = False
        self.robot = RobotEnableState(enabled=enable)
        self.arm = ArmCommander(world, SIDE)
        self.gripper = ElectricGripperProtocol(
            lambda position, force, velocity: world.command_gripper(SIDE, position, force, velocity))
        self.cameras = CameraBank()
        self._kinematics = ArmKinematics(SIDE)
        self._kinematics_lock = threading.Lock()
        self._tree = urdf_tree(urdf_text)
        self._moving_joints = [(p, c) for p, c, kind in self._tree if kind != 'fixed']
        self._tf_edges = {}                          # {child: (parent, T_parent_child)} last published
        self._current_angles = dict(zip(self.arm.joint_names, self._arm_angles()))
        self.pacer = RealTimePacer(real_time_factor)
        self._schedules = [(RateSchedule(RATES_HZ[key]), getattr(self, '_publish_' + key)) for key in RATES_HZ]
        for name, width, height, fps in open_cameras:
            world.prepare_camera(image_model(name, width, height))
            self.cameras.open(name, width, height, fps, now=0.0)
            world.start_fault_clock()

        rospy.set_param('/rethink/software_version', SOFTWARE_VERSION)
        rospy.set_param('/robot_description', urdf_text)
        latched = dict(queue_size=1, latch=True)
        self._pub = {
            'clock': rospy.Publisher('/clock', Clock, queue_size=10),
            'robot_state': rospy.Publisher(sdk.ROBOT_STATE_TOPIC, msg.AssemblyState, queue_size=10),
            'joint_states': rospy.Publisher(sdk.JOINT_STATES_TOPIC, JointState, queue_size=10),
            'endpoint_state': rospy.Publisher(LIMB_TOPICS.endpoint_state, msg.EndpointState, queue_size=10),
            'gripper_state': rospy.Publisher(GRIPPER_TOPICS.state, msg.EndEffectorState, queue_size=10),
            'gripper_properties': rospy.Publisher(GRIPPER_TOPICS.properties, msg.EndEffectorProperties,
                                                  **latched),
            'range': rospy.Publisher(sdk.range_topic(SIDE), Range, queue_size=10),
            'tf': rospy.Publisher('/tf', TFMessage, queue_size=10),
            'tf_static': rospy.Publisher('/tf_static', TFMessage, **latched),
            'object_poses': rospy.Publisher('~object_poses', PoseArray, queue_size=10),
            'respawns': rospy.Publisher('~respawns', UInt32, **latched),
        }
        self._respawns_published = None
        self._publish_respawns()
        self._image_pubs = {}

        def queued(handler):
            return lambda message: self._inbox.append(lambda: handler(message))

        rospy.Subscriber(sdk.ENABLE_TOPIC, Bool, queued(self._on_enable), queue_size=10)
        rospy.Subscriber(sdk.RESET_TOPIC, Empty, queued(self._on_reset), queue_size=10)
        rospy.Subscriber(sdk.STOP_TOPIC, Empty, queued(self._on_stop), queue_size=10)
        rospy.Subscriber(LIMB_TOPICS.joint_command, msg.JointCommand, queued(self._on_joint_command),
                         queue_size=10, tcp_nodelay=True)
        rospy.Subscriber(LIMB_TOPICS.speed_ratio, Float64, queued(self._on_speed_ratio), queue_size=10)
        rospy.Subscriber(LIMB_TOPICS.command_timeout, Float64, queued(self._on_command_timeout),
                         queue_size=10)
        rospy.Subscriber(GRIPPER_TOPICS.command, msg.EndEffectorCommand, queued(self._on_gripper_command),
                         queue_size=10)
        if not self.faults.ik.absent:
            rospy.Service(IK_SERVICE, srv.SolvePositionIK, self._solve_ik)
        rospy.Service(sdk.CAMERAS_LIST_SERVICE, srv.ListCameras,
                      lambda request: srv.ListCamerasResponse(self.cameras.list()))
        rospy.Service(sdk.CAMERAS_OPEN_SERVICE, srv.OpenCamera, self._open_camera)
        rospy.Service(sdk.CAMERAS_CLOSE_SERVICE, srv.CloseCamera,
                      lambda request: srv.CloseCameraResponse(self.cameras.close(request.name)))
        self._publish_tf_static()

    # ------------------------------------------------------------------ main loop
    def run(self):
        """Step, publish and pace until rospy shuts down."""
        ready_pub = None
        while not rospy.is_shutdown():
            while self._inbox:
                self._inbox.popleft()()
            now = self.world.time
            for apply_command in self._delayed_commands.due(now):
                apply_command()
            self._inject_estop(self.world.fault_time(now))
            if self.arm.tick(now):
                rospy.logdebug('velocity command timed out: holding position')
            self._publish_due(now)
            if ready_pub is None:
                ready_pub = self._announce_ready()
            self.world.step()
            self._pub['clock'].publish(Clock(clock=rospy.Time.from_sec(self.world.time)))
            self._publish_respawns()
            self.pacer.pace(self.world.time)
        rospy.loginfo('fake_baxter: stopped after %.1f s of simulated time (real-time factor %.2f)',
                      self.world.time, self.pacer.measured_factor())

    def _announce_ready(self):
        """Latch /robot/sim/started (as the official simulator does) and log the one 'ready' line."""
        publisher = rospy.Publisher('/robot/sim/started', Empty, queue_size=1, latch=True)
        publisher.publish(Empty())
        age = _process_age()
        boot = '' if age is None else f' {age:.1f} s after start'
        cameras = [name for name in sdk.CAMERA_NAMES if self.cameras.is_open(name)]
        rospy.loginfo('fake_baxter ready%s: robot %s, cameras open: %s, real-time factor %s, faults: %s', boot,
                      'enabled' if self.robot.enabled else 'disabled (publish True on /robot/set_super_enable)',
                      ', '.join(cameras) or 'none',
                      'as fast as possible' if self.pacer.real_time_factor == 0 else
                      f'{self.pacer.real_time_factor:g}', self.faults.summary())
        return publisher

    def _inject_estop(self, now):
        """The ``estop_at`` fault: stop the robot once, as ``/robot/set_super_stop`` does."""
        if self.faults.estop_at is not None and not self._estop_done and now >= self.faults.estop_at:
            self._estop_done = True
            rospy.logwarn(f'fault injected: robot stopped at {now:.3f} s (estop_at {self.faults.estop_at:g} s)')
            self._on_stop(None)

    def _publish_due(self, now):
        for schedule, publish in self._schedules:
            if schedule.due(now):
                publish(self._stamp(now))
        for name, cam in self.cameras.due(now):
            self._capture_camera(name, cam, now)
        for name, image, info in self._delayed_frames.due(now):
            if self.cameras.is_open(name):
                self._image_publishers(name)[0].publish(image)
                self._image_publishers(name)[1].publish(info)

    @staticmethod
    def _stamp(now):
        return Header(stamp=rospy.Time.from_sec(now))

    def _arm_angles(self):
        positions, _, _ = self.world.joint_state()
        index = {name: i for i, name in enumerate(self.world.joint_names())}
        return [float(positions[index[name]]) for name in self.arm.joint_names]

    # ------------------------------------------------------------------ robot state and arm commands
    def _on_enable(self, message):
        if self.robot.request_enable(message.data):
            if not message.data:
                self.arm.hold()
        else:
            rospy.logwarn_throttle(2.0, 'enable refused: the robot is stopped (reset it first)')

    def _on_reset(self, message):
        self.robot.reset()
        self.arm.hold()

    def _on_stop(self, message):
        self.robot.stop()
        self.arm.hold()

    def _on_joint_command(self, message):
        try:
            values = parse_joint_command(message.mode, message.names, message.command, self.arm.joint_names)
        except ValueError as error:
            rospy.logerr_throttle_identical(1.0, f'{LIMB_TOPICS.joint_command} ignored: {error}')
            return
        self._delayed_commands.put(self.world.time, lambda: self._apply_joint_command(message.mode, values))

    def _apply_joint_command(self, mode, values):
        """Execute a validated JointCommand (after the ``joint_command_delay`` fault, if any)."""
        if not self.robot.enabled:
            rospy.logwarn_throttle(2.0, f'{LIMB_TOPICS.joint_command} ignored: the robot is not enabled')
            return
        if mode == TORQUE_MODE:
            rospy.logwarn_throttle(2.0, f'{LIMB_TOPICS.joint_command}: torque mode is not emulated (ignored)')
            return
        self.arm.command(mode, values, self.world.time)

    def _on_speed_ratio(self, message):
        if not math.isfinite(message.data):
            rospy.logerr(f'{LIMB_TOPICS.speed_ratio} ignored: {message.data}')
            return
        self.arm.set_speed_ratio(message.data)

    def _on_command_timeout(self, message):
        try:
            self.arm.set_command_timeout(message.data)
        except ValueError as error:
            rospy.logerr(f'{LIMB_TOPICS.command_timeout} ignored: {error}')

    def _on_gripper_command(self, message):
        try:
            self.gripper.handle_command(message.command, message.args, message.sender, message.sequence)
        except GripperCommandError as error:
            rospy.logwarn(f'{GRIPPER_TOPICS.command}: {error}')

    # ------------------------------------------------------------------ periodic publications
    def _publish_robot_state(self, header):
        self._pub['robot_state'].publish(msg.AssemblyState(**self.robot.fields()))

    def _publish_joint_states(self, header):
        positions, velocities, efforts = self.world.joint_state()
        message = JointState(header=header, name=list(self.world.joint_names()),
                             position=[float(v) for v in positions], velocity=[float(v) for v in velocities],
                             effort=[float(v) for v in efforts])
        self._current_angles = {name: message.position[i] for i, name in enumerate(message.name)
                                if name in self.arm.joint_names}
        self._pub['joint_states'].publish(message)

    def _publish_endpoint_state(self, header):
        header.frame_id = sdk.BASE_FRAME
        message = msg.EndpointState(header=header)
        fastmath.matrix_to_pose_msg(self.world.link_pose(ENDPOINT_LINK), message.pose)
        twist = self.world.link_twist(ENDPOINT_LINK)
        (message.twist.linear.x, message.twist.linear.y, message.twist.linear.z,
         message.twist.angular.x, message.twist.angular.y, message.twist.angular.z) = (float(v) for v in twist)
        self._pub['endpoint_state'].publish(message)

    def _publish_gripper_state(self, header):
        self.gripper.update(self.world.time, self.world.gripper_state(SIDE))
        fields = self.gripper.state()
        fields['timestamp'] = header.stamp
        self._pub['gripper_state'].publish(msg.EndEffectorState(**fields))

    def _publish_gripper_properties(self, header):
        self._pub['gripper_properties'].publish(msg.EndEffectorProperties(**self.gripper.properties()))

    def _publish_range(self, header):
        header.frame_id = RANGE_LINK
        distance = self.world.range_at(RANGE_LINK, *RANGE_LIMITS)
        self._pub['range'].publish(Range(header=header, radiation_type=Range.INFRARED, field_of_view=0.0,
                                         min_range=RANGE_LIMITS[0], max_range=RANGE_LIMITS[1],
                                         range=float(distance)))

    def _link_poses(self, links):
        """{link: T_base_link} from the world (``base`` is the identity)."""
        poses = self.world.link_poses([link for link in links if link != sdk.BASE_FRAME])
        return {link: np.eye(4) if link == sdk.BASE_FRAME else poses[link] for link in links}

    def _publish_tf(self, header):
        poses = self._link_poses({link for joint in self._moving_joints for link in joint})
        moving = {child: (parent, invert(poses[parent]) @ poses[child]) for parent, child in self._moving_joints}
        self._tf_edges = dict(self._tf_edges, **moving)
        self._pub['tf'].publish(TFMessage(transforms=[
            self._transform(header, parent, child, T) for child, (parent, T) in moving.items()]))

    def _publish_tf_static(self):
        """Fixed joints, once, latched (computed from the world's link poses at boot)."""
        header = self._stamp(self.world.time)
        poses = self._link_poses({link for parent, child, _ in self._tree for link in (parent, child)})
        self._tf_edges = {child: (parent, invert(poses[parent]) @ poses[child]) for parent, child, _ in self._tree}
        self._pub['tf_static'].publish(TFMessage(transforms=[
            self._transform(header, parent, child, self._tf_edges[child][1])
            for parent, child, kind in self._tree if kind == 'fixed']))

    def _T_base(self, frame):
        """T_base_frame composed from the last published transforms, or None for an unknown frame."""
        edges = self._tf_edges
        T = np.eye(4)
        while frame != sdk.BASE_FRAME:
            if frame not in edges:
                return None
            frame, T_parent_child = edges[frame]
            T = T_parent_child @ T
        return T

    @staticmethod
    def _transform(header, parent, child, T_parent_child):
        pose = fastmath.matrix_to_pose_msg(T_parent_child, Pose())
        message = TransformStamped()
        message.header.stamp, message.header.frame_id, message.child_frame_id = header.stamp, parent, child
        message.transform.translation.x = pose.position.x
        message.transform.translation.y = pose.position.y
        message.transform.translation.z = pose.position.z
        message.transform.rotation = pose.orientation
        return message

    def _publish_object_poses(self, header):
        header.frame_id = sdk.BASE_FRAME
        self._pub['object_poses'].publish(PoseArray(
            header=header, poses=[fastmath.matrix_to_pose_msg(T, Pose()) for T in self.world.object_poses()]))

    def _publish_respawns(self):
        """Latch the world's respawn count (ground truth, ``scene.respawn``) when it changed; log each respawn."""
        count = self.world.respawns
        if count == self._respawns_published:
            return
        if count:
            respawn = self.world.scene.respawn
            x, y, z = self.world.object_poses()[respawn.object][:3, 3]
            rospy.loginfo(f'respawn {count}: objects[{respawn.object}] put back on the table at '
                          f'({x:.3f}, {y:.3f}, {z:.3f}) m at {self.world.time:.2f} s')
        self._respawns_published = count
        self._pub['respawns'].publish(UInt32(count))

    # ------------------------------------------------------------------ cameras
    def _open_camera(self, request):
        settings = request.settings
        half = any(c.id == RESOLUTION_HALF_CONTROL and c.value > 0 for c in settings.controls)
        if not camera_settings_problem(request.name, settings.width, settings.height, settings.fps, half):
            # here, not at the first frame, where it would stall the loop
            self.world.prepare_camera(image_model(request.name, settings.width, settings.height, half))
        now = self.world.time               # one instant for the frame grid and the fault clock
        err, reason = self.cameras.open(request.name, settings.width, settings.height, settings.fps, now, half)
        if err:
            rospy.logwarn(f'{sdk.CAMERAS_OPEN_SERVICE} {request.name} refused ({errno.errorcode[err]}): {reason}')
        else:
            self.world.start_fault_clock(now)
            self._image_publishers(request.name)      # advertised now, not by the loop at the first frame
        return srv.OpenCameraResponse(err)

    def _image_publishers(self, name):
        """(image, camera_info) publishers of camera ``name``, advertised when first needed."""
        if name not in self._image_pubs:
            image_topic, info_topic = sdk.camera_topics(name)
            # 10 frames queued per subscriber: unpaced, the fake can publish faster than a busy subscriber reads
            self._image_pubs[name] = (rospy.Publisher(image_topic, Image, queue_size=10),
                                      rospy.Publisher(info_topic, CameraInfo, queue_size=10))
        return self._image_pubs[name]

    def _capture_camera(self, name, cam, now):
        """Render the frame due at ``now`` (s) and queue it for publication after the camera latency fault;
        the frame-drop, stall, blackout and brightness faults apply here."""
        camera_faults = self.faults.camera
        if not camera_faults.publishes(self.world.fault_time(now), self._frame_fault_rng.random()):
            return
        header = Header(stamp=rospy.Time.from_sec(now), frame_id='/' + name)     # as the robot: leading /
        image = self.world.render_camera(name, cam.model, self._noise_rng,
                                         gain=camera_faults.gain(self.world.fault_time(now)))
        self._delayed_frames.put(now, (name, bgr_to_msg(image, self.image_encoding, header),
                                       cam.camera_info(header)))

    # ------------------------------------------------------------------ IK service
    def _solve_ik(self, request):
        """SolvePositionIK: one JointState, isValid and result_type per requested pose (see ``ik_stages``).

        A pose the IK faults fail (``IKFaults.fails``: one draw per pose) is answered like an unreachable one."""
        names = self.arm.joint_names
        current_map = dict(self._current_angles)
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
                    rospy.loginfo_throttle(1.0, f'{IK_SERVICE}: fault injected, pose at '
                                                f'{np.round(T_base_target[:3, 3], 3).tolist()} m marked invalid')
                elif T_base_target is not None:
                    for stage_type, seed in stages:
                        solution = self._kinematics.ik(T_base_target, seed=seed,
                                                       n_random_seeds=0 if seed is not None else IK_MAP_SEEDS)
                        if solution is not None:
                            result_type = stage_type
                            break
            solution_state = JointState(name=list(names), position=[] if solution is None else list(solution))
            solution_state.header.stamp = rospy.Time.from_sec(self.world.time)
            joints.append(solution_state)
            valid.append(solution is not None)
            result_types.append(result_type)
        return srv.SolvePositionIKResponse(joints=joints, isValid=valid, result_type=result_types)

    def _pose_in_base(self, pose_stamped):
        """T_base_target of a PoseStamped in 'base' (or '') or any URDF frame; None for an unknown frame."""
        frame = pose_stamped.header.frame_id.lstrip('/') or sdk.BASE_FRAME
        T_base_frame = self._T_base(frame)
        if T_base_frame is None:
            rospy.logwarn(f'{IK_SERVICE}: unknown frame {frame!r}, pose marked invalid')
            return None
        return T_base_frame @ pose_msg_to_matrix(pose_stamped.pose)


# ================================================================================ entry point
def _process_age():
    """Wall seconds since this process started (Linux /proc), or None where that is unavailable."""
    try:
        with open('/proc/self/stat') as f:
            start_ticks = int(f.read().rsplit(')', 1)[1].split()[19])   # field 22: starttime
        with open('/proc/uptime') as f:
            uptime = float(f.read().split()[0])
    except (OSError, ValueError, IndexError):
        return None
    return uptime - start_ticks / os.sysconf('SC_CLK_TCK')


def parse_args(argv):
    parser = argparse.ArgumentParser(prog='fake_baxter.py', description=(
        'A PyBullet "fake Baxter" serving the robot\'s ROS interfaces (SDK 1.2.0) for the left arm, '
        'its gripper, cameras and range sensor, in simulated time.'))
    parser.add_argument('--scene', default=DEFAULT_SCENE_YAML,
                        help='scene YAML (table, blocks, start pose, camera error, faults); default %(default)s')
    parser.add_argument('--faults', metavar='FILE',
                        help="YAML file with a 'faults:' key (as in a scene), replacing the scene's faults")
    parser.add_argument('--enable', action='store_true', help='boot with the robot enabled')
    parser.add_argument('--start-pose', choices=('down', 'angled', 'neutral'),
                        help="left-arm start pose, overriding the scene's 'start'")
    parser.add_argument('--real-time-factor', type=float, default=1.0,
                        help='simulated seconds per wall second (0 = as fast as possible); default %(default)s')
    parser.add_argument('--image-encoding', choices=IMAGE_ENCODINGS, default='bgra8',
                        help='encoding of the camera images (the real hand cameras publish bgra8)')
    parser.add_argument('--open-camera', action='append', type=parse_camera_option, default=[],
                        metavar='NAME:WxH[@FPS]', help='open a camera at boot, e.g. left_hand_camera:640x400@20 '
                                                      '(repeatable, at most two)')
    parser.add_argument('--seed', type=int, default=0,
                        help='seed of the image noise and of the random faults; default %(default)s')
    parser.add_argument('--renderer', choices=RENDERERS, default='auto',
                        help='what draws the cameras: OpenGL through EGL (~5 ms a 640x400 frame) or PyBullet\'s '
                             'TinyRenderer (~75 ms); auto: EGL where it works, else TinyRenderer; default %(default)s')
    args = parser.parse_args(argv)
    if args.real_time_factor < 0 or not math.isfinite(args.real_time_factor):
        parser.error('--real-time-factor must be >= 0')
    if args.seed < 0:
        parser.error('--seed must be >= 0')
    if len({c[0] for c in args.open_camera}) > MAX_OPEN_CAMERAS:
        parser.error(f'at most {MAX_OPEN_CAMERAS} cameras can be open at once')
    return args


def main(argv=None):
    """Entry point of ``scripts/fake_baxter.py``: parse options, load the scene, run the node."""
    args = parse_args(rospy.myargv(sys.argv if argv is None else argv)[1:])
    try:
        scene = load_scene(args.scene)
        if args.faults:
            scene = scene.with_faults(load_faults(args.faults))
    except (SceneError, OSError, yaml.YAMLError) as error:
        print(f'fake_baxter: error: bad scene: {error}', file=sys.stderr)
        sys.exit(2)
    if args.start_pose:
        scene = dataclasses.replace(scene, start=args.start_pose)
    try:
        world = SimWorld(scene, urdf_path=DEFAULT_URDF, renderer=args.renderer)
    except RendererUnavailable as error:
        print(f'fake_baxter: error: --renderer {args.renderer}: {error}', file=sys.stderr)
        sys.exit(2)
    with open(DEFAULT_URDF) as f:
        urdf_text = f.read()
    # The fake Baxter owns the clock: every node (this one included) runs on /clock.
    try:
        rosgraph.Master('/' + NODE_NAME).setParam('/use_sim_time', True)
    except OSError as error:
        print(f'fake_baxter: error: no ROS master at {rosgraph.get_master_uri()} ({error})', file=sys.stderr)
        sys.exit(1)
    rospy.init_node(NODE_NAME)
    rospy.loginfo('fake_baxter: cameras drawn by %s', world.renderer_description)
    node = FakeBaxterNode(world, urdf_text, real_time_factor=args.real_time_factor,
                          image_encoding=args.image_encoding, enable=args.enable,
                          open_cameras=args.open_camera, seed=args.seed)
    node.run()
