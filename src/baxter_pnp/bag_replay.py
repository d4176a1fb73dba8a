"""Replay of a recorded run: the frames of a rosbag's image topic, each with the CameraInfo in effect at its stamp.

A run recorded on the robot with ``rosbag record`` (docs/perception.md, "Replaying a recorded run") holds the hand
camera's ``sensor_msgs/Image`` and ``sensor_msgs/CameraInfo`` topics. ``BagReplay`` reads them with Debian's
``python3-rosbag`` (no master, no rospy): per image message a ``BagFrame`` with the uint8 BGR image and the
``CameraModel`` of the latest CameraInfo stamped at or before the image's stamp, read as ``image_geometry`` reads it
(``CameraModel.from_camera_info``: ROI, binning, leading ``/`` of ``frame_id`` dropped).

Times: a message's time is its header stamp, or the time it was recorded when the stamp is zero (an unstamped
driver); nanoseconds of ROS time. Images are decoded by ``ros_image`` (bgra8, bgr8, rgb8); mono8 is refused (the
pipeline segments by colour), as is any other encoding.
"""
import bisect
import os
import posixpath
from dataclasses import dataclass
from typing import Optional

import genpy
import numpy as np
import rosbag

from baxter_pnp import ros_image
from baxter_pnp.camera import CameraModel

IMAGE_TYPE = 'sensor_msgs/Image'
CAMERA_INFO_TYPE = 'sensor_msgs/CameraInfo'


class BagTopicError(ValueError):
    """A topic named (or implied) by the arguments is not in the bag, has another type, or is ambiguous."""


class BagReadError(OSError):
    """The bag cannot be read (missing, not a bag, unindexed, corrupt)."""


@dataclass
class BagFrame:
    """One image message of the replayed topic.

    ``stamp_ns``: its time (ns, see the module); ``seq`` and ``frame_id`` (leading ``/`` dropped) of its header;
    ``image_bgr``: uint8 (H, W, 3); ``camera``: the model of the CameraInfo in effect (same size as the image), or
    the fallback camera (any size). ``error``: why the frame cannot be used (then ``image_bgr`` is None).
    """
    stamp_ns: int
    seq: int
    frame_id: str
    image_bgr: Optional[np.ndarray]
    camera: Optional[CameraModel]
    error: Optional[str] = None

    @property
    def stamp(self):
        """The frame's time in seconds (float)."""
        return self.stamp_ns / 1e9


def sibling_camera_info_topic(image_topic):
    """The ``camera_info`` topic next to ``image_topic`` (``/a/b/image`` -> ``/a/b/camera_info``)."""
    return posixpath.join(posixpath.dirname(image_topic), 'camera_info')


def decode_image(msg):
    """uint8 BGR (H, W, 3) of a ``sensor_msgs/Image``; ValueError for mono8 or an unsupported encoding."""
    if msg.encoding == 'mono8':
        raise ValueError('mono8 image: the pipeline segments by colour; record the colour image topic '
                         '(bgra8, bgr8 or rgb8)')
    return ros_image.msg_to_bgr(msg)


class BagReplay:
    """The frames of ``image_topic`` in the rosbag at ``path``, with the CameraInfo of ``camera_info_topic``.

    ``image_topic`` None: the bag's only ``sensor_msgs/Image`` topic. ``camera_info_topic`` None: the image
    topic's sibling ``camera_info``. ``fallback_camera`` (a ``CameraModel``, e.g. from ``--camera-info``) is used
    for frames before the first CameraInfo, or for all frames when the bag has no CameraInfo topic and none was
    named. Opening raises ``BagReadError`` (unreadable bag) or ``BagTopicError`` (message lists the bag's topics).
    Use as a context manager, or ``close()``.
    """

    def __init__(self, path, image_topic=None, camera_info_topic=None, fallback_camera=None):
        self.path = path
        self.fallback_camera = fallback_camera
        self.skipped_without_camera_info = 0     # frames before any CameraInfo (and no fallback): not yielded
        if not os.path.isfile(path):
            raise BagReadError(f'cannot read bag {path}: no such file')
        try:
            self._bag = rosbag.Bag(path)
        except rosbag.ROSBagUnindexedException:
            raise BagReadError(f'cannot read bag {path}: it is not indexed (recording interrupted?): '
                               f'run `rosbag reindex {path}`') from None
        except (rosbag.ROSBagException, ValueError, OSError) as error:
            raise BagReadError(f'cannot read bag {path}: {error}') from None
        try:
            self._topics = {name: info.msg_type for name, info in self._bag.get_type_and_topic_info().topics.items()}
            self.image_topic = self._image_topic(image_topic)
            self.camera_info_topic = self._camera_info_topic(camera_info_topic)
            self._info_times, self._info_messages = self._read_camera_infos()
        except BaseException:
            self._bag.close()
            raise
        self._models = {}                # index in the CameraInfo timeline -> (model, error)

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    def close(self):
        self._bag.close()

    def topics_listing(self):
        """``topic (type)`` of every topic in the bag, for error messages."""
        return ', '.join(f'{name} ({msg_type})' for name, msg_type in sorted(self._topics.items())) or 'none'

    def _check_topic(self, topic, msg_type, option):
        topic = topic if topic.startswith('/') else '/' + topic
        if topic not in self._topics:
            raise BagTopicError(f'{self.path} has no topic {topic} ({option}); its topics: {self.topics_listing()}')
        if self._topics[topic] != msg_type:
            raise BagTopicError(f'{self.path}: {topic} holds {self._topics[topic]}, not {msg_type} ({option}); '
                                f'its topics: {self.topics_listing()}')
        return topic

    def _image_topic(self, image_topic):
        if image_topic is not None:
            return self._check_topic(image_topic, IMAGE_TYPE, '--image-topic')
        images = sorted(name for name, msg_type in self._topics.items() if msg_type == IMAGE_TYPE)
        if len(images) != 1:
            raise BagTopicError(f'{self.path} has {len(images)} {IMAGE_TYPE} topics: choose one with --image-topic; '
                                f'its topics: {self.topics_listing()}')
        return images[0]

    def _camera_info_topic(self, camera_info_topic):
        if camera_info_topic is not None:
            return self._check_topic(camera_info_topic, CAMERA_INFO_TYPE, '--camera-info-topic')
        sibling = sibling_camera_info_topic(self.image_topic)
        if sibling not in self._topics and self.fallback_camera is not None:
            return None                                    # every frame uses the fallback camera
        return self._check_topic(sibling, CAMERA_INFO_TYPE, 'the image topic\'s camera_info; give '
                                 '--camera-info-topic, or --camera-info YAML for a bag without one')

    def _read_camera_infos(self):
        """Sorted times (ns) and the CameraInfo messages at them (a stable sort: at equal times the last recorded
        comes last, and wins)."""
        if self.camera_info_topic is None:
            return [], []
        timeline = sorted(((_message_time_ns(msg, t), k, msg) for k, (_, msg, t)
                           in enumerate(self._read_messages(self.camera_info_topic))), key=lambda e: e[:2])
        return [e[0] for e in timeline], [e[2] for e in timeline]

    def _read_messages(self, topic):
        try:
            yield from self._bag.read_messages(topics=[topic])
        except (rosbag.ROSBagException, genpy.DeserializationError, ValueError, OSError) as error:
            raise BagReadError(f'cannot read bag {self.path} ({topic}): {error}') from None

    def _camera_at(self, time_ns):
        """(model, error) of the CameraInfo in effect at ``time_ns``; (None, None) if none was received yet."""
        index = bisect.bisect_right(self._info_times, time_ns) - 1
        if index < 0:
            return None, None
        if index not in self._models:
            try:
                self._models[index] = (CameraModel.from_camera_info(self._info_messages[index]), None)
            except ValueError as error:
                self._models[index] = (None, f'its camera_info ({self.camera_info_topic}) is unusable: {error}')
        return self._models[index]

    def frames(self, every=1, max_frames=None):
        """``BagFrame`` of every ``every``-th image message (the first included), at most ``max_frames`` of them
        (None: all). Frames before any CameraInfo and without a fallback camera are counted in
        ``skipped_without_camera_info``, not yielded. Raises ``BagReadError`` if the bag is corrupt."""
        self.skipped_without_camera_info = 0
        taken = 0
        for index, (_, msg, t) in enumerate(self._read_messages(self.image_topic)):
            if index % every:
                continue
            if max_frames is not None and taken >= max_frames:
                break
            taken += 1
            time_ns = _message_time_ns(msg, t)
            camera, error = self._camera_at(time_ns)
            published = camera is not None or error is not None
            if not published and self.fallback_camera is not None:
                camera = self.fallback_camera
            if camera is None and error is None:
                self.skipped_without_camera_info += 1
                continue
            if error is None:
                image_bgr, error = _decoded(msg, camera if published else None)
            yield BagFrame(time_ns, int(msg.header.seq), msg.header.frame_id.lstrip('/'),
                           None if error else image_bgr, camera, error)


def _decoded(msg, published_camera):
    """(uint8 BGR image, None) of an image message, or (None, why not): a bad encoding or layout, or a size that
    is not the one of ``published_camera`` (the CameraInfo in effect; None: no size to check)."""
    try:
        image_bgr = decode_image(msg)
    except ValueError as error:
        return None, str(error)
    size = (image_bgr.shape[1], image_bgr.shape[0])
    if published_camera is not None and size != (published_camera.width, published_camera.height):
        return None, (f'the image is {size[0]}x{size[1]} but its camera_info describes a '
                      f'{published_camera.width}x{published_camera.height} image')
    return image_bgr, None


def _message_time_ns(msg, recorded):
    """The header stamp of ``msg`` (ns), or the time it was ``recorded`` when the stamp is zero."""
    stamp = msg.header.stamp.to_nsec()
    return stamp if stamp else recorded.to_nsec()
