"""The fake Baxter's robot-wide state, pure (no ROS): the AssemblyState with its reaction to enable / reset / stop
(interfaces §2) and the robot's identity (the parameters the SDK's version checks and the smoke tests read).
"""
from baxter_pnp.msgs import msg

# A real robot publishes a four-part build string; baxter_interface's version check (CHECK_VERSION) keeps the first
# three parts (1.2.0, the SDK's release), the smoke test drops the last one: both find 1.2.0.
SOFTWARE_VERSION = '1.2.0.57'
ROBOT_SERIAL = 'FAKE00000001'     # /manifest/robot_serial (the smoke test names its log file after it)
IDENTITY_PARAMS = {'/rethink/software_version': SOFTWARE_VERSION, '/manifest/robot_serial': ROBOT_SERIAL}

ESTOP_BUTTON_UNPRESSED = msg.AssemblyState.ESTOP_BUTTON_UNPRESSED
ESTOP_SOURCE_NONE, ESTOP_SOURCE_UNKNOWN = msg.AssemblyState.ESTOP_SOURCE_NONE, msg.AssemblyState.ESTOP_SOURCE_UNKNOWN


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

