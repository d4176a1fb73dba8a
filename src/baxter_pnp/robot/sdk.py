"""The Baxter SDK's names and numbers (SDK 1.2.0, reference/baxter_interfaces.md), defined once.

Both sides of the robot's ROS interface use this module: the clients in ``baxter_pnp.robot`` and the
fake Baxter (``baxter_pnp.sim.node``), which serves the same topics and services. Pure constants and
name functions: it imports nothing heavy, so the fake Baxter loads it without the clients.

Names that depend on an arm take ``side`` ('left' or 'right'); camera names are e.g. ``left_hand_camera``.
Units: seconds, radians, percent (gripper parameters), pixels (camera modes). Frames: ``base`` is the
robot's base frame; ``<side>_gripper`` is the endpoint the limb topics and the IK service talk about.
"""

from typing import NamedTuple

# ------------------------------------------------------------------------------ frames
BASE_FRAME = 'base'


class ArmFrames(NamedTuple):
    """The tf frames of one arm's hand (``T_base_gripper`` is the pose of ``gripper`` in ``base``)."""
    hand: str            # <side>_hand: the hand link, at the end of the wrist
    gripper: str         # <side>_gripper: the endpoint of the limb topics and the IK service
    hand_camera: str     # <side>_hand_camera: the hand camera's optical frame, also the camera's name
    hand_range: str      # <side>_hand_range: the infrared range sensor


def arm_frames(side):
    return ArmFrames(*(f'{side}_{part}' for part in ArmFrames._fields))


# ------------------------------------------------------------------------------ robot state (interfaces §2)
ROBOT_STATE_TOPIC = '/robot/state'                    # baxter_core_msgs/AssemblyState
ENABLE_TOPIC = '/robot/set_super_enable'              # std_msgs/Bool
RESET_TOPIC = '/robot/set_super_reset'                # std_msgs/Empty
STOP_TOPIC = '/robot/set_super_stop'                  # std_msgs/Empty

# ------------------------------------------------------------------------------ limbs (interfaces §3-6)
JOINT_STATES_TOPIC = '/robot/joint_states'            # sensor_msgs/JointState, every joint of the robot
COMMAND_TIMEOUT = 0.2           # s: the robot drops velocity/torque commands older than this (SDK default)
DEFAULT_SPEED_RATIO = 0.3       # the robot's position-mode speed ratio until set_speed_ratio is published
COMMAND_RATE_HZ = 100.0         # joint command stream rate (as baxter_interface)
JOINT_ANGLE_TOLERANCE = 0.008726646   # rad (0.5 deg): baxter_interface's "arrived" threshold


class LimbTopics(NamedTuple):
    """One arm's topics, under ``/robot/limb/<side>``."""
    endpoint_state: str    # baxter_core_msgs/EndpointState: <side>_gripper pose (m), twist (m/s, rad/s) in base
    joint_command: str     # baxter_core_msgs/JointCommand: position (rad), velocity (rad/s), torque, raw position
    speed_ratio: str       # std_msgs/Float64: position-mode speed, fraction (0, 1] of the velocity limits
    command_timeout: str   # std_msgs/Float64: the command timeout (s)


def limb_topics(side):
    namespace = f'/robot/limb/{side}'
    return LimbTopics(f'{namespace}/endpoint_state', f'{namespace}/joint_command', f'{namespace}/set_speed_ratio',
                      f'{namespace}/joint_command_timeout')


def ik_service(side):
    """baxter_core_msgs/SolvePositionIK for ``<side>_gripper`` poses."""
    return f'/ExternalTools/{side}/PositionKinematicsNode/IKService'


# ------------------------------------------------------------------------------ gripper (interfaces §7)
# baxter_interface.Gripper's default parameters (percent), sent with 'configure'.
GRIPPER_PARAMETERS = {'velocity': 50.0, 'moving_force': 40.0, 'holding_force': 30.0, 'dead_zone': 5.0}
GRIPPER_TYPES = {1: 'suction', 2: 'electric', 3: 'custom'}    # EndEffectorProperties.ui_type


class GripperTopics(NamedTuple):
    """One gripper's topics (baxter_core_msgs/EndEffector{State,Properties,Command})."""
    state: str
    properties: str
    command: str


def gripper_topics(side):
    return GripperTopics(*(f'/robot/end_effector/{side}_gripper/{leaf}' for leaf in GripperTopics._fields))


# ------------------------------------------------------------------------------ cameras (interfaces §8)
CAMERA_NAMES = (arm_frames('left').hand_camera, arm_frames('right').hand_camera, 'head_camera')
CAMERA_MODES = ((1280, 800), (960, 600), (640, 400), (480, 300), (384, 240), (320, 200))   # (width, height) px
CAMERA_CONTROL_EXPOSURE, CAMERA_CONTROL_GAIN = 100, 101   # baxter_core_msgs/CameraControl ids
CAMERA_CONTROL_HALF_RESOLUTION = 109
CAMERA_CONTROL_AUTO = -1                # baxter_interface.CameraController.CONTROL_AUTO
CAMERA_CONTROL_RANGES = {CAMERA_CONTROL_EXPOSURE: ('exposure', 0, 100),   # baxter_interface's setters' ranges
                         CAMERA_CONTROL_GAIN: ('gain', 0, 79)}
CAMERAS_LIST_SERVICE = '/cameras/list'
CAMERAS_OPEN_SERVICE = '/cameras/open'
CAMERAS_CLOSE_SERVICE = '/cameras/close'


def camera_control_problem(control, value):
    """None when ``value`` is an integer in the range of exposure or gain ``control`` (``CAMERA_CONTROL_RANGES``) or
    ``CAMERA_CONTROL_AUTO``, else what is wrong with it."""
    name, low, high = CAMERA_CONTROL_RANGES[control]
    if isinstance(value, bool) or not isinstance(value, int):
        return f'camera {name} must be an integer {low}-{high}, or {CAMERA_CONTROL_AUTO}: automatic; got {value!r}'
    if value != CAMERA_CONTROL_AUTO and not low <= value <= high:
        return f'camera {name} must be {low}-{high}, or {CAMERA_CONTROL_AUTO}: automatic; got {value}'
    return None


def camera_topics(camera):
    """(image, camera_info) topics of ``camera`` (sensor_msgs/Image, sensor_msgs/CameraInfo)."""
    return f'/cameras/{camera}/image', f'/cameras/{camera}/camera_info'


# ------------------------------------------------------------------------------ range sensors
def range_topic(side):
    """sensor_msgs/Range of the hand's infrared range sensor (m)."""
    return f'/robot/range/{arm_frames(side).hand_range}/state'
