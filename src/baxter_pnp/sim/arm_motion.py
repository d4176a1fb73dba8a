"""One arm's joint motion in the fake Baxter's PyBullet world (no ROS): the position-mode set-point profile and
velocity mode, sent to PyBullet motors every step (``sim.world.SimWorld`` owns one per arm).

Units: rad, rad/s, rad/s^2, N m; time steps in seconds.
"""
import numpy as np
import pybullet as p

from baxter_pnp.kinematics import arm_joint_names

ARM_MOTOR_FORCE = 1000.0        # N m: stiff joint servos (also carry the arm's weight, like gravity compensation)
ARM_ACCELERATION = 3.0          # rad/s^2 of the position set-point profile
ARM_POSITION_GAIN = 0.2         # PyBullet motor position gain (fraction of the error corrected per step)

class ArmMotion:
    """Joint motion of one arm: a velocity/acceleration-limited set-point profile (position mode) or
    velocity targets (velocity mode), sent to PyBullet motors every step."""

    def __init__(self, world, side):
        self._world = world
        self.names = arm_joint_names(side)
        self.indices = [world._joints[name] for name in self.names]
        infos = [p.getJointInfo(world._robot, i, physicsClientId=world._client) for i in self.indices]
        self.lower = np.array([info[8] for info in infos])
        self.upper = np.array([info[9] for info in infos])
        self.velocity_limits = np.array([info[11] for info in infos])
        self.mode = 'position'
        self.target = self.setpoint = self.setpoint_velocity = np.zeros(7)
        self.max_speed = 0.3 * self.velocity_limits
        self.velocity_command = np.zeros(7)
        self._sent = None               # the position command the motors hold (resending it changes nothing)

    def _measured(self):
        states = p.getJointStates(self._world._robot, self.indices, physicsClientId=self._world._client)
        return np.array([s[0] for s in states]), np.array([s[1] for s in states])

    def _vector(self, values, what):
        unknown = set(values) - set(self.names)
        if unknown:
            raise ValueError(f'{what}: unknown joints {sorted(unknown)} (expected {self.names})')
        return np.array([values.get(name, np.nan) for name in self.names], dtype=float)

    def _enter_position_mode(self):
        if self.mode != 'position':
            q, v = self._measured()
            self.mode, self.target, self.setpoint = 'position', q, q
            self.setpoint_velocity = np.clip(v, -self.max_speed, self.max_speed)

    def command_positions(self, targets, speed_ratio):
        values = self._vector(targets, 'command_arm_positions')
        self._enter_position_mode()
        self.max_speed = float(np.clip(speed_ratio, 0.0, 1.0)) * self.velocity_limits
        self.target = np.where(np.isnan(values), self.target, np.clip(values, self.lower, self.upper))

    def command_velocities(self, velocities):
        values = np.nan_to_num(self._vector(velocities, 'command_arm_velocities'))
        self.mode = 'velocity'
        self.velocity_command = np.clip(values, -self.velocity_limits, self.velocity_limits)

    def hold(self):
        q, _ = self._measured()
        self.mode, self.target, self.setpoint, self.setpoint_velocity = 'position', q, q, np.zeros(7)

    def teleport(self, positions):
        values = self._vector(positions, 'set_arm_positions')
        q, _ = self._measured()
        q = np.where(np.isnan(values), q, np.clip(values, self.lower, self.upper))
        for index, angle in zip(self.indices, q):
            p.resetJointState(self._world._robot, index, angle, 0.0, physicsClientId=self._world._client)
        self._world._pose_cache.clear()
        self.mode, self.target, self.setpoint, self.setpoint_velocity = 'position', q, q, np.zeros(7)
        self._sent = None
        self.update(0.0)

    def update(self, dt):
        """Advance the set-point by ``dt`` seconds and command the motors."""
        world = self._world
        if self.mode == 'velocity':
            q, _ = self._measured()
            step = max(dt, world.time_step)       # stop on a joint limit instead of driving into it
            velocities = np.clip(self.velocity_command, (self.lower - q) / step, (self.upper - q) / step)
            p.setJointMotorControlArray(world._robot, self.indices, p.VELOCITY_CONTROL,
                                        targetVelocities=velocities.tolist(), forces=[ARM_MOTOR_FORCE] * 7,
                                        physicsClientId=world._client)
            self._sent = None
            return
        self.setpoint, self.setpoint_velocity = profile_step(self.setpoint, self.setpoint_velocity, self.target,
                                                             self.max_speed, ARM_ACCELERATION, dt)
        command = (self.setpoint.tobytes(), self.setpoint_velocity.tobytes(), self.max_speed.tobytes())
        if command == self._sent:          # an arm at rest: the motors already hold this command
            return
        self._sent = command
        for index, position, velocity, max_speed in zip(self.indices, self.setpoint, self.setpoint_velocity,
                                                         self.max_speed):
            p.setJointMotorControl2(world._robot, index, p.POSITION_CONTROL, targetPosition=position,
                                    targetVelocity=velocity, force=ARM_MOTOR_FORCE, positionGain=ARM_POSITION_GAIN,
                                    velocityGain=1.0, maxVelocity=max_speed, physicsClientId=world._client)


def profile_step(position, velocity, target, max_speed, acceleration, dt):
    """One ``dt`` step of the arm's set-point toward ``target`` (7 joints), synchronised like a robot's
    joint interpolator: the desired velocity is proportional to the remaining error, so the joints move
    along the straight joint-space line and arrive together; each joint stays within its ``max_speed``
    and slows in time to stop on the target (``acceleration``); the velocity vector changes by at most
    ``acceleration * dt`` (largest joint), keeping its direction while it speeds up. Returns (position,
    velocity)."""
    error = target - position
    distance = np.abs(error)
    if distance.max() <= 1e-9:
        return target.copy(), np.zeros_like(velocity)
    moving = distance > 1e-12
    safe = np.where(moving, distance, 1.0)
    gain = np.min(np.where(moving, np.minimum(max_speed / safe, np.sqrt(2.0 * acceleration / safe)), np.inf))
    change = gain * error - velocity
    largest = np.abs(change).max()
    if largest > acceleration * dt:
        change *= acceleration * dt / largest
    velocity = velocity + change
    new_position = position + velocity * dt
    arrived = (np.sign(target - new_position) != np.sign(error)) | ~moving
    return np.where(arrived, target, new_position), np.where(arrived, 0.0, velocity)
