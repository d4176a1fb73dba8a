"""Forward kinematics, Jacobian and inverse kinematics of one Baxter arm, from ``urdf/baxter.urdf``.

Everything is in Baxter's ``base`` frame (metres, radians). Each ``ArmKinematics`` owns a private
PyBullet DIRECT client (no gravity, never stepped): joint angles are set with ``resetJointState`` and
frames are read back with ``getLinkState(computeForwardKinematics=True)``, so the numbers are those
of the URDF itself. Any URDF link of the arm's chain can be the frame (``left_gripper``,
``left_hand``, ``left_hand_camera``, ...).
"""
import os
from typing import NamedTuple

import numpy as np
import pybullet as p
import yaml
from scipy.spatial.transform import Rotation

from baxter_pnp.runtime import PACKAGE_ROOT
from baxter_pnp.transforms import from_xyz_quat, invert

DEFAULT_URDF = os.path.join(PACKAGE_ROOT, 'urdf', 'baxter.urdf')
START_POSES_YAML = os.path.join(PACKAGE_ROOT, 'config', 'start_poses.yaml')
ARM_JOINTS = ('s0', 's1', 'e0', 'e1', 'w0', 'w1', 'w2')
NEUTRAL = (0.0, -0.55, 0.0, 0.75, 0.0, 1.26, 0.0)   # baxter_interface Limb.move_to_neutral()


def arm_joint_names(side):
    """The 7 joint names of an arm, shoulder to wrist: ``<side>_s0`` ... ``<side>_w2``."""
    if side not in ('left', 'right'):
        raise ValueError(f"side must be 'left' or 'right', got {side!r}")
    return [f'{side}_{j}' for j in ARM_JOINTS]


def load_start_poses(path=None):
    """dict pose name -> {left joint name: angle (rad)} from ``config/start_poses.yaml`` (the thesis's start poses)."""
    with open(path or START_POSES_YAML) as f:
        poses = yaml.safe_load(f)
    names = arm_joint_names('left')
    return {name: dict(zip(names, (float(a) for a in angles))) for name, angles in poses.items()}


def body_indices(body, client):
    """PyBullet indices of a loaded URDF body: (joint index by joint name, link index by link name).

    The link index of a URDF link is the index of the joint whose child it is; ``base`` is -1.
    """
    joints, links = {}, {'base': -1}
    for index in range(p.getNumJoints(body, physicsClientId=client)):
        info = p.getJointInfo(body, index, physicsClientId=client)
        joints[info[1].decode()] = index
        links[info[12].decode()] = index
    return joints, links


def link_pose(body, link_index, client):
    """T_base_link (4x4) of a URDF link frame (not its centre of mass) in the body's current state."""
    state = p.getLinkState(body, link_index, computeForwardKinematics=True, physicsClientId=client)
    return from_xyz_quat(state[4], state[5])


def pose_difference(T_current, T_target):
    """(6,) [position error (m); rotation vector (rad)] taking ``T_current`` to ``T_target``, in base."""
    rotation = Rotation.from_matrix(T_target[:3, :3] @ T_current[:3, :3].T).as_rotvec()
    return np.concatenate([T_target[:3, 3] - T_current[:3, 3], rotation])


class Solid(NamedTuple):
    """A box or a cylinder: ``kind`` ('box' | 'cylinder'), its pose ``T`` (4x4, m) in some frame, and its
    ``half_extents`` (3,) m along its own axes (a cylinder: radius, radius, half length along z)."""
    kind: str
    T: np.ndarray
    half_extents: np.ndarray

    def moved(self, T_new_old):
        """The same solid with its pose expressed in another frame (``T_new_old`` @ T)."""
        return self._replace(T=T_new_old @ self.T)


class PyBulletClientOwner:
    """Base of the classes that own a PyBullet client (``self._client``): ``close()`` disconnects it, and
    so does garbage collection."""

    _client = None

    def close(self):
        """Disconnect the PyBullet client."""
        if self._client is not None and p.isConnected(self._client):
            p.disconnect(self._client)
        self._client = None

    def __del__(self):
        try:
            self.close()
        except Exception:   # interpreter shutdown: pybullet may already be gone
            pass


class ArmKinematics(PyBulletClientOwner):
    """FK, Jacobian and IK of Baxter's ``side`` arm from a URDF (default ``urdf/baxter.urdf``)."""

    def __init__(self, side='left', urdf_path=None):
        self.side = side
        self.joint_names = arm_joint_names(side)
        self._client = p.connect(p.DIRECT)
        self._robot = p.loadURDF(urdf_path or DEFAULT_URDF, useFixedBase=True, physicsClientId=self._client)
        joints, self._links = body_indices(self._robot, self._client)
        self._joint_indices = [joints[name] for name in self.joint_names]
        infos = [p.getJointInfo(self._robot, i, physicsClientId=self._client) for i in self._joint_indices]
        self.lower = np.array([info[8] for info in infos])          # rad
        self.upper = np.array([info[9] for info in infos])          # rad
        self.velocity_limits = np.array([info[11] for info in infos])   # rad/s
        # PyBullet's IK and Jacobian take vectors over every movable joint (DOF) of the body.
        movable = [i for i in range(p.getNumJoints(self._robot, physicsClientId=self._client))
                   if p.getJointInfo(self._robot, i, physicsClientId=self._client)[2] != p.JOINT_FIXED]
        self._dof_of_arm_joint = np.array([movable.index(i) for i in self._joint_indices])
        self._dof_lower = np.array([p.getJointInfo(self._robot, i, physicsClientId=self._client)[8] for i in movable])
        self._dof_upper = np.array([p.getJointInfo(self._robot, i, physicsClientId=self._client)[9] for i in movable])
        self._n_dof = len(movable)
        self._reach_cache = {}

    # --------------------------------------------------------------------------------- FK / Jacobian
    def _set(self, q):
        for index, angle in zip(self._joint_indices, q):
            p.resetJointState(self._robot, index, float(angle), physicsClientId=self._client)

    def _link(self, frame):
        try:
            return self._links[frame]
        except KeyError:
            raise ValueError(f'unknown frame {frame!r} (not a link of the URDF)') from None

    def fk(self, q, frame=None):
        """T_base_frame (4x4, metres) for the 7 arm angles ``q`` (rad); ``frame`` defaults to ``<side>_gripper``."""
        link = self._link(frame or f'{self.side}_gripper')
        self._set(q)
        return link_pose(self._robot, link, self._client)

    def relative(self, parent, child):
        """T_parent_child (4x4, m) of two frames rigidly joined beyond the arm's joints (e.g. ``<side>_hand`` ->
        ``<side>_hand_camera``: the URDF's camera mount): the same at any joint angles."""
        q = np.clip(np.zeros(7), self.lower, self.upper)
        return invert(self.fk(q, parent)) @ self.fk(q, child)

    def jacobian(self, q, frame=None):
        """(6, 7) geometric Jacobian [linear; angular] of ``frame``'s origin in base: d[v; w] / d(q dot)."""
        link = self._link(frame or f'{self.side}_gripper')
        self._set(q)
        state = p.getLinkState(self._robot, link, computeForwardKinematics=True, physicsClientId=self._client)
        # calculateJacobian wants the point in the link's centre-of-mass frame; ours is the link frame origin.
        com_in_link = np.asarray(state[2])
        R_link_com = Rotation.from_quat(state[3]).as_matrix()
        origin_in_com = R_link_com.T @ -com_in_link
        positions = np.zeros(self._n_dof)
        positions[self._dof_of_arm_joint] = q
        linear, angular = p.calculateJacobian(self._robot, link, origin_in_com.tolist(), positions.tolist(),
                                              [0.0] * self._n_dof, [0.0] * self._n_dof,
                                              physicsClientId=self._client)
        return np.vstack([np.asarray(linear), np.asarray(angular)])[:, self._dof_of_arm_joint]

    def max_reach(self, frame=None):
        """Upper bound (m) of the distance from the ``s0`` joint's origin to ``frame``'s origin, any angles.

        Consecutive frames of the chain are rigidly attached, so the sum of their distances bounds the reach.
        """
        frame = frame or f'{self.side}_gripper'
        if frame not in self._reach_cache:
            chain = [self._link(frame)]
            while chain[-1] != self._joint_indices[0]:
                parent = p.getJointInfo(self._robot, chain[-1], physicsClientId=self._client)[16]
                if parent == -1:
                    raise ValueError(f'frame {frame!r} is not on the {self.side} arm')
                chain.append(parent)
            self._set(NEUTRAL)
            points = [link_pose(self._robot, link, self._client)[:3, 3] for link in chain]
            self._reach_cache[frame] = (float(np.sum(np.linalg.norm(np.diff(points, axis=0), axis=1))), points[-1])
        return self._reach_cache[frame]

    def hand_solids(self, frame=None, opening=1.0):
        """The gripper's solids in ``frame`` (default ``<side>_gripper``): what the hand camera sees of its
        own hand.

        Returns a list of :class:`Solid` (a box, or a cylinder along its own z), one per visual shape of
        ``<side>_gripper_base`` and the links below it (fingers and finger tips), with the fingers
        ``opening`` (0 closed .. 1 fully open) of their travel apart. The hand is rigid, so the result does
        not depend on the arm's angles.
        """
        frame = frame or f'{self.side}_gripper'
        hand_links = {self._link(f'{self.side}_gripper_base')}
        grown = True
        while grown:        # the links whose parent is already a hand link, until none is added
            grown = False
            for index in range(p.getNumJoints(self._robot, physicsClientId=self._client)):
                info = p.getJointInfo(self._robot, index, physicsClientId=self._client)
                if info[16] in hand_links and index not in hand_links:
                    hand_links.add(index)
                    grown = True
                    if info[2] == p.JOINT_PRISMATIC:     # a finger: its open end is its limit farthest from 0
                        travel = info[9] if abs(info[9]) >= abs(info[8]) else info[8]
                        p.resetJointState(self._robot, index, opening * travel, physicsClientId=self._client)
        T_frame_base = np.linalg.inv(link_pose(self._robot, self._link(frame), self._client))
        solids = []
        for shape in p.getVisualShapeData(self._robot, physicsClientId=self._client):
            link, geometry, dimensions, position, orientation = shape[1], shape[2], shape[3], shape[5], shape[6]
            if link not in hand_links:
                continue
            if geometry == p.GEOM_BOX:
                kind, half_extents = 'box', 0.5 * np.asarray(dimensions)
            elif geometry == p.GEOM_CYLINDER:       # dimensions: (length, radius) along the shape's z
                kind, half_extents = 'cylinder', np.array([dimensions[1], dimensions[1], 0.5 * dimensions[0]])
            else:
                continue
            T_base_solid = link_pose(self._robot, link, self._client) @ from_xyz_quat(position, orientation)
            solids.append(Solid(kind, T_frame_base @ T_base_solid, half_extents))
        return solids

    # --------------------------------------------------------------------------------- IK
    def ik(self, T_base_target, frame=None, seed=None, pos_tol=1e-3, rot_tol=np.radians(0.5),
           n_random_seeds=12):
        """7 joint angles (rad, inside the limits) putting ``frame`` at ``T_base_target``, or None.

        First damped least squares straight from the ``seed`` (e.g. the current angles): for a nearby
        target that is the solution closest to the seed, with no motion in the arm's null space, so
        successive targets along a path get successive, continuous solutions. Then the seed, the
        neutral pose and ``n_random_seeds`` reproducible random configurations, each started with
        PyBullet's null-space IK and refined with damped least squares on the exact FK. A solution must
        be within ``pos_tol`` (m) and ``rot_tol`` (rad) of the target. Targets beyond the arm's reach
        return None at once.
        """
        frame = frame or f'{self.side}_gripper'
        T_target = np.asarray(T_base_target, dtype=float)
        reach, shoulder = self.max_reach(frame)
        if np.linalg.norm(T_target[:3, 3] - shoulder) > reach + pos_tol:
            return None
        rng = np.random.default_rng(0)
        seeds = [] if seed is None else [np.clip(np.asarray(seed, dtype=float), self.lower, self.upper)]
        seeds.append(np.array(NEUTRAL))
        seeds += [rng.uniform(self.lower, self.upper) for _ in range(n_random_seeds)]
        if seed is not None:
            q = self._refine(seeds[0], T_target, frame, pos_tol, rot_tol)
            if q is not None:
                return q
        for start in seeds:
            q = self._refine(self._pybullet_ik(T_target, frame, start), T_target, frame, pos_tol, rot_tol)
            if q is not None:
                return q
        return None

    def _pybullet_ik(self, T_target, frame, start):
        """PyBullet's null-space IK from ``start`` (rest pose = ``start``), clipped to the joint limits."""
        current = np.zeros(self._n_dof)
        current[self._dof_of_arm_joint] = start
        position, quaternion = T_target[:3, 3], Rotation.from_matrix(T_target[:3, :3]).as_quat()
        self._set(start)
        solution = p.calculateInverseKinematics(
            self._robot, self._link(frame), position.tolist(), quaternion.tolist(),
            lowerLimits=self._dof_lower.tolist(), upperLimits=self._dof_upper.tolist(),
            jointRanges=(self._dof_upper - self._dof_lower).tolist(), restPoses=current.tolist(),
            currentPositions=current.tolist(), maxNumIterations=50, residualThreshold=1e-5,
            physicsClientId=self._client)
        return np.clip(np.asarray(solution)[self._dof_of_arm_joint], self.lower, self.upper)

    def _refine(self, q, T_target, frame, pos_tol, rot_tol, max_iterations=60, damping=0.02, max_step=0.3):
        """Damped-least-squares iterations (projected onto the joint limits); q or None if not within tolerance."""
        best_error = np.inf
        stalled = 0
        for _ in range(max_iterations):
            error = pose_difference(self.fk(q, frame), T_target)
            position_error, rotation_error = np.linalg.norm(error[:3]), np.linalg.norm(error[3:])
            if position_error < 0.1 * pos_tol and rotation_error < 0.1 * rot_tol:
                break
            size = position_error + 0.1 * rotation_error
            stalled = stalled + 1 if size > 0.9 * best_error else 0
            best_error = min(best_error, size)
            if stalled >= 5:
                break
            J = self.jacobian(q, frame)
            step = J.T @ np.linalg.solve(J @ J.T + damping ** 2 * np.eye(6), error)
            step *= min(1.0, max_step / np.max(np.abs(step)))
            q = np.clip(q + step, self.lower, self.upper)
        error = pose_difference(self.fk(q, frame), T_target)
        if np.linalg.norm(error[:3]) <= pos_tol and np.linalg.norm(error[3:]) <= rot_tol:
            return q
        return None

