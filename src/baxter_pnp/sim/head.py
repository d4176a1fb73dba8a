"""Baxter's head, pure (no ROS): pan commands with their speed ratio and pan enable, the nod, and the fields of
``baxter_core_msgs/HeadState`` (``baxter_interface.Head``: ``/robot/head/head_state``, ``command_head_pan``,
``command_head_nod``).

Angles in rad (the ``head_pan`` joint, 0 = facing forward), speeds in rad/s, times in simulated seconds. The pan
itself is ``SimWorld.command_head_pan``'s motor; ``sim.head_node`` is the ROS edge.
"""
import math

from baxter_pnp.msgs import msg

NOD_DURATION = 1.0              # s: one nod of the screen, down and up (isNodding stays true this long)
TURNING_TOLERANCE = 0.01        # rad: the head is turning while farther than this from its target
REQUEST_PAN_DISABLE = msg.HeadPanCommand.REQUEST_PAN_DISABLE
REQUEST_PAN_ENABLE = msg.HeadPanCommand.REQUEST_PAN_ENABLE
REQUEST_PAN_VOID = msg.HeadPanCommand.REQUEST_PAN_VOID


class HeadCommander:
    """Pan target, pan enable and the nod timer of the head, whose fastest pan is ``max_speed`` rad/s."""

    def __init__(self, max_speed):
        self.max_speed = float(max_speed)
        self.target = 0.0
        self.pan_enabled = True
        self._nod_end = -math.inf

    def pan_command(self, target, speed_ratio, enable_request):
        """(target rad, speed rad/s) to turn toward for a HeadPanCommand, or None while the pan is disabled (after
        this command's ``enable_request``). The ratio is clipped to [MIN_SPEED_RATIO, MAX_SPEED_RATIO]; ValueError
        for a non-finite target or ratio or an unknown request."""
        if enable_request not in (REQUEST_PAN_DISABLE, REQUEST_PAN_ENABLE, REQUEST_PAN_VOID):
            raise ValueError(f'unknown enable_pan_request {enable_request} (0 disable, 1 enable, 2 void)')
        if not (math.isfinite(target) and math.isfinite(speed_ratio)):
            raise ValueError(f'non-finite target {target} or speed_ratio {speed_ratio}')
        if enable_request != REQUEST_PAN_VOID:
            self.pan_enabled = enable_request == REQUEST_PAN_ENABLE
        if not self.pan_enabled:
            return None
        ratio = min(max(float(speed_ratio), msg.HeadPanCommand.MIN_SPEED_RATIO), msg.HeadPanCommand.MAX_SPEED_RATIO)
        return float(target), ratio * self.max_speed

    def nod(self, now):
        """Start a nod at ``now`` (s) unless one is under way."""
        if not self.nodding(now):
            self._nod_end = now + NOD_DURATION

    def nodding(self, now):
        return now < self._nod_end

    def fields(self, pan, now):
        """HeadState field values with the head at ``pan`` (rad) at time ``now`` (s)."""
        return {'pan': float(pan), 'isTurning': abs(pan - self.target) > TURNING_TOLERANCE,
                'isNodding': self.nodding(now), 'isPanEnabled': self.pan_enabled}
