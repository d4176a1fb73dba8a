"""Safety checks that every arm command passes before it is sent to the robot (pure: no ROS).

Two pieces:

- ``SafetyLimits``: the numbers. The table top height and the clearances above it for the gripper tip
  and for the hand / hand camera, a workspace box, the arm's joint limits (and velocity limits), the
  largest joint change and the largest gripper-tip displacement one command may ask for. Everything is
  in Baxter's ``base`` frame, metres and radians.
- ``ArmSafety``: the checks for one arm. ``check_joint_target``, ``check_cartesian_target`` and
  ``check_velocity`` either return quietly or raise ``UnsafeCommand`` (a ``ValueError``) whose message
  says which rule the command breaks, by how much, and for which joint or frame.

Joint vectors are the 7 arm angles in the order ``s0, s1, e0, e1, w0, w1, w2`` (radians).
With a forward-kinematics function ``fk(q, frame) -> T_base_frame`` the Cartesian rules are checked
for three frames of the arm: the gripper tip (``<side>_gripper``, tip clearance) and the hand and the
hand camera (``<side>_hand``, ``<side>_hand_camera``, hand clearance). A joint move is checked along
the straight joint-space segment from the current to the target angles (the path that
``robot.Limb.move_to_joint_positions`` commands), every ``path_resolution`` radians: the target must
satisfy every rule; an intermediate configuration may break a Cartesian rule only if the same frame
already broke it at the start by at least as much (so an arm that starts outside the box or too low
can be moved back, but never further out).
"""
from dataclasses import dataclass

import numpy as np

from baxter_pnp.transforms import invert

JOINT_LIMIT_TOLERANCE = 1e-3      # rad: joint readings and targets this close outside a limit still count as inside
ROTATION_TOLERANCE = 1e-6         # max |R^T R - I| element of an acceptable rotation matrix


class UnsafeCommand(ValueError):
    """An arm command breaks a safety rule; it must not be (and has not been) sent."""


def _vector(values, name, size=None):
    """``values`` as a finite float array (of ``size`` elements), or UnsafeCommand naming ``name``."""
    try:
        array = np.asarray(values, dtype=float).reshape(-1)
    except (TypeError, ValueError) as error:
        raise UnsafeCommand(f'{name} is not a numeric vector: {error}') from None
    if size is not None and array.size != size:
        raise UnsafeCommand(f'{name} must have {size} elements, got {array.size}')
    if not np.all(np.isfinite(array)):
        raise UnsafeCommand(f'{name} contains NaN or inf: {np.array2string(array, precision=4)}')
    return array


MAX_TABLE_TILT = np.radians(10.0)     # rad: a table plane tilted more is a wrong calibration, not a table


@dataclass(frozen=True)
class SafetyLimits:
    """The numbers the safety checks use (base frame, metres, radians).

    - ``joint_lower``, ``joint_upper`` (7,): joint limits (rad); ``velocity_limits`` (7,) rad/s or None.
    - ``table_top_z``: height of the table top in base (m), or ``table_plane`` (a ``models.Plane`` in base, e.g.
      a calibrated, slightly tilted table: it replaces ``table_top_z``); ``tip_margin``: the gripper tip
      (``<side>_gripper`` origin) must stay this far above it; ``hand_margin``: same for the hand and
      the hand camera origins.
    - ``workspace_min``, ``workspace_max`` (3,): the box (base, m) the tip, hand and camera stay in.
    - ``max_joint_step``: largest |target - current| of any joint in one command (rad).
    - ``max_cartesian_step``: largest displacement of the gripper tip in one command (m).
    - ``path_resolution``: largest joint change between two checked configurations of a move (rad).
    """
    joint_lower: tuple
    joint_upper: tuple
    velocity_limits: tuple = None
    table_top_z: float = -0.15
    table_plane: object = None
    tip_margin: float = 0.01
    hand_margin: float = 0.05
    workspace_min: tuple = (0.15, -1.2, -0.5)
    workspace_max: tuple = (1.3, 1.2, 0.9)
    max_joint_step: float = 1.0
    max_cartesian_step: float = 0.4
    path_resolution: float = 0.05

    def __post_init__(self):
        lower = np.asarray(self.joint_lower, dtype=float)
        upper = np.asarray(self.joint_upper, dtype=float)
        if lower.shape != (7,) or upper.shape != (7,) or not np.all(lower < upper):
            raise ValueError('joint_lower and joint_upper must be 7 values each with lower < upper')
        object.__setattr__(self, 'joint_lower', lower)
        object.__setattr__(self, 'joint_upper', upper)
        if self.velocity_limits is not None:
            velocity = np.asarray(self.velocity_limits, dtype=float)
            if velocity.shape != (7,) or not np.all(velocity > 0):
                raise ValueError('velocity_limits must be 7 positive values (rad/s) or None')
            object.__setattr__(self, 'velocity_limits', velocity)
        box_min = np.asarray(self.workspace_min, dtype=float)
        box_max = np.asarray(self.workspace_max, dtype=float)
        if box_min.shape != (3,) or box_max.shape != (3,) or not np.all(box_min < box_max):
            raise ValueError('workspace_min and workspace_max must be 3 values each with min < max')
        object.__setattr__(self, 'workspace_min', box_min)
        object.__setattr__(self, 'workspace_max', box_max)
        if self.table_plane is not None and not self.table_plane.tilt() <= MAX_TABLE_TILT:
            raise ValueError('table_plane is tilted %.1f deg: more than %.0f deg is no table top'
                             % (np.degrees(self.table_plane.tilt()), np.degrees(MAX_TABLE_TILT)))
        for name in ('tip_margin', 'hand_margin'):
            if not getattr(self, name) >= 0:
                raise ValueError(f'{name} must be >= 0 (m)')
        for name in ('max_joint_step', 'max_cartesian_step', 'path_resolution'):
            if not getattr(self, name) > 0:
                raise ValueError(f'{name} must be > 0')

    @classmethod
    def from_kinematics(cls, kinematics, **overrides):
        """Limits with an ``ArmKinematics``'s joint and velocity limits (other fields: defaults or ``overrides``)."""
        return cls(joint_lower=kinematics.lower, joint_upper=kinematics.upper,
                   velocity_limits=kinematics.velocity_limits, **overrides)


class ArmSafety:
    """The safety checks of one arm: every joint, Cartesian or velocity command passes here first.

    ``fk(q, frame) -> T_base_frame`` (4x4, e.g. ``ArmKinematics.fk``) enables the Cartesian rules
    (table clearance, workspace box, tip step) for joint and velocity commands and the hand/camera
    clearance for Cartesian targets; without it only the joint rules are checked for joint commands
    and only the tip for Cartesian targets. ``joint_names`` (7) are used in messages.
    """

    def __init__(self, limits, fk=None, side='left', joint_names=None):
        self.limits = limits
        self.side = side
        self.joint_names = list(joint_names) if joint_names is not None else [f'joint {k}' for k in range(7)]
        self.tip_frame = f'{side}_gripper'
        self.body_frames = (f'{side}_hand', f'{side}_hand_camera')
        self._fk = fk
        # The hand and camera are rigidly attached to the tip: T_gripper_frame is the same for any angles.
        self._T_tip_body = {}
        if fk is not None:
            q_any = np.clip(np.zeros(7), limits.joint_lower, limits.joint_upper)
            T_base_tip = fk(q_any, self.tip_frame)
            self._T_tip_body = {frame: invert(T_base_tip) @ fk(q_any, frame) for frame in self.body_frames}

    @classmethod
    def for_arm(cls, kinematics, **limit_overrides):
        """Checks for the arm of an ``ArmKinematics``: its limits, its FK, its side and joint names."""
        return cls(SafetyLimits.from_kinematics(kinematics, **limit_overrides), fk=kinematics.fk,
                   side=kinematics.side, joint_names=kinematics.joint_names)

    # ------------------------------------------------------------------------------------ public checks
    def check_joint_target(self, q_target, q_current):
        """Raise ``UnsafeCommand`` unless moving from ``q_current`` to ``q_target`` (7 angles, rad) is safe.

        Rules: both finite; the target within the joint limits; no joint changes by more than
        ``max_joint_step``; with FK, the tip moves at most ``max_cartesian_step`` and the tip, hand and
        camera stay above the table (+ their margins) and inside the workspace box along the move.
        """
        q_target = _vector(q_target, 'joint target', 7)
        q_current = _vector(q_current, 'current joint angles', 7)
        self._check_joint_limits(q_target)
        step = np.abs(q_target - q_current)
        worst = int(np.argmax(step))
        if step[worst] > self.limits.max_joint_step:
            raise UnsafeCommand(f'{self.joint_names[worst]} would move by {step[worst]:.3f} rad in one command '
                                f'(max_joint_step {self.limits.max_joint_step:.3f} rad)')
        if self._fk is None:
            return
        start = self._frame_positions(q_current)
        target = self._frame_positions(q_target)
        tip_step = np.linalg.norm(target[self.tip_frame] - start[self.tip_frame])
        if tip_step > self.limits.max_cartesian_step:
            raise UnsafeCommand(f'{self.tip_frame} would move by {tip_step:.3f} m in one command '
                                f'(max_cartesian_step {self.limits.max_cartesian_step:.3f} m)')
        self._check_points(target, 'at the target')
        start_depth = {frame: self._violation(frame, p)[0] for frame, p in start.items()}
        n_steps = int(np.ceil(step[worst] / self.limits.path_resolution))
        for s in np.arange(1, n_steps) / max(n_steps, 1):
            for frame, position in self._frame_positions(q_current + s * (q_target - q_current)).items():
                depth, reason = self._violation(frame, position)
                if depth > start_depth[frame] + 1e-9:
                    raise UnsafeCommand(f'{frame} {reason} at {100 * s:.0f}% of the joint move')

    def check_cartesian_target(self, T_base_gripper, T_base_gripper_current=None):
        """Raise ``UnsafeCommand`` unless the gripper-tip pose ``T_base_gripper`` (4x4, base) is safe.

        Rules: finite, a proper rotation; the tip (and, with FK, the hand and camera, rigidly attached
        to it) above the table + margin and inside the box; with ``T_base_gripper_current``, a tip
        displacement of at most ``max_cartesian_step``.
        """
        T_target = self._pose(T_base_gripper, 'gripper target pose')
        positions = {self.tip_frame: T_target[:3, 3]}
        positions.update({frame: (T_target @ T)[:3, 3] for frame, T in self._T_tip_body.items()})
        self._check_points(positions, 'at the target pose')
        if T_base_gripper_current is not None:
            T_current = self._pose(T_base_gripper_current, 'current gripper pose')
            tip_step = np.linalg.norm(T_target[:3, 3] - T_current[:3, 3])
            if tip_step > self.limits.max_cartesian_step:
                raise UnsafeCommand(f'{self.tip_frame} would move by {tip_step:.3f} m in one command '
                                    f'(max_cartesian_step {self.limits.max_cartesian_step:.3f} m)')

    def check_velocity(self, qdot, dt, q_current):
        """Raise ``UnsafeCommand`` unless joint velocities ``qdot`` (7, rad/s) are safe for ``dt`` seconds.

        ``dt`` is how long the command may stay in force (at least the robot's command timeout,
        0.2 s by default). Rules: finite; within the velocity limits; the angles one step ahead,
        ``q_current + qdot * dt``, pass ``check_joint_target``.
        """
        qdot = _vector(qdot, 'joint velocities', 7)
        if not (np.isfinite(dt) and dt > 0):
            raise UnsafeCommand(f'velocity command horizon dt must be a positive number of seconds, got {dt}')
        if self.limits.velocity_limits is not None:
            ratio = np.abs(qdot) / self.limits.velocity_limits
            worst = int(np.argmax(ratio))
            if ratio[worst] > 1.0:
                raise UnsafeCommand(f'{self.joint_names[worst]} velocity {qdot[worst]:.3f} rad/s exceeds its limit '
                                    f'{self.limits.velocity_limits[worst]:.3f} rad/s')
        q_current = _vector(q_current, 'current joint angles', 7)
        self.check_joint_target(q_current + qdot * dt, q_current)

    # ------------------------------------------------------------------------------------ helpers
    def _check_joint_limits(self, q):
        below = self.limits.joint_lower - JOINT_LIMIT_TOLERANCE - q
        above = q - self.limits.joint_upper - JOINT_LIMIT_TOLERANCE
        for k in range(7):
            if below[k] > 0 or above[k] > 0:
                raise UnsafeCommand(f'{self.joint_names[k]} target {q[k]:.4f} rad is outside its limits '
                                    f'[{self.limits.joint_lower[k]:.4f}, {self.limits.joint_upper[k]:.4f}] rad')

    def _pose(self, T, name):
        T = np.asarray(T, dtype=float)
        if T.shape != (4, 4):
            raise UnsafeCommand(f'{name} must be a 4x4 matrix, got shape {T.shape}')
        if not np.all(np.isfinite(T)):
            raise UnsafeCommand(f'{name} contains NaN or inf')
        R = T[:3, :3]
        if np.max(np.abs(R.T @ R - np.eye(3))) > ROTATION_TOLERANCE or np.linalg.det(R) <= 0:
            raise UnsafeCommand(f'{name} does not hold a proper rotation matrix')
        return T

    def _frame_positions(self, q):
        """{frame: origin (3,) in base} of the tip, hand and camera at angles ``q``."""
        return {frame: self._fk(q, frame)[:3, 3] for frame in (self.tip_frame,) + self.body_frames}

    def table_z_at(self, position):
        """Height (m, base) of the table top under ``position`` (x, y, ...)."""
        plane = self.limits.table_plane
        return self.limits.table_top_z if plane is None else plane.z_at(position[:2])

    def _violation(self, frame, position):
        """(depth (m) by which ``position`` of ``frame`` breaks the clearance/box rules, reason) - depth 0 if none."""
        margin = self.limits.tip_margin if frame == self.tip_frame else self.limits.hand_margin
        table_z = self.table_z_at(position)
        depths = [(table_z + margin - position[2],
                   f'would be at z = {position[2]:.3f} m, below the table top {table_z:.3f} m '
                   f'+ margin {margin:.3f} m')]
        for axis, name in enumerate('xyz'):
            low, high = self.limits.workspace_min[axis], self.limits.workspace_max[axis]
            depths.append((max(low - position[axis], position[axis] - high),
                           f'would be at {name} = {position[axis]:.3f} m, outside the workspace box '
                           f'[{low:.3f}, {high:.3f}] m'))
        depth, reason = max(depths, key=lambda item: item[0])
        return max(depth, 0.0), reason

    def _check_points(self, positions, where):
        for frame, position in positions.items():
            depth, reason = self._violation(frame, position)
            if depth > 0:
                raise UnsafeCommand(f'{frame} {reason} {where}')
