"""The fake Baxter ROS node: serves the real robot's topics and services from a PyBullet ``SimWorld``.

One node, ``fake_baxter``, emulates what the Baxter SDK 1.2.0 clients and Rethink's own tools use (reference/
baxter_interfaces.md, section 10; docs/fake_baxter.md): it is composed of parts shaped like the robot, each the ROS
edge of a part of it -- ``sim.limb_node`` (each arm: commands, endpoint, IK, range sensor, collision states),
``sim.gripper_node`` (each gripper), ``sim.head_node``, ``sim.io_node`` (digital and analog I/O, navigators),
``sim.cameras_node`` -- around pure cores (``sim.arm``, ``sim.head``, ``sim.io_board``, ``sim.gripper``,
``sim.cameras``, ``sim.assembly``: the enable state and the identity parameters). This module keeps the robot-wide
topics (``/robot/state`` and its enable / reset / stop, ``/robot/joint_states``, ``/tf``, ``/clock``), the ground
truth of tests (``/fake_baxter/...``) and the loop.

Each loop iteration advances the physics by one fixed step, publishes whatever is due in simulated time
(``clock.RateSchedule``), then sleeps just enough to run at ``--real-time-factor`` (``clock.RealTimePacer``). Rates
therefore hold in simulated time whatever the CPU speed; a slow CPU only lowers the achieved real-time factor.
``--clock`` (``clock.MessageClock``) says what its stamps hold: ``wall`` (the default at a real-time factor of 1)
stamps the wall clock, with no ``/clock`` and no ``/use_sim_time``, as a real robot; ``sim`` (the default at any
other factor) publishes ``/clock`` every step and sets ``/use_sim_time``, so every node runs on simulated time.

Names: the SDK's topic, service and frame names and constants come from ``baxter_pnp.robot.sdk``, which
the robot clients use too; nothing else of ``baxter_pnp.robot`` is imported here.

Threading: rospy runs subscriber and service callbacks in their own threads while PyBullet belongs
to the main loop. Subscriber callbacks only queue work (``self._inbox``) that the loop executes between
steps; the IK services use their own ``ArmKinematics`` (own PyBullet client, own lock) and the last joint
angles published; the camera services only touch the camera bank and the image publishers under their locks.

Faults (``scene.faults``, ``sim.faults``; docs/fake_baxter.md "Fault injection") acted out by the parts: camera
frame drops, latency, stall, blackout and brightness (cameras); IK failures and an absent IK service, delayed
joint commands (limbs); the e-stop at a given time (here). Random decisions draw from generators seeded with
``seed``, one stream each (image noise, frame faults, left IK, right IK).

Run it with ``rosrun baxter_pnp fake_baxter.py`` or ``roslaunch baxter_pnp fake_baxter.launch``.
"""
import argparse
import collections
import dataclasses
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
from sensor_msgs.msg import JointState
from std_msgs.msg import Bool, Empty, Header, UInt32
from tf2_msgs.msg import TFMessage

from baxter_pnp.kinematics import DEFAULT_URDF
from baxter_pnp.msgs import msg
from baxter_pnp.robot import sdk
from baxter_pnp.sim import fastmath
from baxter_pnp.sim.publishers import state_publisher
from baxter_pnp.sim.assembly import IDENTITY_PARAMS, RobotEnableState
from baxter_pnp.sim.cameras import MAX_OPEN_CAMERAS, parse_camera_option
from baxter_pnp.sim.cameras_node import CamerasNode
from baxter_pnp.sim.clock import CLOCKS, MessageClock, RateSchedule, RealTimePacer, default_clock
from baxter_pnp.sim.faults import DelayLine
from baxter_pnp.sim.gripper_node import GripperNode
from baxter_pnp.sim.head_node import HeadNode
from baxter_pnp.sim.io_node import IONode
from baxter_pnp.sim.limb_node import RANGE_LIMITS, LimbNode
from baxter_pnp.sim.render import RENDERERS, RendererUnavailable
from baxter_pnp.sim.scene import DEFAULT_SCENE_YAML, SceneError, load_faults, load_scene
from baxter_pnp.sim.world import SimWorld
from baxter_pnp.transforms import invert, relative_transforms

NODE_NAME = 'fake_baxter'
SIDES = ('left', 'right')
# Publication rates in simulated Hz (the real robot publishes its state at 100 Hz; robot_state_publisher
# sends /tf at 50 Hz; ground truth is for tests and benchmarks). The parts have their own.
RATES_HZ = {'robot_state': 100.0, 'joint_states': 100.0, 'tf': 50.0, 'object_poses': 30.0}
EDGES_WAIT_S = 1.0      # wall s an IK request in another frame waits for the loop to read the arm's links
IMAGE_ENCODINGS = ('bgra8', 'bgr8', 'rgb8', 'mono8')
RNG_STREAMS = {'image_noise': 0, 'frame_faults': 1, 'left_ik_faults': 2, 'right_ik_faults': 3}


def urdf_tree(urdf_text):
    """[(parent link, child link, joint type)] of every joint of a URDF document."""
    root = ElementTree.fromstring(urdf_text)
    return [(j.find('parent').get('link'), j.find('child').get('link'), j.get('type')) for j in root.iter('joint')]



class FakeBaxterNode:
    """Publishes, subscribes and serves Baxter's interfaces around a ``SimWorld``; ``run()`` is the loop."""

    def __init__(self, world, urdf_text, real_time_factor=1.0, image_encoding='bgra8', enable=False,
                 open_cameras=(), seed=0, clock=None):
        self.world = world
        self.faults = world.scene.faults
        # Independent streams, so that e.g. the IK calls an application makes do not change the image noise.
        rng = {name: np.random.default_rng([seed, stream]) for name, stream in RNG_STREAMS.items()}
        self._inbox = collections.deque()        # callables queued by ROS threads, run by the loop
        self._delayed_commands = DelayLine(self.faults.joint_command_delay)   # JointCommands not yet applied
        self._estop_done = False
        self.robot = RobotEnableState(enabled=enable)
        self._tree = urdf_tree(urdf_text)
        self._moving_joints = [(p, c) for p, c, kind in self._tree if kind != 'fixed']
        self._tf_edges = {}                          # {child: (parent, T_parent_child)}: /tf and the IK frames
        positions, _, _ = world.joint_state()
        self._joint_positions = dict(zip(world.joint_names(), (float(q) for q in positions)))   # rad, last published
        self.pacer = RealTimePacer(real_time_factor)
        self.clock = MessageClock(clock or default_clock(real_time_factor), self.pacer)

        for name, value in IDENTITY_PARAMS.items():
            rospy.set_param(name, value)
        rospy.set_param('/robot_description', urdf_text)
        latched = dict(queue_size=1, latch=True)
        self._pub = {
            'robot_state': state_publisher(sdk.ROBOT_STATE_TOPIC, msg.AssemblyState),
            'joint_states': state_publisher(sdk.JOINT_STATES_TOPIC, JointState),
            'tf': state_publisher('/tf', TFMessage),
            'tf_static': rospy.Publisher('/tf_static', TFMessage, **latched),
            'object_poses': state_publisher('~object_poses', PoseArray),
            'respawns': rospy.Publisher('~respawns', UInt32, **latched),
        }
        self._clock_publisher = state_publisher('/clock', Clock) if self.clock.publishes_clock else None
        self._respawns_published = None
        self._publish_respawns()
        queued = self._queued
        rospy.Subscriber(sdk.ENABLE_TOPIC, Bool, queued(self._on_enable), queue_size=10)
        rospy.Subscriber(sdk.RESET_TOPIC, Empty, queued(self._on_reset), queue_size=10)
        rospy.Subscriber(sdk.STOP_TOPIC, Empty, queued(self._on_stop), queue_size=10)

        self.limbs = {side: LimbNode(side, world, self.robot, self.faults, queued, self._delayed_commands,
                                     rng[f'{side}_ik_faults'], self._T_base, self._arm_angles, self.ros_time)
                      for side in SIDES}
        self.grippers = {side: GripperNode(side, world, queued) for side in SIDES}
        self.head = HeadNode(world, self.robot, queued)
        self.io = IONode(lambda side: world.range_at(sdk.arm_frames(side).hand_range, *RANGE_LIMITS), queued,
                         self.ros_time)
        self.cameras = CamerasNode(world, image_encoding, rng['image_noise'], rng['frame_faults'], self.ros_time,
                                   open_cameras)
        self._holders = [*self.limbs.values(), self.head]     # hold still on disable, stop and reset
        self._tickers = [*self.limbs.values(), self.io]       # per-step work before the publications
        own = [(rate, getattr(self, '_publish_' + key)) for key, rate in RATES_HZ.items()]
        parts = [*self.limbs.values(), *self.grippers.values(), self.head, self.io]
        self._schedules = [(RateSchedule(rate), publish)
                           for rate, publish in own + [s for part in parts for s in part.schedules()]]
        self._publish_tf_static()

    def _queued(self, handler):
        """A subscriber callback that queues ``handler(message)`` for the main loop."""
        return lambda message: self._inbox.append(lambda: handler(message))

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
            for part in self._tickers:
                part.tick(now)
            self._publish_due(now)
            self.world.step()
            if self._clock_publisher is not None:
                self._clock_publisher.publish(Clock(clock=rospy.Time.from_sec(self.world.time)))
            if ready_pub is None:       # after the first /clock: a client started once ready has a clock
                ready_pub = self._announce_ready()
            self._publish_respawns()
            if rospy.is_shutdown():     # a shutdown that began in this step is not lag
                break
            self.pacer.pace(self.world.time)
        streaming = ''
        if self.cameras.first_opened is not None:
            streaming = (f', {self.pacer.measured_factor(since=self.cameras.first_opened):.3f} since the first '
                         f'camera opened {self.world.time - self.cameras.first_opened[1]:.1f} simulated s ago')
        behind = '' if not self.pacer.resets else (f'; fell behind {self.pacer.resets} times by more than '
                                                   f'{self.pacer.max_lag:g} s, {self.pacer.lost:.2f} simulated s lost')
        rospy.loginfo('fake_baxter: stopped after %.1f s of simulated time (real-time factor %.3f%s%s)',
                      self.world.time, self.pacer.measured_factor(), streaming, behind)

    def _announce_ready(self):
        """Latch /robot/sim/started (as the official simulator does) and log the one 'ready' line."""
        publisher = rospy.Publisher('/robot/sim/started', Empty, queue_size=1, latch=True)
        publisher.publish(Empty())
        age = _process_age()
        boot = '' if age is None else f' {age:.1f} s after start'
        rospy.loginfo('fake_baxter ready%s: robot %s, cameras open: %s, real-time factor %s, clock %s, faults: %s',
                      boot,
                      'enabled' if self.robot.enabled else 'disabled (publish True on /robot/set_super_enable)',
                      ', '.join(self.cameras.open_names()) or 'none',
                      'as fast as possible' if self.pacer.real_time_factor == 0 else
                      f'{self.pacer.real_time_factor:g}',
                      'sim (/clock)' if self.clock.publishes_clock else 'wall (no /clock)', self.faults.summary())
        return publisher

    def _inject_estop(self, now):
        """The ``estop_at`` fault: stop the robot once, as ``/robot/set_super_stop`` does."""
        if self.faults.estop_at is not None and not self._estop_done and now >= self.faults.estop_at:
            self._estop_done = True
            rospy.logwarn(f'fault injected: robot stopped at {now:.3f} s (estop_at {self.faults.estop_at:g} s)')
            self._on_stop(None)

    def _publish_due(self, now):
        stamp = None
        for schedule, publish in self._schedules:
            if schedule.due(now):
                if stamp is None:
                    stamp = self.ros_time(now)
                publish(Header(stamp=stamp))
        self.cameras.capture_due(now)

    def ros_time(self, now):
        """The ``rospy.Time`` stamp of simulated time ``now`` (s), as ``--clock`` says."""
        return rospy.Time.from_sec(self.clock.seconds(now))

    def _stamp(self, now):
        return Header(stamp=self.ros_time(now))

    def _arm_angles(self):
        """{joint: rad} of the last published joint state (a copy: the IK services read it in their threads)."""
        return dict(self._joint_positions)

    # ------------------------------------------------------------------ robot state
    def _on_enable(self, message):
        if self.robot.request_enable(message.data):
            if not message.data:
                self._hold()
        else:
            rospy.logwarn_throttle(2.0, 'enable refused: the robot is stopped (reset it first)')

    def _on_reset(self, message):
        self.robot.reset()
        self._hold()

    def _on_stop(self, message):
        self.robot.stop()
        self._hold()

    def _hold(self):
        for part in self._holders:
            part.hold()

    # ------------------------------------------------------------------ periodic publications
    def _publish_robot_state(self, header):
        if not self._pub['robot_state'].get_num_connections():
            return
        self._pub['robot_state'].publish(msg.AssemblyState(**self.robot.fields()))

    def _publish_joint_states(self, header):
        positions, velocities, efforts = self.world.joint_state()
        names, positions = list(self.world.joint_names()), [float(v) for v in positions]
        self._joint_positions = dict(zip(names, positions))
        if self._pub['joint_states'].get_num_connections():
            self._pub['joint_states'].publish(JointState(header=header, name=names, position=positions,
                                                         velocity=[float(v) for v in velocities],
                                                         effort=[float(v) for v in efforts]))

    def _link_poses(self, links):
        """{link: T_base_link} from the world (``base`` is the identity)."""
        poses = self.world.link_poses([link for link in links if link != sdk.BASE_FRAME])
        return {link: np.eye(4) if link == sdk.BASE_FRAME else poses[link] for link in links}

    def _publish_tf(self, header):
        if not self._pub['tf'].get_num_connections():
            return
        moving = self._refresh_tf_edges()
        self._pub['tf'].publish(TFMessage(transforms=[
            self._transform(header, parent, child, T) for child, (parent, T) in moving.items()]))

    def _refresh_tf_edges(self):
        """Read the moving joints' transforms from the world into the tf edges (loop thread); returns them."""
        poses = self._link_poses({link for joint in self._moving_joints for link in joint})
        T_parent_child = relative_transforms(np.stack([poses[parent] for parent, _ in self._moving_joints]),
                                             np.stack([poses[child] for _, child in self._moving_joints]))
        moving = {child: (parent, T) for (parent, child), T in zip(self._moving_joints, T_parent_child)}
        self._tf_edges = dict(self._tf_edges, **moving)
        return moving

    def _publish_tf_static(self):
        """Fixed joints, once, latched (computed from the world's link poses at boot)."""
        header = self._stamp(self.world.time)
        poses = self._link_poses({link for parent, child, _ in self._tree for link in (parent, child)})
        self._tf_edges = {child: (parent, invert(poses[parent]) @ poses[child]) for parent, child, _ in self._tree}
        self._pub['tf_static'].publish(TFMessage(transforms=[
            self._transform(header, parent, child, self._tf_edges[child][1])
            for parent, child, kind in self._tree if kind == 'fixed']))

    def _T_base(self, frame):
        """T_base_frame composed from the tf edges, or None for an unknown frame. Called from a service thread:
        unless ``frame`` is ``base``, the loop refreshes the moving joints' edges first (waits up to
        ``EDGES_WAIT_S``; they are computed only when wanted, as /tf is published only to subscribers)."""
        if frame != sdk.BASE_FRAME and frame in self._tf_edges:
            refreshed = threading.Event()
            self._inbox.append(lambda: (self._refresh_tf_edges(), refreshed.set()))
            if not refreshed.wait(EDGES_WAIT_S):
                rospy.logwarn(f'T_base({frame!r}): the loop did not refresh the arm\'s transforms within '
                              f'{EDGES_WAIT_S:g} s; using the last ones')
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
        if not self._pub['object_poses'].get_num_connections():
            return
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
        'A PyBullet "fake Baxter" serving the robot\'s ROS interfaces (SDK 1.2.0): both arms with their '
        'grippers, IK services and range sensors, the head, the cameras, digital and analog I/O and the '
        'navigators, in simulated time.'))
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
    parser.add_argument('--clock', choices=CLOCKS, default=None,
                        help='wall: stamp the wall clock, paced at 1.0, no /clock, as a real robot; sim: publish '
                             '/clock and set /use_sim_time (every node on simulated time; any --real-time-factor); '
                             'default: wall at a real-time factor of 1, else sim')
    parser.add_argument('--renderer', choices=RENDERERS, default='auto',
                        help='what draws the cameras: OpenGL through EGL (~5 ms a 640x400 frame) or PyBullet\'s '
                             'TinyRenderer (~75 ms); auto: EGL where it works, else TinyRenderer; default %(default)s')
    args = parser.parse_args(argv)
    if args.real_time_factor < 0 or not math.isfinite(args.real_time_factor):
        parser.error('--real-time-factor must be >= 0')
    args.clock = args.clock or default_clock(args.real_time_factor)
    if args.clock == 'wall' and args.real_time_factor != 1:
        parser.error(f'--clock wall runs at real time: --real-time-factor must be 1, got {args.real_time_factor:g} '
                     f'(use --clock sim to run slower or faster)')
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
    _agree_on_time(args.clock)
    rospy.init_node(NODE_NAME)
    rospy.loginfo('fake_baxter: cameras drawn by %s', world.renderer_description)
    node = FakeBaxterNode(world, urdf_text, real_time_factor=args.real_time_factor,
                          image_encoding=args.image_encoding, enable=args.enable,
                          open_cameras=args.open_camera, seed=args.seed, clock=args.clock)
    node.run()


def _agree_on_time(clock):
    """Set the master's ``/use_sim_time`` for ``--clock sim`` (the fake owns the clock: every node, this one
    included, runs on ``/clock``); with ``--clock wall`` exit (code 2) if it is set: no ``/clock`` will come."""
    master = rosgraph.Master('/' + NODE_NAME)
    try:
        if clock == 'sim':
            master.setParam('/use_sim_time', True)
        elif master.hasParam('/use_sim_time') and master.getParam('/use_sim_time'):
            print('fake_baxter: error: --clock wall publishes no /clock, but /use_sim_time is true on the master '
                  '(every node would wait for /clock): unset it (rosparam delete /use_sim_time) or use --clock sim',
                  file=sys.stderr)
            sys.exit(2)
    except OSError as error:
        print(f'fake_baxter: error: no ROS master at {rosgraph.get_master_uri()} ({error})', file=sys.stderr)
        sys.exit(1)
