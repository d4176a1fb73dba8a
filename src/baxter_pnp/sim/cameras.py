"""The fake Baxter's camera bank, pure (no ROS): ``/cameras/list|open|close`` semantics (known cameras, the
SDK's modes, at most two open at once, as the real robot powers), each open camera's published model and frame
schedule in simulated time, and the ``--camera NAME:WIDTHxHEIGHT@FPS`` option.

The model of the camera's modes (docs/fake_baxter.md, "Cameras"): a 1280x800 sensor; every mode is the centred
window of that many sensor pixels (no scaling), so the published ``CameraInfo`` holds the full-sensor ``K``, the
window as ``roi`` and ``P`` for the delivered image, with ``frame_id`` ``/<camera>`` -- what a real Baxter's
hand camera publishes at 640x400 (roi offset (320, 200)). The ``RESOLUTION_HALF`` control reads out a window
twice as large with 2x2 binning (modes up to 640x400). The other modes' windows and the binning follow from the
640x400 message and the SDK's control list; no message of theirs was at hand.
"""
import argparse
import dataclasses
import errno
import re
import threading

from baxter_pnp import camera as camera_module
from baxter_pnp.robot import sdk
from baxter_pnp.sim.clock import RateSchedule

MAX_OPEN_CAMERAS = 2                            # the real robot powers at most two cameras at once
MAX_CAMERA_FPS = 60.0


SENSOR_SIZE = (1280, 800)                       # px: the hand cameras' full sensor (the largest mode)
RESOLUTION_HALF_CONTROL = sdk.CAMERA_CONTROL_HALF_RESOLUTION     # baxter_interface's CAMERA_CONTROL_RESOLUTION_HALF
AUTO_EXPOSURE = 50                              # the exposure value the fake's automatic exposure amounts to ...
GAIN_PER_UNIT = 1.0 / 16.0                      # ... and the brightness a unit of gain adds (x 1 at 0, x 5.9 at 79)


@dataclasses.dataclass
class OpenCamera:
    """An open camera: its full-sensor model, the window it delivers, the delivered image's model (what the
    image shows: ``sensor.windowed(window)``), frame rate and schedule, and the brightness its exposure and gain
    controls give."""
    sensor: camera_module.CameraModel
    window: camera_module.SensorWindow
    model: camera_module.CameraModel
    fps: float
    schedule: RateSchedule
    brightness: float = 1.0         # ``control_brightness`` of its exposure and gain

    def camera_info(self, header):
        """The ``sensor_msgs/CameraInfo`` a real hand camera publishes for this window, with ``header``."""
        return self.sensor.to_camera_info(header, self.window)


def sensor_model(name):
    """Full-sensor model of camera ``name``: the thesis calibration (a 640x480 image) taken as the centred
    640x480 window of the 1280x800 sensor, so that 640x400 gives the thesis's numbers cropped."""
    thesis = camera_module.load_default_camera()
    K = thesis.K.copy()
    K[0, 2] += (SENSOR_SIZE[0] - thesis.width) / 2
    K[1, 2] += (SENSOR_SIZE[1] - thesis.height) / 2
    return camera_module.CameraModel(*SENSOR_SIZE, K, thesis.D, name=name, frame_id=name)


def sensor_window(width, height, half_resolution=False):
    """The ``SensorWindow`` of mode ``width`` x ``height`` (binned 2x2 with ``half_resolution``)."""
    return camera_module.SensorWindow.centred(*SENSOR_SIZE, width, height, 2 if half_resolution else 1)


def image_model(name, width, height, half_resolution=False):
    """The model of the images camera ``name`` delivers in mode ``width`` x ``height`` (``OpenCamera.model``)."""
    return sensor_model(name).windowed(sensor_window(width, height, half_resolution))


class CameraBank:
    """``/cameras/list|open|close`` semantics: known cameras, allowed modes, at most two open (thread-safe)."""

    def __init__(self):
        self._lock = threading.Lock()
        self._open = {}

    def list(self):
        return list(sdk.CAMERA_NAMES)

    def open(self, name, width, height, fps, now, half_resolution=False, controls=()):
        """(0, '') when opened (or re-opened with new settings) at simulated time ``now``, else (errno, reason):
        ENODEV unknown camera, EINVAL bad mode, fps, half resolution or exposure and gain ``controls`` ([(id,
        value)]), EBUSY two other cameras already open."""
        problem = camera_settings_problem(name, width, height, fps, half_resolution)
        if problem:
            return problem
        try:
            brightness = control_brightness(controls)
        except ValueError as error:
            return errno.EINVAL, str(error)
        sensor, window = sensor_model(name), sensor_window(width, height, half_resolution)
        with self._lock:
            if name not in self._open and len(self._open) >= MAX_OPEN_CAMERAS:
                return errno.EBUSY, f'{", ".join(self._open)} already open (at most {MAX_OPEN_CAMERAS} cameras)'
            self._open[name] = OpenCamera(sensor, window, sensor.windowed(window), float(fps),
                                          RateSchedule(fps, start=now), brightness)
        return 0, ''

    def close(self, name):
        """0 when closed, EINVAL when it was not open (both accepted by baxter_interface)."""
        with self._lock:
            return 0 if self._open.pop(name, None) is not None else errno.EINVAL

    def due(self, now):
        """[(name, OpenCamera)] of the open cameras whose next frame is due at ``now``."""
        with self._lock:
            return [(name, cam) for name, cam in self._open.items() if cam.schedule.due(now)]

    def is_open(self, name):
        with self._lock:
            return name in self._open


def control_brightness(controls):
    """The factor on every intensity of the exposure and gain ``controls`` ([(CameraControl id, value)]; others
    ignored): exposure over ``AUTO_EXPOSURE`` times 1 + gain x ``GAIN_PER_UNIT``, each 1 when automatic (-1). The
    fake's model: the real sensor's curves are not published. ValueError for a value out of baxter_interface's
    ranges (``sdk.camera_control_problem``)."""
    factor = 1.0
    for control, value in controls:
        if control not in sdk.CAMERA_CONTROL_RANGES:
            continue
        problem = sdk.camera_control_problem(control, value)
        if problem:
            raise ValueError(problem)
        if value != sdk.CAMERA_CONTROL_AUTO:
            factor *= value / AUTO_EXPOSURE if control == sdk.CAMERA_CONTROL_EXPOSURE else 1.0 + value * GAIN_PER_UNIT
    return factor


def camera_settings_problem(name, width, height, fps, half_resolution=False):
    """None when camera ``name`` can run at ``width`` x ``height`` px and ``fps`` Hz (binned with
    ``half_resolution``), else (errno, reason)."""
    if name not in sdk.CAMERA_NAMES:
        return errno.ENODEV, f'unknown camera {name!r} (one of {", ".join(sdk.CAMERA_NAMES)})'
    if (width, height) not in sdk.CAMERA_MODES:
        return errno.EINVAL, (f'{width}x{height} is not a camera mode '
                              f'({", ".join("%dx%d" % mode for mode in sdk.CAMERA_MODES)})')
    if not 0 < fps <= MAX_CAMERA_FPS:
        return errno.EINVAL, f'fps must be in (0, {MAX_CAMERA_FPS:g}], got {fps:g}'
    if half_resolution and (2 * width > SENSOR_SIZE[0] or 2 * height > SENSOR_SIZE[1]):
        return errno.EINVAL, f'half resolution needs a mode of at most {SENSOR_SIZE[0] // 2}x{SENSOR_SIZE[1] // 2}'
    return None


def parse_camera_option(text):
    """``NAME:WIDTHxHEIGHT@FPS`` (``@FPS`` optional, default 20) -> (name, width, height, fps)."""
    match = re.fullmatch(r'(\w+):(\d+)x(\d+)(?:@(\d+(?:\.\d*)?))?', text)
    if not match:
        raise argparse.ArgumentTypeError(f'{text!r}: expected NAME:WIDTHxHEIGHT[@FPS], '
                                         f'e.g. left_hand_camera:640x400@20')
    name, width, height, fps = match.group(1), int(match.group(2)), int(match.group(3)), float(match.group(4) or 20)
    problem = camera_settings_problem(name, width, height, fps)
    if problem:
        raise argparse.ArgumentTypeError(f'{text!r}: {problem[1]}')
    return name, width, height, fps
