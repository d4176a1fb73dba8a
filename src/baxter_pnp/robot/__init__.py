"""Thin clients of the Baxter SDK's ROS topics and services: the robot edge of the package.

Shaped like Rethink's ``baxter_interface`` (reference/baxter_interfaces.md §2-8), one module per part:

- ``sdk``: the SDK's topic and service names, frame names and constants (nothing heavy: the fake Baxter,
  ``baxter_pnp.sim.node``, serves the same names from it);
- ``errors``: ``RobotError`` and its kinds (``RobotTimeout``, ``StreamLost``, ``ServiceUnavailable``,
  ``IKFailure``);
- ``topics``: ``CachedTopic`` (a subscribed stream with a watchdog) and the waits the clients share;
- ``enable``: ``RobotEnable``, ``/robot/state`` and enable / disable / reset / stop;
- ``limb``: ``Limb(side, safety)``, joint angles, endpoint pose, the IK service, position and velocity
  commands (every arm command first passes ``safety``, a ``baxter_pnp.safety.ArmSafety``, and is logged);
- ``gripper``: ``Gripper(side)``, the electric gripper's command protocol (calibrate, open, close, state);
- ``camera``: ``HandCamera(side)``, opens the hand camera and delivers BGR ``Frame``s with their ``CameraModel``;
- ``hand_eye``: ``hand_eye_transform(side)``, the camera mount from tf (or the URDF if tf does not answer);
  ``hand_eye_from_calibration``: from a hand-eye calibration.

Only the SDK's topics and services are used, so the same code drives a real Baxter and the fake one.
Frames: ``base`` for poses (``T_base_gripper`` = the ``<side>_gripper`` pose in ``base``, 4x4, metres),
radians for joints. Timeouts and stream ages are wall-clock seconds; motion timing follows ROS time
(the robot's clock). Nothing here calls ``rospy.init_node``: the application does.

Every public name of the parts is available here (``robot.Limb``, ``robot.COMMAND_TIMEOUT``, ...), imported
on first use, so that importing ``baxter_pnp.robot.sdk`` alone loads no client (nor rospy).
"""
import importlib

_EXPORTS = {
    'sdk': ('COMMAND_RATE_HZ', 'COMMAND_TIMEOUT', 'DEFAULT_SPEED_RATIO', 'JOINT_ANGLE_TOLERANCE', 'CAMERA_MODES',
            'GRIPPER_PARAMETERS', 'GRIPPER_TYPES'),
    'errors': ('RobotError', 'RobotTimeout', 'StreamLost', 'ServiceUnavailable', 'IKFailure'),
    'topics': ('CachedTopic', 'DEFAULT_MAX_AGE', 'ROBOT_TIME_BACKSTOP'),
    'enable': ('RobotEnable',),
    'limb': ('Limb', 'ArmJointState', 'EndpointState', 'ENDPOINT_HISTORY'),
    'gripper': ('Gripper',),
    'camera': ('HandCamera', 'Frame', 'CAMERA_INFO_GRACE'),
    'hand_eye': ('hand_eye_transform', 'hand_eye_from_calibration', 'HandEye'),
}
_MODULE_OF = {name: module for module, names in _EXPORTS.items() for name in names}
__all__ = sorted(_MODULE_OF)


def __getattr__(name):
    """``robot.X``: the public name ``X`` of the part that defines it (PEP 562, imported on first use)."""
    module = _MODULE_OF.get(name)
    if module is None:
        raise AttributeError(f'module {__name__!r} has no attribute {name!r}')
    value = getattr(importlib.import_module(f'{__name__}.{module}'), name)
    globals()[name] = value
    return value


def __dir__():
    return sorted(set(globals()) | set(__all__))
