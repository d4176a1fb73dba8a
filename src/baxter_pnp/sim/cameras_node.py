"""The fake Baxter's cameras, the ROS edge (``baxter_interface.CameraController``, ``camera_control.py``, interfaces §8):
``/cameras/list|open|close|reset`` and each open camera's ``/cameras/<name>/image`` and ``camera_info``.

As on the robot, a camera's image topics exist only while it is open: ``open`` advertises them (before it answers),
``close`` and ``reset`` withdraw them, so ``camera_control.py -l``, which asks the master for publishers of
``/cameras/<name>/image``, lists exactly the open cameras. ``reset`` (std_srvs/Empty, "clear and re-enumerate the
devices") closes every camera. Each camera renders from its own URDF link (``left_hand_camera``, ``right_hand_camera``,
``head_camera``: the head camera pans with the head). The camera faults (``faults.camera``: drops, latency, stall,
blackout, brightness) act here. The camera bank (modes, at most two open) is ``sim.cameras``'s; its services run
in their own threads, the frames are captured by the main loop (``capture_due``), publishers under a lock.
"""
import errno
import threading
import time

import rospy
from sensor_msgs.msg import CameraInfo, Image
from std_msgs.msg import Header
from std_srvs.srv import Empty as EmptyService, EmptyResponse

from baxter_pnp.msgs import srv
from baxter_pnp.robot import sdk
from baxter_pnp.ros_image import bgr_to_msg
from baxter_pnp.sim.cameras import RESOLUTION_HALF_CONTROL, CameraBank, camera_settings_problem, image_model
from baxter_pnp.sim.faults import DelayLine

CAMERAS_RESET_SERVICE = '/cameras/reset'


class CamerasNode:
    """Camera services and image topics around ``world``'s renderer; ``noise_rng`` and ``frame_fault_rng`` are the
    image-noise and frame-fault generators; ``ros_time(now)`` the stamp of simulated time ``now`` (s);
    ``open_cameras`` [(name, width, height, fps)] open at boot."""

    def __init__(self, world, image_encoding, noise_rng, frame_fault_rng, ros_time, open_cameras=()):
        self.world, self.image_encoding, self._ros_time = world, image_encoding, ros_time
        self.faults = world.scene.faults.camera
        self._noise_rng, self._frame_fault_rng = noise_rng, frame_fault_rng
        self.bank = CameraBank()
        self._delayed_frames = DelayLine(self.faults.latency)    # (name, Image, CameraInfo) captured, not published
        self._publishers = {}             # {open camera: (image, camera_info) publishers}
        self._publishers_lock = threading.Lock()
        self.first_opened = None          # (wall s of time.monotonic, simulated s) of the first camera opened
        for name, width, height, fps in open_cameras:
            world.prepare_camera(image_model(name, width, height))
            self.bank.open(name, width, height, fps, now=0.0)
            world.start_fault_clock()
            self._note_first_open(0.0)
            self._advertise(name)
        rospy.Service(sdk.CAMERAS_LIST_SERVICE, srv.ListCameras,
                      lambda request: srv.ListCamerasResponse(self.bank.list()))
        rospy.Service(sdk.CAMERAS_OPEN_SERVICE, srv.OpenCamera, self._open_camera)
        rospy.Service(sdk.CAMERAS_CLOSE_SERVICE, srv.CloseCamera,
                      lambda request: srv.CloseCameraResponse(self._close_camera(request.name)))
        rospy.Service(CAMERAS_RESET_SERVICE, EmptyService, self._reset)

    def open_names(self):
        return [name for name in sdk.CAMERA_NAMES if self.bank.is_open(name)]

    # ------------------------------------------------------------------ services (their own threads)
    def _open_camera(self, request):
        settings = request.settings
        half = any(c.id == RESOLUTION_HALF_CONTROL and c.value > 0 for c in settings.controls)
        if not camera_settings_problem(request.name, settings.width, settings.height, settings.fps, half):
            # here, not at the first frame, where it would stall the loop
            self.world.prepare_camera(image_model(request.name, settings.width, settings.height, half))
        now = self.world.time               # one instant for the frame grid and the fault clock
        err, reason = self.bank.open(request.name, settings.width, settings.height, settings.fps, now, half,
                                     [(c.id, c.value) for c in settings.controls])
        if err:
            rospy.logwarn(f'{sdk.CAMERAS_OPEN_SERVICE} {request.name} refused ({errno.errorcode[err]}): {reason}')
        else:
            self.world.start_fault_clock(now)
            self._note_first_open(now)
            self._advertise(request.name)      # advertised before the answer, as the robot's driver does
        return srv.OpenCameraResponse(err)

    def _note_first_open(self, now):
        if self.first_opened is None:
            self.first_opened = (time.monotonic(), now)

    def _close_camera(self, name):
        """0 when closed (its topics withdrawn), EINVAL when it was not open."""
        with self._publishers_lock:
            err = self.bank.close(name)
            for publisher in self._publishers.pop(name, ()):
                publisher.unregister()
        return err

    def _reset(self, request):
        """Close every camera (the robot re-enumerates its USB cameras: none streams afterwards)."""
        closed = [name for name in self.open_names() if self._close_camera(name) == 0]
        rospy.loginfo(f'{CAMERAS_RESET_SERVICE}: cameras closed: {", ".join(closed) or "none"}')
        return EmptyResponse()

    def _advertise(self, name):
        with self._publishers_lock:
            if name not in self._publishers:
                image_topic, info_topic = sdk.camera_topics(name)
                # 10 frames queued per subscriber: unpaced, the fake can publish faster than a busy subscriber reads
                self._publishers[name] = (rospy.Publisher(image_topic, Image, queue_size=10),
                                          rospy.Publisher(info_topic, CameraInfo, queue_size=10))

    # ------------------------------------------------------------------ frames (the main loop)
    def capture_due(self, now):
        """Render the frames due at ``now`` (s) and publish those whose latency has passed (if still open)."""
        for name, cam in self.bank.due(now):
            self._capture(name, cam, now)
        for name, image, info in self._delayed_frames.due(now):
            with self._publishers_lock:
                if name in self._publishers and self.bank.is_open(name):
                    image_publisher, info_publisher = self._publishers[name]
                    image_publisher.publish(image)
                    info_publisher.publish(info)

    def _capture(self, name, cam, now):
        """Render the frame due at ``now`` (s) and queue it for publication after the camera latency fault;
        the frame-drop, stall, blackout and brightness faults apply here."""
        fault_time = self.world.fault_time(now)
        if not self.faults.publishes(fault_time, self._frame_fault_rng.random()):
            return
        header = Header(stamp=self._ros_time(now), frame_id='/' + name)     # as the robot: leading /
        image = self.world.render_camera(name, cam.model, self._noise_rng,
                                         gain=self.faults.gain(fault_time) * cam.brightness)
        self._delayed_frames.put(now, (name, bgr_to_msg(image, self.image_encoding, header), cam.camera_info(header)))
