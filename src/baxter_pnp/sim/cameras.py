"""The fake Baxter's camera bank, pure (no ROS): ``/cameras/list|open|close`` semantics (known cameras, the
SDK's modes, at most two open at once, as the real robot powers), each open camera's published model and frame
schedule in simulated time, and the ``--camera NAME:WIDTHxHEIGHT@FPS`` option."""
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


@dataclasses.dataclass
class OpenCamera:
    """An open camera: its published model (resolution, intrinsics), frame rate and schedule."""
    model: camera_module.CameraModel
    fps: float
    schedule: RateSchedule


def camera_model_for(name, width, height):
    """The published model of camera ``name`` at ``width`` x ``height``: the thesis calibration, scaled."""
    model = camera_module.load_default_camera().scaled(width, height)
    return dataclasses.replace(model, name=name, frame_id=name)


class CameraBank:
    """``/cameras/list|open|close`` semantics: known cameras, allowed modes, at most two open (thread-safe)."""

    def __init__(self):
        self._lock = threading.Lock()
        self._open = {}

    def list(self):
        return list(sdk.CAMERA_NAMES)

    def open(self, name, width, height, fps, now):
        """(0, '') when opened (or re-opened with new settings) at simulated time ``now``, else (errno, reason):
        ENODEV unknown camera, EINVAL bad mode or fps, EBUSY two other cameras already open."""
        problem = camera_settings_problem(name, width, height, fps)
        if problem:
            return problem
        with self._lock:
            if name not in self._open and len(self._open) >= MAX_OPEN_CAMERAS:
                return errno.EBUSY, f'{", ".join(self._open)} already open (at most {MAX_OPEN_CAMERAS} cameras)'
            self._open[name] = OpenCamera(camera_model_for(name, width, height), float(fps),
                                          RateSchedule(fps, start=now))
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


def camera_settings_problem(name, width, height, fps):
    """None when camera ``name`` can run at ``width`` x ``height`` px and ``fps`` Hz, else (errno, reason)."""
    if name not in sdk.CAMERA_NAMES:
        return errno.ENODEV, f'unknown camera {name!r} (one of {", ".join(sdk.CAMERA_NAMES)})'
    if (width, height) not in sdk.CAMERA_MODES:
        return errno.EINVAL, (f'{width}x{height} is not a camera mode '
                              f'({", ".join("%dx%d" % mode for mode in sdk.CAMERA_MODES)})')
    if not 0 < fps <= MAX_CAMERA_FPS:
        return errno.EINVAL, f'fps must be in (0, {MAX_CAMERA_FPS:g}], got {fps:g}'
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
