"""One arm's command semantics in the fake Baxter, pure (no ROS): JointCommand validation, the modes with speed ratio
and command timeout (``ArmCommander``) and the IK service's seed stages (interfaces §3-6).

Units: rad, rad/s, simulated seconds. ``sim.limb_node`` is the ROS edge that uses them for each arm.
"""
import math

import numpy as np

from baxter_pnp.msgs import msg, srv
from baxter_pnp.robot import sdk

POSITION_MODE, VELOCITY_MODE = msg.JointCommand.POSITION_MODE, msg.JointCommand.VELOCITY_MODE
TORQUE_MODE, RAW_POSITION_MODE = msg.JointCommand.TORQUE_MODE, msg.JointCommand.RAW_POSITION_MODE
SEED_AUTO, SEED_USER = srv.SolvePositionIKRequest.SEED_AUTO, srv.SolvePositionIKRequest.SEED_USER
SEED_CURRENT, SEED_NS_MAP = srv.SolvePositionIKRequest.SEED_CURRENT, srv.SolvePositionIKRequest.SEED_NS_MAP
IK_MAP_SEEDS = 30                               # random seeds of our stand-in for the robot's null-space map


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

