"""The fake Baxter's physical world (no ROS): PyBullet DIRECT, gravity, a fixed time step, simulated clock.

Frames: PyBullet's world frame is Baxter's ``base`` (metres, radians, seconds). The robot is
``urdf/baxter.urdf`` on a fixed base; the table is a static box whose top is at ``scene.table.top_z``;
each block is a free regular prism (convex hull) whose body frame is its centre of mass, half its
height below the ``block`` frame of docs/ARCHITECTURE.md (top-face centre).

Arms: position commands run through a velocity- and acceleration-limited set-point profile tracked by
stiff PyBullet position motors (the arm moves smoothly at <= ``speed_ratio`` x the URDF velocity limit,
never teleports, and holds still); velocity commands use velocity motors. Gravity acts on everything;
the motors' large force limit plays the part of Baxter's gravity compensation (``sim.arm_motion``). The head: the
``head_pan`` joint is a speed-limited position motor (``command_head_pan``). Grippers: each finger
is a prismatic position motor with the commanded force and speed, the two geared together like the
real gripper's single drive; a grasp holds by friction and finger force only (nothing ties the block
to the gripper).

Faults (``scene.faults``, ``sim.faults``) acted out here: the occluder plate (visual only), the nudge
(a kinematic slide of a block), grippers whose first closes miss (the fingers pass through the
blocks: finger-block collisions are off until the reopened fingers are clear of every block) and closes
that slip (once the fingers grip, they let go of the block the same way: it stays on the table when they
rise, while the gripper holds the opening it gripped at and keeps reporting ``gripping`` until it opens).

Chessboards (``scene.boards``) are visual only, like the occluder: a white box (the board and its border,
``thickness`` thick on the table) and one body of flat black quads on its top; nothing collides with them,
so the physics, the range sensor and the blocks (``object_poses``, block indices) are those of the scene
without them.

``scene.respawn`` (soak tests) is acted out too (``sim.respawner``): a block that was lifted and has been put down and
let go is moved to the next of its respawn poses (``respawns`` counts the moves).
"""
import math
import os
import tempfile

import cv2
import numpy as np
import pybullet as p

from baxter_pnp.camera import CameraModel
from baxter_pnp.kinematics import (DEFAULT_URDF, NEUTRAL, PyBulletClientOwner, arm_joint_names, body_indices,
                                   link_pose)
from baxter_pnp.sim import appearance, fastmath, props
from baxter_pnp.sim.arm_motion import ARM_MOTOR_FORCE, ArmMotion
from baxter_pnp.sim.faults import OCCLUDER_THICKNESS
from baxter_pnp.sim.render import Light, make_renderer
from baxter_pnp.sim.respawner import Respawner
from baxter_pnp.transforms import make_transform

HEAD_MAX_SPEED = 1.5            # rad/s: the head's pan speed at speed ratio 1 (the URDF's limit is no real one)
FINGER_TRAVEL = 0.020833        # m, per finger, closed (0 %) to open (100 %)
GRIPPER_MAX_FORCE = 35.0        # N per finger at force_percent = 100
GRIPPER_MAX_SPEED = 0.04        # m/s per finger at velocity_percent = 100
GRIPPER_STILL_SPEED = 0.002     # m/s: fingers slower than this (low-passed) have stopped
GRIPPER_SPEED_FILTER = 0.03     # s, time constant of that low-pass (contact jitter is not motion)
GRIPPER_START_TIME = 0.05       # s after a command during which the fingers count as moving
GRIPPER_CLOSED_PERCENT = 2.0    # at or below this position the gripper is fully closed
SOLVER_ITERATIONS = 300         # PyBullet's default 50: a blocked finger reaches ~15 N only, a held block jitters
BLOCK_MARGIN = 0.001            # m, Bullet collision margin of the blocks' convex hulls
BLOCK_DENSITY = 780.0           # kg/m^3 (wood: a 40 x 40 x 20 mm square weighs 25 g)
FRICTION = {'table': 0.5, 'block': 0.8}   # finger pads: 1.5 (urdf/baxter.urdf)
TABLE_THICKNESS = 0.04          # m
BLUR_MAX_FRAME_GAP = 0.25      # s: a camera's last render older than this says nothing of its motion (no blur)
SHADOW_CASTERS_HEIGHT = 1.2     # m above the table top: what casts shadows on it (the arms and the head over it)


class SimWorld(PyBulletClientOwner):
    """The simulated Baxter, table and blocks of ``scene`` (a ``sim.scene.Scene``); see docs/ARCHITECTURE.md.

    ``renderer`` draws the cameras: 'auto' (OpenGL through EGL where it works, else PyBullet's TinyRenderer),
    'egl' or 'tiny' (``sim.render``); ``renderer_name`` says which one runs."""

    def __init__(self, scene, urdf_path=None, time_step=1 / 240.0, renderer='auto'):
        self.scene = scene
        self.time_step = float(time_step)
        self.time = 0.0
        self._client = p.connect(p.DIRECT)
        p.setGravity(0, 0, -9.81, physicsClientId=self._client)
        p.setTimeStep(self.time_step, physicsClientId=self._client)
        p.setPhysicsEngineParameter(numSolverIterations=SOLVER_ITERATIONS, physicsClientId=self._client)
        self._robot = p.loadURDF(urdf_path or DEFAULT_URDF, useFixedBase=True,
                                 flags=p.URDF_USE_INERTIA_FROM_FILE, physicsClientId=self._client)
        self._joints, self._links = body_indices(self._robot, self._client)
        self._pose_cache = {}        # {link: T_base_link} of the current state (cleared by every state change)
        self._published = ['head_pan', 'l_gripper_l_finger_joint', 'l_gripper_r_finger_joint',
                           *arm_joint_names('left'), 'r_gripper_l_finger_joint', 'r_gripper_r_finger_joint',
                           *arm_joint_names('right')]
        self._published_indices = [self._joints[name] for name in self._published]
        self._arms = {side: ArmMotion(self, side) for side in ('left', 'right')}
        self._grippers = {side: _Gripper(self, side) for side in ('left', 'right')}
        head = p.getJointInfo(self._robot, self._joints['head_pan'], physicsClientId=self._client)
        self.head_pan_limits = (head[8], head[9])     # rad
        self.command_head_pan(0.0, HEAD_MAX_SPEED)
        self._table = self._make_table(scene.table)
        self._blocks = [self._make_block(obj) for obj in scene.objects]
        if scene.faults.occluder is not None:
            self._make_occluder(scene.faults.occluder)
        board_meshes = dict(props.make_board(self._client, board, scene.table.top_z) for board in scene.boards)
        for prop in scene.props:
            props.make_prop(self._client, prop, scene.table.top_z)
        self._nudge_start = None     # (position, orientation) of the nudged block when its push began
        # Fault times count from boot, or (time_origin 'camera_open') from start_fault_clock(): never before.
        self.fault_time_origin = 0.0 if scene.faults.time_origin == 'boot' else math.inf
        self.set_arm_positions('left', scene.start_positions())
        self.set_arm_positions('right', dict(zip(arm_joint_names('right'), NEUTRAL)))
        self._ideal_cameras = {}     # (true camera) -> ideal pinhole camera rendered by PyBullet
        self._renderer = make_renderer(renderer, self._client, {
            **{body: _prism_mesh(obj.model.vertices[:, :2], obj.model.height)
               for body, obj in zip(self._blocks, scene.objects)},
            **board_meshes}, textures=self._textures, light=self._light())
        self._pixel_gains = {}       # (camera size, K) -> appearance.pixel_gain of scene.appearance (H, W, 3)
        self._remap_maps = {}        # (true camera, ideal camera) -> fixed-point cv2.remap maps
        self._camera_poses = {}      # link -> (time, T_base_camera) of its last render (motion blur)
        self._riding = {}            # camera link -> {(robot, link index)} that move with it (_riding_parts)
        self._respawner = None if scene.respawn is None else Respawner(self, scene.respawn)

    @property
    def renderer_name(self):
        """'egl' or 'tiny': the renderer drawing the cameras (``sim.render``)."""
        return self._renderer.name

    @property
    def renderer_description(self):
        """What draws the cameras, e.g. 'OpenGL through EGL (llvmpipe (LLVM 15.0.6, 256 bits))'."""
        return self._renderer.description

    def close(self):
        """Free the renderer and disconnect the PyBullet client."""
        renderer, self._renderer = getattr(self, '_renderer', None), None
        if renderer is not None:
            renderer.close()
        super().close()

    @property
    def respawns(self):
        """How many times ``scene.respawn`` has re-placed its block (0 without a ``respawn``)."""
        return 0 if self._respawner is None else self._respawner.count

    # ------------------------------------------------------------------------------------ building
    def _light(self):
        """The renderer's ``Light`` of ``scene.appearance``: shadows cast by what stands over the table, up to
        ``SHADOW_CASTERS_HEIGHT`` above it (the arms over their workspace)."""
        look, table = self.scene.appearance, self.scene.table
        half = np.divide(table.size, 2.0)
        low = (*(np.subtract(table.center, half) - 0.05), table.top_z - 0.05)
        high = (*(np.add(table.center, half) + 0.05), table.top_z + SHADOW_CASTERS_HEIGHT)
        return Light(tuple(look.light_direction), look.shadows, (tuple(map(float, low)), tuple(map(float, high))))

    def _make_table(self, table):
        half = [table.size[0] / 2, table.size[1] / 2, TABLE_THICKNESS / 2]
        collision = p.createCollisionShape(p.GEOM_BOX, halfExtents=half, physicsClientId=self._client)
        look = self.scene.appearance
        textured = look.table_texture > 0
        visual = p.createVisualShape(p.GEOM_BOX, halfExtents=half, physicsClientId=self._client,
                                     rgbaColor=[1.0, 1.0, 1.0, 1.0] if textured else [*look.table_color, 1.0])
        body = p.createMultiBody(0.0, collision, visual,
                                 [table.center[0], table.center[1], table.top_z - TABLE_THICKNESS / 2],
                                 physicsClientId=self._client)
        p.changeDynamics(body, -1, lateralFriction=FRICTION['table'], physicsClientId=self._client)
        self._textures = {}          # {body: RGB image of its PyBullet texture}, for the EGL renderer
        if textured:        # PyBullet loads textures from files only
            self._textures[body] = image = appearance.table_texture(look)
            with tempfile.TemporaryDirectory() as folder:
                path = os.path.join(folder, 'table.png')
                cv2.imwrite(path, cv2.cvtColor(image, cv2.COLOR_RGB2BGR))
                texture = p.loadTexture(path, physicsClientId=self._client)
            p.changeVisualShape(body, -1, textureUniqueId=texture, physicsClientId=self._client)
        return body

    def _make_block(self, obj):
        model = obj.model
        vertices, normals, indices = _prism_mesh(model.vertices[:, :2], model.height)
        # Bullet pads a convex hull by its collision margin: build the hull that much smaller, so the block
        # rests on the table and meets the fingers at its true size.
        apothem = model.circumradius * math.cos(math.pi / model.n)
        hull, _, _ = _prism_mesh(model.vertices[:, :2] * (1 - BLOCK_MARGIN / apothem),
                                 model.height - 2 * BLOCK_MARGIN)
        collision = p.createCollisionShape(p.GEOM_MESH, vertices=hull.tolist(), physicsClientId=self._client)
        visual = p.createVisualShape(p.GEOM_MESH, vertices=vertices.tolist(), normals=normals.tolist(),
                                     indices=indices.tolist(), rgbaColor=[*obj.color, 1.0],
                                     specularColor=[0.05, 0.05, 0.05], physicsClientId=self._client)
        area = 0.5 * model.n * model.circumradius ** 2 * math.sin(model.symmetry_angle)
        body = p.createMultiBody(BLOCK_DENSITY * area * model.height, collision, visual,
                                 physicsClientId=self._client)
        p.changeDynamics(body, -1, lateralFriction=FRICTION['block'], spinningFriction=0.001,
                         collisionMargin=BLOCK_MARGIN, physicsClientId=self._client)
        self._place(body, model.height, obj.xy, obj.yaw)
        return body

    def _make_occluder(self, occluder):
        """The occluder plate: a visual shape without collision shape (cameras see it, nothing touches it)."""
        half = [occluder.size[0] / 2, occluder.size[1] / 2, OCCLUDER_THICKNESS / 2]
        visual = p.createVisualShape(p.GEOM_BOX, halfExtents=half, rgbaColor=[*occluder.color, 1.0],
                                     physicsClientId=self._client)
        centre = [*occluder.xy, self.scene.table.top_z + occluder.height + OCCLUDER_THICKNESS / 2]
        return p.createMultiBody(0.0, -1, visual, centre, p.getQuaternionFromEuler([0, 0, occluder.yaw]),
                                 physicsClientId=self._client)

    def _place(self, body, height, xy, yaw):
        com = [xy[0], xy[1], self.scene.table.top_z + height / 2]
        p.resetBasePositionAndOrientation(body, com, p.getQuaternionFromEuler([0, 0, yaw]),
                                          physicsClientId=self._client)
        p.resetBaseVelocity(body, [0, 0, 0], [0, 0, 0], physicsClientId=self._client)

    # ------------------------------------------------------------------------------------ clock
    def fault_time(self, t=None):
        """Simulated time ``t`` (default now), in s, on the faults' clock (``scene.faults.time_origin``)."""
        return (self.time if t is None else t) - self.fault_time_origin

    def start_fault_clock(self, now=None):
        """With ``time_origin: camera_open``: fault times count from ``now`` (s, default the world's time;
        first call only)."""
        if math.isinf(self.fault_time_origin):
            self.fault_time_origin = self.time if now is None else now

    def step(self, n=1):
        """Advance ``n`` physics steps of ``time_step`` seconds (arm set-points, motors, contacts)."""
        nudge = self.scene.faults.nudge
        for _ in range(int(n)):
            for arm in self._arms.values():
                arm.update(self.time_step)
            if nudge is not None and nudge.moves_during(self.fault_time(), self.fault_time() + self.time_step):
                self._push(nudge)
            p.stepSimulation(physicsClientId=self._client)
            self._pose_cache.clear()
            for gripper in self._grippers.values():
                gripper.update(self.time_step)
            self.time += self.time_step
            if self._respawner is not None:
                self._respawner.update()

    def _push(self, nudge):
        """Slide the nudged block over the coming step: put it where the push has brought it now and give it
        the velocity that reaches the next position (same height and orientation as when the push began)."""
        body = self._blocks[nudge.object]
        if self._nudge_start is None:
            self._nudge_start = p.getBasePositionAndOrientation(body, physicsClientId=self._client)
        (x, y, z), orientation = self._nudge_start
        now, after = nudge.displacement(self.fault_time()), nudge.displacement(self.fault_time() + self.time_step)
        p.resetBasePositionAndOrientation(body, [x + now[0], y + now[1], z], orientation,
                                          physicsClientId=self._client)
        velocity = (after - now) / self.time_step
        p.resetBaseVelocity(body, [velocity[0], velocity[1], 0.0], [0.0, 0.0, 0.0], physicsClientId=self._client)

    # ------------------------------------------------------------------------------------ joints
    def joint_names(self):
        """Published joints: head_pan, l_gripper fingers, left arm, r_gripper fingers, right arm (19)."""
        return list(self._published)

    def joint_state(self):
        """(positions (rad or m), velocities (rad/s or m/s), efforts (N m or N)) aligned with ``joint_names()``."""
        states = p.getJointStates(self._robot, self._published_indices, physicsClientId=self._client)
        return tuple(np.array([s[k] for s in states]) for k in (0, 1, 3))

    def arm_joint_names(self, side):
        """The 7 joint names of the ``side`` arm, s0..w2."""
        return arm_joint_names(side)

    def command_arm_positions(self, side, targets, speed_ratio=0.3):
        """Move the named joints toward ``targets`` (rad, clipped to the limits) at <= ``speed_ratio`` x their
        velocity limits; joints not named keep their current targets."""
        self._arms[side].command_positions(targets, speed_ratio)

    def command_arm_velocities(self, side, velocities):
        """Drive the named joints at ``velocities`` (rad/s, clipped to the limits); the others hold still."""
        self._arms[side].command_velocities(velocities)

    def hold_arm(self, side):
        """Stop and hold the ``side`` arm at its current angles."""
        self._arms[side].hold()

    def set_arm_positions(self, side, positions):
        """Teleport the named joints to ``positions`` (rad) at rest and hold them there (start pose / resets)."""
        self._arms[side].teleport(positions)

    # ------------------------------------------------------------------------------------ head
    def command_head_pan(self, angle, max_speed):
        """Turn the head toward ``angle`` (rad, clipped to ``head_pan_limits``) at <= ``max_speed`` rad/s; returns
        the clipped target."""
        target = float(np.clip(angle, *self.head_pan_limits))
        p.setJointMotorControl2(self._robot, self._joints['head_pan'], p.POSITION_CONTROL, targetPosition=target,
                                force=ARM_MOTOR_FORCE, maxVelocity=max(float(max_speed), 1e-6),
                                physicsClientId=self._client)
        return target

    def head_pan(self):
        """(angle rad, velocity rad/s) of the head pan joint."""
        angle, velocity, _, _ = p.getJointState(self._robot, self._joints['head_pan'], physicsClientId=self._client)
        return angle, velocity

    # ------------------------------------------------------------------------------------ grippers
    def command_gripper(self, side, position_percent, force_percent=40.0, velocity_percent=50.0):
        """Move the fingers to ``position_percent`` (0 closed .. 100 open) with ``force_percent`` of
        ``GRIPPER_MAX_FORCE`` and ``velocity_percent`` of ``GRIPPER_MAX_SPEED`` (each clipped to 0..100)."""
        self._grippers[side].command(position_percent, force_percent, velocity_percent)

    def gripper_at_rest(self, side):
        """True if the ``side`` gripper's state cannot change by itself: open or opening done, fingers stopped, not
        gripping, its last command older than ``GRIPPER_START_TIME``."""
        return self._grippers[side].at_rest()

    def gripper_state(self, side):
        """dict: position_percent (0 closed .. 100 open), force_percent (measured squeeze), moving, gripping
        (both finger pads on the same block, stopped short of closed), missed (a close ended fully closed
        touching nothing)."""
        return self._grippers[side].state()

    # ------------------------------------------------------------------------------------ frames
    def _link(self, link):
        try:
            return self._links[link]
        except KeyError:
            raise ValueError(f'unknown link {link!r} (not a link of the URDF)') from None

    def link_pose(self, link):
        """T_base_link (4x4) of a URDF link frame, e.g. 'left_gripper', 'left_hand', 'left_hand_camera'."""
        return self.link_poses((link,))[link]

    def link_poses(self, links):
        """{link: T_base_link (4x4, a copy)} of URDF link frames; read from PyBullet once per state (one forward
        kinematics for all the links not read yet)."""
        cache = self._pose_cache
        missing = [link for link in dict.fromkeys(links) if link not in cache]
        indices = [self._link(link) for link in missing]
        if -1 in indices:                 # the base: not a link state
            for link, index in zip(missing, indices):
                cache[link] = link_pose(self._robot, index, self._client)
        elif missing:
            states = p.getLinkStates(self._robot, indices, computeForwardKinematics=True, physicsClientId=self._client)
            for link, state in zip(missing, states):
                cache[link] = fastmath.from_xyz_quat(state[4], state[5])
        return {link: cache[link].copy() for link in links}

    def link_twist(self, link):
        """(6,) [linear velocity (m/s); angular velocity (rad/s)] of the link frame's origin, in base."""
        state = p.getLinkState(self._robot, self._link(link), computeLinkVelocity=True,
                               computeForwardKinematics=True, physicsClientId=self._client)
        if link not in self._pose_cache:     # the pose comes with it: ``link_pose`` need not ask again
            self._pose_cache[link] = fastmath.from_xyz_quat(state[4], state[5])
        (wx, wy, wz), (vx, vy, vz) = state[7], state[6]
        rx, ry, rz = (a - b for a, b in zip(state[4], state[0]))      # centre of mass -> link origin
        return np.array([vx + wy * rz - wz * ry, vy + wz * rx - wx * rz, vz + wx * ry - wy * rx, wx, wy, wz])

    def object_poses(self):
        """Ground truth T_base_block (4x4) of every block (top-face centre frame), in scene order."""
        poses = []
        for body, obj in zip(self._blocks, self.scene.objects):
            position, quaternion = p.getBasePositionAndOrientation(body, physicsClientId=self._client)
            poses.append(fastmath.from_xyz_quat(position, quaternion) @ make_transform(None, [0, 0, obj.height / 2]))
        return poses

    def place_object(self, index, xy, yaw):
        """Put block ``index`` back on the table, top-face centre above ``xy`` (m), rotated ``yaw`` (rad), at rest."""
        self._place(self._blocks[index], self.scene.objects[index].height, xy, yaw)

    # ------------------------------------------------------------------------------------ sensors
    def range_at(self, link, min_range=0.004, max_range=0.4):
        """Distance (m) from the link origin to the first surface along the link's +x axis (the ROS
        ``sensor_msgs/Range`` convention; for ``left_hand_range`` that is the gripper's direction), or inf if
        nothing lies between ``min_range`` and ``max_range``."""
        T = self.link_pose(link)
        origin, direction = T[:3, 3], T[:3, 0]
        hit = p.rayTest((origin + min_range * direction).tolist(), (origin + max_range * direction).tolist(),
                        physicsClientId=self._client)[0]
        if hit[0] < 0:
            return math.inf
        return min_range + hit[2] * (max_range - min_range)

    def render_camera(self, link, camera, rng=None, gain=1.0):
        """uint8 BGR (H, W, 3) image of ``camera`` (a ``CameraModel``) mounted at ``link``'s optical frame.

        The true camera is the published one perturbed by ``scene.camera_error`` (mount offset, focal
        scale). It is rendered as an ideal pinhole with a margin (``renderer_name``; with ``scene.supersampling``
        n > 1 at n times the resolution, then each n x n block averaged), warped with
        the true camera's distortion (``CameraModel.rendering_maps``), then formed as ``scene.appearance``
        says (``sim.appearance.form_image``: exposure, white balance, vignetting; its intensities multiplied
        by ``gain``, a lighting change, 0 = black, nothing rendered; noise drawn from ``rng``, none if None).
        """
        if gain > 0:
            image = self._render(link, camera)
        else:
            image = np.zeros((camera.height, camera.width, 3), np.uint8)
        look = self.scene.appearance
        if rng is None and gain == 1.0 and not look.scales_intensity():
            return image
        return appearance.form_image(image, look, camera, rng, gain, self._pixel_gain(camera))

    def prepare_camera(self, camera):
        """Compute now what the first frame of ``camera`` needs (ideal camera, remap maps, vignetting, the noise bank:
        0.1-0.3 s, which would stall the loop). No PyBullet call: a service thread may call it."""
        self._true_camera(camera)
        self._pixel_gain(camera)
        look = self.scene.appearance
        if look.noise_std > 0 or look.colour_noise_std > 0:
            appearance._noise_bank((camera.height, camera.width, 3), look.noise_std, look.colour_noise_std)

    def _pixel_gain(self, camera):
        """``appearance.pixel_gain`` of ``camera`` under ``scene.appearance`` (None for the clean look), cached."""
        key = (camera.width, camera.height, tuple(camera.K.ravel()))
        if key not in self._pixel_gains:
            self._pixel_gains[key] = appearance.pixel_gain(camera, self.scene.appearance)
        return self._pixel_gains[key]

    def _true_camera(self, camera):
        """(ideal pinhole camera to render, fixed-point cv2.remap maps from it to the true camera) of ``camera``."""
        error = self.scene.camera_error
        K_true = camera.K.copy()
        K_true[0, 0] *= error.focal_scale
        K_true[1, 1] *= error.focal_scale
        true_camera = CameraModel(camera.width, camera.height, K_true, camera.D)
        ideal = self._ideal_camera(true_camera)
        key = (true_camera.width, true_camera.height, tuple(K_true.ravel()), tuple(camera.D), tuple(ideal.K.ravel()))
        if key not in self._remap_maps:     # fixed-point maps: what cv2.remap makes of float maps each call (same image)
            self._remap_maps[key] = cv2.convertMaps(*true_camera.rendering_maps(ideal), cv2.CV_16SC2)
        return ideal, self._remap_maps[key]

    def _render(self, link, camera):
        """Noise-free uint8 BGR image of ``camera`` at ``link`` (see ``render_camera``)."""
        error = self.scene.camera_error
        ideal, maps = self._true_camera(camera)
        T_base_camera = self.link_pose(link) @ error.T_published_true
        T_base_camera_before = self._exposure_start_pose(link, T_base_camera)
        riding = None if T_base_camera_before is None else self._riding_parts(link)
        n = self.scene.supersampling
        if n == 1:
            render = self._renderer.render(T_base_camera, ideal, riding)
        else:          # n x n samples a pixel, averaged: each pixel integrates the light over its area
            large = self._renderer.render(T_base_camera, ideal.scaled(n * ideal.width, n * ideal.height), riding)
            render = cv2.resize(large, (ideal.width, ideal.height), interpolation=cv2.INTER_AREA)
        image = cv2.remap(render, *maps, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
        if T_base_camera_before is None:
            return image
        return appearance.motion_blur(cv2.cvtColor(image, cv2.COLOR_BGRA2BGR), camera, T_base_camera,   # 0.1 ms
                                      T_base_camera_before, self.scene.table.top_z, cv2.extractChannel(image, 3))

    def _riding_parts(self, link):
        """{(robot body, link index)} of the links that move with camera ``link``: those joined to its wrist by
        fixed or prismatic joints only (the hand, the camera, the gripper and its fingers)."""
        if link not in self._riding:
            parents, kinds = {}, {}
            for index in range(p.getNumJoints(self._robot, physicsClientId=self._client)):
                info = p.getJointInfo(self._robot, index, physicsClientId=self._client)
                parents[index], kinds[index] = info[16], info[2]
            root = self._link(link)
            while kinds.get(root) in (p.JOINT_FIXED, p.JOINT_PRISMATIC) and parents[root] >= 0:
                root = parents[root]

            def rides(index):
                while index != root:
                    if kinds[index] not in (p.JOINT_FIXED, p.JOINT_PRISMATIC):
                        return False
                    index = parents[index]
                    if index < 0:
                        return False
                return True
            self._riding[link] = frozenset((self._robot, index) for index in parents if rides(index))
        return self._riding[link]

    def _exposure_start_pose(self, link, T_base_camera):
        """The camera's pose ``scene.appearance.exposure_time`` before now, from its motion since ``link``'s last
        render (at most ``BLUR_MAX_FRAME_GAP`` s ago; the motion's rate carried back by up to twice that gap); None
        without an exposure time or a recent render."""
        exposure_time = self.scene.appearance.exposure_time
        if exposure_time <= 0:
            return None
        last = self._camera_poses.get(link)
        self._camera_poses[link] = (self.time, T_base_camera)
        if last is None or not 0 < self.time - last[0] <= BLUR_MAX_FRAME_GAP:
            return None
        T_now_last = np.linalg.inv(T_base_camera) @ last[1]
        return T_base_camera @ appearance.scaled_motion(T_now_last, min(2.0, exposure_time / (self.time - last[0])))

    def _ideal_camera(self, true_camera):
        """Pinhole camera (no distortion, the true focal lengths) whose image covers every ray of ``true_camera``."""
        key = (true_camera.width, true_camera.height, tuple(true_camera.K.ravel()), tuple(true_camera.D))
        if key not in self._ideal_cameras:
            w, h = true_camera.width, true_camera.height
            u, v = np.linspace(0, w - 1, 64), np.linspace(0, h - 1, 64)
            border = np.concatenate([np.column_stack([u, np.full(64, y)]) for y in (0, h - 1)]
                                    + [np.column_stack([np.full(64, x), v]) for x in (0, w - 1)])
            ideal_px = true_camera.normalised_to_pixels(true_camera.undistort_points(border))
            low = np.floor(np.minimum(ideal_px.min(axis=0), 0)) - 2
            high = np.ceil(np.maximum(ideal_px.max(axis=0), [w - 1, h - 1])) + 2
            K = true_camera.K.copy()
            K[:2, 2] -= low
            size = (high - low + 1).astype(int)
            self._ideal_cameras[key] = CameraModel(size[0], size[1], K)
        return self._ideal_cameras[key]


class _Gripper:
    """One electric gripper: two prismatic fingers, each a force- and speed-limited position motor, geared together.

    Close attempts (a closing command after a non-closing one) are counted; those that
    ``scene.faults.gripper`` says must miss turn the finger-block collisions off; those that must slip turn
    them off once the fingers grip (the block, no longer squeezed, stays where it lies: frictionless pads
    instead squirt it out sideways now and then) and hold the fingers' opening and the ``gripping`` flag
    until the next opening command, whether or not the block is still between the fingers.
    """

    def __init__(self, world, side):
        self._world = world
        g = side[0]
        self.indices = [world._joints[f'{g}_gripper_l_finger_joint'], world._joints[f'{g}_gripper_r_finger_joint']]
        self.signs = np.array([1.0, -1.0])      # finger joint = sign * opening (m)
        self.contact_links = [
            {world._links[f'{g}_gripper_{finger}_finger'], world._links[f'{g}_gripper_{finger}_finger_tip']}
            for finger in ('l', 'r')]
        self.target = FINGER_TRAVEL
        self.command_time = -math.inf
        self.closing = False
        self.faults = world.scene.faults.gripper
        self.close_attempts = 0
        self.phantom = False                    # the fingers pass through the blocks (a close that must miss)
        self.slipping = False                   # this close slips: it lets go once gripping, gripping flag held
        self.gripping = False                   # latched: set when the fingers stop on a block, kept while they hold it
        self.speed = 0.0                        # m/s, low-passed opening speed of the fingers
        for index, sign in zip(self.indices, self.signs):
            p.resetJointState(world._robot, index, sign * FINGER_TRAVEL, physicsClientId=world._client)
        # The real fingers share one drive: a gear constraint keeps them symmetric (q_r = -q_l), so a squeezed
        # block is centred instead of drifting between two equal, independent forces.
        gear = p.createConstraint(world._robot, self.indices[0], world._robot, self.indices[1], p.JOINT_GEAR,
                                  [0, 1, 0], [0, 0, 0], [0, 0, 0], physicsClientId=world._client)
        p.changeConstraint(gear, gearRatio=1.0, erp=0.2, maxForce=GRIPPER_MAX_FORCE, physicsClientId=world._client)
        self.command(100.0, 40.0, 50.0)

    def command(self, position_percent, force_percent, velocity_percent):
        world = self._world
        self.target = float(np.clip(position_percent, 0.0, 100.0)) / 100.0 * FINGER_TRAVEL
        was_closing, self.closing = self.closing, self.target < self._opening()[0].mean()
        if self.closing and not was_closing:
            if self.faults.misses(self.close_attempts):
                self._collide_with_blocks(False)
            self.slipping = self.faults.slips(self.close_attempts)
            self.close_attempts += 1
        elif not self.closing:
            self.slipping = False
        self.gripping = self.gripping and self.closing
        self.command_time = world.time
        force = float(np.clip(force_percent, 0.0, 100.0)) / 100.0 * GRIPPER_MAX_FORCE
        speed = float(np.clip(velocity_percent, 0.0, 100.0)) / 100.0 * GRIPPER_MAX_SPEED
        for index, sign in zip(self.indices, self.signs):
            p.setJointMotorControl2(world._robot, index, p.POSITION_CONTROL, targetPosition=sign * self.target,
                                    force=force, maxVelocity=speed, physicsClientId=world._client)

    def update(self, dt):
        """Low-pass the fingers' opening speed (time constant ``GRIPPER_SPEED_FILTER``) after a step of ``dt`` s;
        after a missed close, collide with the blocks again once the reopening fingers are clear of them."""
        alpha = dt / (GRIPPER_SPEED_FILTER + dt)
        (_, speed_l, _, _), (_, speed_r, _, _) = p.getJointStates(self._world._robot, self.indices,
                                                                  physicsClientId=self._world._client)
        self.speed += alpha * ((speed_l - speed_r) / 2 - self.speed)     # _opening()[1].mean(), in floats
        if self.phantom and not self.closing and not self._inside_a_block():
            self._collide_with_blocks(True)
        if self.slipping and self.gripping and self.target < self._opening()[0].mean() - 1e-4:
            self._hold_opening()
            self._collide_with_blocks(False)

    def _hold_opening(self):
        """A slipping grip: the drive holds the opening it gripped at, block or no block."""
        world = self._world
        self.target = float(self._opening()[0].mean())
        for index, sign in zip(self.indices, self.signs):
            p.setJointMotorControl2(world._robot, index, p.POSITION_CONTROL, targetPosition=sign * self.target,
                                    force=GRIPPER_MAX_FORCE, maxVelocity=GRIPPER_MAX_SPEED,
                                    physicsClientId=world._client)

    def _finger_links(self):
        return sorted(self.contact_links[0] | self.contact_links[1])

    def _collide_with_blocks(self, enable):
        world = self._world
        for block in world._blocks:
            for link in self._finger_links():
                p.setCollisionFilterPair(world._robot, block, link, -1, int(enable), physicsClientId=world._client)
        self.phantom = not enable

    def _inside_a_block(self):
        """True if a finger overlaps or touches a block (collision filters do not apply to this query)."""
        world = self._world
        return any(p.getClosestPoints(world._robot, block, 0.0, linkIndexA=link, physicsClientId=world._client)
                   for block in world._blocks for link in self._finger_links())

    def _opening(self):
        """(opening (2,) m, opening speed (2,) m/s, squeeze force (2,) N) of the two fingers."""
        states = p.getJointStates(self._world._robot, self.indices, physicsClientId=self._world._client)
        return tuple(self.signs * np.array([s[k] for s in states]) for k in (0, 1, 3))

    def _touched_blocks(self):
        """[body ids of the blocks touching finger 0 (l), those touching finger 1 (r)], paddle tips included."""
        blocks = set(self._world._blocks)
        contacts = [(contact[3], contact[2]) for contact in p.getContactPoints(bodyA=self._world._robot,
                                                                              physicsClientId=self._world._client)
                    if contact[2] in blocks]
        return [{block for link, block in contacts if link in finger_links} for finger_links in self.contact_links]

    def at_rest(self):
        return (not self.closing and not self.gripping and abs(self.speed) <= GRIPPER_STILL_SPEED
                and self._world.time - self.command_time >= GRIPPER_START_TIME)

    def state(self):
        opening, _, force = self._opening()
        position_percent = float(opening.mean() / FINGER_TRAVEL * 100.0)
        starting = (self._world.time - self.command_time < GRIPPER_START_TIME
                    and np.max(np.abs(opening - self.target)) > 5e-4)
        moving = bool(abs(self.speed) > GRIPPER_STILL_SPEED or starting)
        touched = self._touched_blocks()
        closed = position_percent <= GRIPPER_CLOSED_PERCENT
        holding = bool(touched[0] & touched[1]) and not closed
        # A block squeezed by compliant pads creeps a little: once gripping, only losing it or opening ends it
        # (a slipping close: only opening).
        self.gripping = (holding or (self.slipping and self.gripping)) and (self.gripping or not moving)
        return {
            'position_percent': position_percent,
            'force_percent': float(np.clip(-force.mean() / GRIPPER_MAX_FORCE * 100.0, 0.0, 100.0)),
            'moving': moving and not self.gripping,
            'gripping': self.gripping,
            'missed': self.closing and not moving and closed and not (touched[0] | touched[1]),
        }


def _prism_mesh(top_xy, height):
    """Flat-shaded triangle mesh of a prism around its centre of mass: top face ``top_xy`` (n, 2) at
    z = +height/2, bottom at -height/2. Returns (vertices (V, 3), normals (V, 3), indices (T*3,))."""
    n = len(top_xy)
    top = np.column_stack([top_xy, np.full(n, height / 2)])
    bottom = np.column_stack([top_xy, np.full(n, -height / 2)])
    vertices, normals, indices = [], [], []

    def face(points, normal):
        start = len(vertices)
        vertices.extend(points)
        normals.extend([normal] * len(points))
        indices.extend(i for k in range(1, len(points) - 1) for i in (start, start + k, start + k + 1))

    face(list(top), (0.0, 0.0, 1.0))
    face(list(bottom[::-1]), (0.0, 0.0, -1.0))
    for k in range(n):
        a, b = k, (k + 1) % n
        outward = np.array([top_xy[b, 1] - top_xy[a, 1], top_xy[a, 0] - top_xy[b, 0], 0.0])
        face([bottom[a], bottom[b], top[b], top[a]], tuple(outward / np.linalg.norm(outward)))
    return np.array(vertices), np.array(normals), np.array(indices)

