"""The eye: one look through the hand camera = a fresh frame + the endpoint pose at its stamp + the hand-eye
transform -> the blocks it shows, posed in ``base``; what the hand's own fingers hide in the image; and what a
user watches: the annotated view on ``/baxter_pnp/debug_image`` (and, asked to, as numbered PNGs), the chosen
block on ``/baxter_pnp/target_pose`` (PoseStamped in ``base``) and as tf frame ``block``. ROS edge.

Frames: ``T_base_gripper`` (the ``<side>_gripper`` tip), ``T_base_camera`` (the hand camera's optical frame),
``T_base_block`` (docs/ARCHITECTURE.md's block frame); 4x4, metres.
"""
import os
from typing import List, NamedTuple, Optional

import numpy as np
import rospy
from geometry_msgs.msg import PoseStamped, TransformStamped
from sensor_msgs.msg import Image

from baxter_pnp import perception, robot, view
from baxter_pnp.models import Plane, table_plane_in_camera
from baxter_pnp.ros_image import bgr_to_msg
from baxter_pnp.transforms import matrix_to_pose_msg, to_xyz_quat

DEBUG_IMAGE_TOPIC = '/baxter_pnp/debug_image'
TARGET_POSE_TOPIC = '/baxter_pnp/target_pose'
BLOCK_FRAME = 'block'


class Look(NamedTuple):
    """One look through the hand camera and what it found (poses 4x4 in base, metres)."""
    frame: robot.Frame
    T_base_gripper: np.ndarray
    T_base_camera: np.ndarray
    observations: List[perception.BlockObservation]
    target: Optional[perception.BlockObservation]
    T_base_block: Optional[np.ndarray]        # the target's pose, None without a target
    predicted: bool = False                   # the target is the last estimate carried over, not seen in this frame


class BlockQuery(NamedTuple):
    """What the eye looks for: a block ``shape`` (None: any) and ``colour`` (None: any), ``side_length`` and
    ``height`` (m), posed by ``estimator`` ('sqp' | 'ippe' | 'sqpnp') on the ``table`` top (a ``models.Plane`` in
    base, e.g. ``RobotSession.table``), its top rim rounded over with ``edge_radius`` (m, ``models.seen_model``);
    ``towers``: blocks may stand on others (``perception.observe_blocks``)."""
    shape: Optional[str]
    colour: Optional[str]
    side_length: float
    height: float
    estimator: str
    table: Plane
    edge_radius: float = 0.0
    towers: bool = False


class Eye:
    """Looks of a connected ``task.session.RobotSession``; ``vision_config`` a ``vision.VisionConfig``."""

    def __init__(self, session, vision_config, query, views_dir=None, publish=True):
        self.session = session
        self.vision_config = vision_config
        self.query = query
        self.views_dir = views_dir          # every annotated view saved here as a PNG (None: not saved)
        self.last_annotated = None
        self._views_saved = 0
        self._hand_clearance = {}           # camera model key -> view.hand_clearance_px map
        self._publish = publish
        if publish:
            import tf2_ros
            self._debug_pub = rospy.Publisher(DEBUG_IMAGE_TOPIC, Image, queue_size=1, latch=True)   # a late viewer sees the last look
            self._target_pub = rospy.Publisher(TARGET_POSE_TOPIC, PoseStamped, queue_size=1, latch=True)
            self._tf = tf2_ros.TransformBroadcaster()

    def frame(self, after_stamp=None):
        """The next camera frame newer than ``after_stamp`` (ROS time, s), with the calibration override's
        camera model if the session has one; StreamLost if none comes within ``frame_timeout``."""
        session = self.session
        timeout = session.config.frame_timeout
        try:
            frame = session.camera.wait_for_frame(after_stamp, timeout=timeout)
        except robot.RobotTimeout as error:
            raise robot.StreamLost(session.camera.image_topic, timeout, timeout) from error
        if session.camera_override is not None:
            frame = frame._replace(camera=session.camera_override)
        return frame

    def look(self, after_stamp=None, choose=None):
        """Check the robot, wait for a frame newer than ``after_stamp``, detect and pose the query's blocks.
        ``choose(observations, T_base_camera, camera)`` picks the target (e.g. ``task.target.choose_target``);
        the view and the target are published. Returns a :class:`Look`."""
        session, q = self.session, self.query
        session.check_robot()
        frame = self.frame(after_stamp)
        T_base_gripper = session.limb.endpoint_pose_at(frame.stamp)
        T_base_camera = T_base_gripper @ session.hand_eye.T_gripper_camera
        plane = table_plane_in_camera(T_base_camera, q.table)
        observations = perception.observe_blocks(frame.image_bgr, frame.camera, self.vision_config, q.side_length,
                                                 q.height, shape=q.shape, colour=q.colour, method=q.estimator,
                                                 table_plane=plane, edge_radius=q.edge_radius, towers=q.towers)
        target = None if choose is None else choose(observations, T_base_camera, frame.camera)
        T_base_block = None if target is None else T_base_camera @ target.pose.T_camera_object
        self.show(frame, observations, T_base_block)
        return Look(frame, T_base_gripper, T_base_camera, observations, target, T_base_block)

    def hand_clearance(self, camera):
        """The hand's clearance map in ``camera``'s image (``view.hand_clearance_px``: each pixel's distance to the
        open fingers, ray-cast from the URDF's gripper solids through the hand-eye transform), once per model."""
        key = (camera.width, camera.height, camera.K.tobytes(), camera.D.tobytes())
        if key not in self._hand_clearance:
            self._hand_clearance[key] = view.hand_clearance_of(self.session.kinematics,
                                                               self.session.hand_eye.T_gripper_camera, camera)
            rospy.loginfo('%s: the open fingers hide %.1f %% of the %dx%d image'
                          % (self.session.log_name, 100.0 * np.mean(self._hand_clearance[key] == 0),
                             camera.width, camera.height))
        return self._hand_clearance[key]

    def show(self, frame, observations, T_base_block):
        """The annotated view on the debug image topic (and saved to ``views_dir``); the block's pose on the
        target pose topic and as tf frame ``block``."""
        annotated = perception.annotate(frame.image_bgr, observations, frame.camera)
        self.last_annotated = annotated
        if self.views_dir:
            import cv2
            self._views_saved += 1
            os.makedirs(self.views_dir, exist_ok=True)
            cv2.imwrite(os.path.join(self.views_dir, 'view_%04d_t%.2f.png' % (self._views_saved, frame.stamp)),
                        annotated)
        if not self._publish:
            return
        stamp = rospy.Time.from_sec(frame.stamp)
        message = bgr_to_msg(annotated, 'bgr8')
        message.header.stamp = stamp
        message.header.frame_id = frame.camera.frame_id
        self._debug_pub.publish(message)
        if T_base_block is None:
            return
        pose = PoseStamped()
        pose.header.stamp, pose.header.frame_id = stamp, 'base'
        matrix_to_pose_msg(T_base_block, pose.pose)
        self._target_pub.publish(pose)
        transform = TransformStamped()
        transform.header.stamp, transform.header.frame_id, transform.child_frame_id = stamp, 'base', BLOCK_FRAME
        xyz, quat = to_xyz_quat(T_base_block)
        t, r = transform.transform.translation, transform.transform.rotation
        t.x, t.y, t.z = (float(v) for v in xyz)
        r.x, r.y, r.z, r.w = (float(v) for v in quat)
        self._tf.sendTransform(transform)
