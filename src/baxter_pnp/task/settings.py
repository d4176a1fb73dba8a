"""The robot session's parameters (arm, camera mode, table, timeouts, outputs) and how a task's parameters and
the session's are read: defaults <- YAML <- private ROS parameters (``~name``) <- command line. Pure (no ROS:
the caller passes the ``~name`` values it read)."""
import math
from dataclasses import dataclass, field, fields
from typing import List, Optional

import yaml

from baxter_pnp.camera import CameraModel, SensorWindow
from baxter_pnp.models import Plane
from baxter_pnp.params import ParameterError, Parameters, load_mapping
from baxter_pnp.robot.sdk import CAMERA_CONTROL_EXPOSURE, CAMERA_CONTROL_GAIN, camera_control_problem
from baxter_pnp.safety import MAX_TABLE_TILT


@dataclass
class SessionConfig(Parameters):
    """Everything a task needs of the robot session (metres, seconds; ``*_timeout`` and ``stream_max_age`` wall
    time unless said otherwise)."""

    side: str = 'left'                      # arm (and its hand camera)
    resolution: List[int] = field(default_factory=lambda: [640, 400])   # hand camera mode
    fps: int = 20                           # hand camera rate (Hz)
    camera_exposure: int = -1               # hand camera exposure sent when the app opens it: 0-100, or -1: the
                                            # camera's automatic one (opening resets what camera_control.py set)
    camera_gain: int = -1                   # hand camera gain: 0-79, or -1: automatic (a dim table: raise these)
    camera_calibration: Optional[str] = None  # camera YAML (calibrate_camera.py) used instead of the robot's
                                            # camera_info; calibrated at a larger size: its centred window of the
                                            # mode's size (a hand camera's modes are windows of its sensor);
                                            # read when validated (a wrong file is a bad parameter)
    hand_eye: Optional[str] = None          # hand-eye calibration YAML (calibrate_hand_eye.py): the camera's mount
                                            # instead of tf / the URDF, and its table plane (if any) instead of
                                            # table_top_z; read when validated
    speed_ratio: float = 0.3                # position-mode speed ratio of the arm (robot default 0.3)
    table_top_z: float = -0.15              # table top height in base (m): the estimator's plane, the safety floor
    table_area: List[float] = field(default_factory=lambda: [0.3, -0.75, 1.2, 0.75])   # the table top's extent
                                            # in base: x_min, y_min, x_max, y_max (m); what a survey looks at
    tip_margin: float = 0.005               # the gripper tip never goes lower than this above the table (m); the
                                            # paddles reach 3.5 mm beyond the tip plane
    waypoint_spacing: float = 0.02          # IK along straight Cartesian paths: waypoints this far apart (m)
    timeout: float = 90.0                   # one task run (s of robot time)
    stream_max_age: float = 2.0             # a robot topic silent for longer is lost
    frame_timeout: float = 5.0              # a look waits this long for a camera frame
    robot_wait_timeout: float = 30.0        # wait this long for the robot's first state, and after lost streams
    max_recoveries: int = 2                 # times a run resumes after the robot came back
    cycles: int = 1                         # tasks run one after the other in one process
    next_block_timeout: float = 30.0        # between cycles: wait this long (s of robot time) for the next block
    save_views: bool = False                # save every annotated camera view in the output directory (views/)

    def validate(self):
        self.require(self.side in ('left', 'right'), 'side', "must be 'left' or 'right'")
        self.require(len(self.resolution) == 2 and min(self.resolution) > 0, 'resolution', 'must be [width, height]')
        self.require_positive('fps', 'waypoint_spacing', 'timeout', 'stream_max_age', 'frame_timeout',
                              'robot_wait_timeout', 'cycles', 'next_block_timeout', 'tip_margin')
        self.require(0.0 < self.speed_ratio <= 1.0, 'speed_ratio', 'must be in (0, 1]')
        for key, control in (('camera_exposure', CAMERA_CONTROL_EXPOSURE), ('camera_gain', CAMERA_CONTROL_GAIN)):
            problem = camera_control_problem(control, getattr(self, key))
            self.require(problem is None, key, problem)
        self.require(math.isfinite(self.table_top_z), 'table_top_z', 'must be a number')
        self.require(len(self.table_area) == 4 and all(map(math.isfinite, self.table_area))
                     and self.table_area[0] < self.table_area[2] and self.table_area[1] < self.table_area[3],
                     'table_area', 'must be [x_min, y_min, x_max, y_max] in metres')
        self.require(self.max_recoveries >= 0, 'max_recoveries', 'must be >= 0')
        if self.camera_calibration is not None:     # read now: a wrong file is a bad parameter, before connecting
            self.calibrated_camera()
        if self.hand_eye is not None:
            self.table()

    def hand_eye_calibration(self):
        """The ``hand_eye`` file's ``hand_eye.HandEyeCalibration`` (ParameterError if unreadable or for the other
        arm)."""
        from baxter_pnp import hand_eye
        try:
            calibration = hand_eye.load_hand_eye(self.hand_eye)
        except (OSError, ValueError, TypeError, yaml.YAMLError) as error:
            raise ParameterError('hand_eye', 'not a readable hand-eye calibration: %s' % error) from None
        expected = ('%s_hand' % self.side, '%s_hand_camera' % self.side)
        if (calibration.parent_frame, calibration.child_frame) != expected:
            raise ParameterError('hand_eye', '%s calibrates %s -> %s, not the %s arm\'s %s -> %s'
                                 % (self.hand_eye, calibration.parent_frame, calibration.child_frame, self.side,
                                    *expected))
        return calibration

    def table_calibrated(self):
        """True when the table top comes from the ``hand_eye`` calibration (it has a table plane)."""
        return self.hand_eye is not None and self.hand_eye_calibration().table_plane is not None

    def table(self):
        """The table top in base (``models.Plane``): the ``hand_eye`` calibration's table plane when it has one,
        else level at ``table_top_z``."""
        if self.table_calibrated():
            table = Plane(*self.hand_eye_calibration().table_plane)
            if not table.tilt() <= MAX_TABLE_TILT:
                raise ParameterError('hand_eye', "%s: the table plane is tilted %.1f deg: not a table top (was "
                                     "the board lying flat?)" % (self.hand_eye, math.degrees(table.tilt())))
            return table
        return Plane.level(self.table_top_z)

    def calibrated_camera(self):
        """The ``camera_calibration`` file's camera for the image of ``resolution``: the file's own model, or
        its centred window when it was calibrated at a larger size (ParameterError if smaller or unreadable)."""
        try:
            camera = CameraModel.from_yaml(self.camera_calibration)
        except (OSError, ValueError, TypeError, yaml.YAMLError) as error:
            raise ParameterError('camera_calibration', 'not a readable camera calibration: %s' % error) from None
        width, height = self.resolution
        if (camera.width, camera.height) == (width, height):
            return camera
        try:
            return camera.windowed(SensorWindow.centred(camera.width, camera.height, width, height))
        except ValueError:
            raise ParameterError('camera_calibration', 'calibrated at %dx%d, smaller than the camera mode %dx%d: '
                                 'calibrate at the mode used' % (camera.width, camera.height, width, height)) from None


def field_names(config_class):
    return [f.name for f in fields(config_class)]


def load_configs(task_class, yaml_path=None, private_params=None, overrides=None):
    """``(task_class config, SessionConfig)`` from, in increasing precedence: the defaults, the YAML mapping at
    ``yaml_path`` (one file holds both sets of keys), ``private_params`` (e.g. ``~name`` ROS parameters) and
    ``overrides`` (the command line); None values in ``overrides`` are ignored. ParameterError names the key
    of any unknown or bad value."""
    values = load_mapping(yaml_path) if yaml_path else {}
    values.update(private_params or {})
    values.update({key: value for key, value in (overrides or {}).items() if value is not None})
    session_keys = set(field_names(SessionConfig))
    session = SessionConfig.from_dict({k: v for k, v in values.items() if k in session_keys})
    task = task_class.from_dict({k: v for k, v in values.items() if k not in session_keys})
    return task, session
