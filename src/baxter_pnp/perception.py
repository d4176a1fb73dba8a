"""Perception: one camera image in -> detected blocks with their 3D pose out (no ROS).

Composes the vision pipeline (``vision.detect``) with the model-based pose estimator
(``pose.estimate_pose``), and draws the annotated debug image. Used by ``scripts/detect_image.py``,
the perception benchmark and the pick application.
"""
from dataclasses import dataclass
from typing import Optional

import cv2
import numpy as np

from baxter_pnp import models, pose, vision

# px: a top face split off its blob whose pose leaves a larger RMS residual has its whole blob tried too (the better
# fit is kept): a shadow's edge across the face cut a corner off it (pick.PickConfig.max_residual_px believes 2 px)
SPLIT_FACE_MAX_RESIDUAL_PX = 2.0


@dataclass
class BlockObservation:
    """A detected block and, when estimation succeeded, its pose in the camera optical frame."""

    detection: vision.Detection
    pose: Optional[pose.PoseEstimate]
    error: Optional[str] = None

    def to_json(self):
        """JSON-ready dict (pixels, metres, quaternion x y z w); pose fields are None on failure."""
        d = self.detection
        estimate = self.pose
        return {
            'shape': d.shape,
            'colour': d.colour,
            'vertices_px': np.round(d.vertices_px, 3).tolist(),
            'centroid_px': np.round(d.centroid_px, 3).tolist(),
            'position_m': None if estimate is None else np.round(estimate.position_m, 6).tolist(),
            'orientation_xyzw': None if estimate is None else np.round(estimate.quaternion_xyzw, 6).tolist(),
            'depth_m': None if estimate is None else round(float(estimate.depth_m), 6),
            'residual_px': None if estimate is None else round(float(estimate.residual_px), 4),
            'error': self.error,
        }


def observe_blocks(image_bgr, camera, vision_config, side, height=0.02, shape=None, colour=None,
                   method='sqp', table_plane=None, edge_radius=0.0):
    """Detect blocks in ``image_bgr`` and estimate the pose of each.

    ``side`` and ``height`` (m) describe the block model, ``edge_radius`` (m) how far its top rim is rounded over
    (``models.seen_model``: 0 for sharp blocks); ``shape``/``colour`` restrict the detections (None = any).
    ``table_plane`` is the table-top ``models.Plane`` in the camera frame, if known.
    Returns a list of ``BlockObservation`` (pose None and ``error`` set where estimation failed). Where a top face
    split off its blob gets no pose, is not ``shape``, or is posed with a residual above
    ``SPLIT_FACE_MAX_RESIDUAL_PX``, the whole blob is tried (``vision.blob_detection``; of two poses the one with the
    smaller residual is kept): a shadow across the face (the arm's, over the block it approaches) cuts the face as a
    side face would; a blob that is not ``shape`` or gets no pose either adds nothing of another shape.
    ValueError when the image is not the camera model's size (its poses would be silently wrong).
    """
    size = vision.validate_image(image_bgr).shape[:2]
    if size != (camera.height, camera.width):
        raise ValueError(f'observe_blocks: the image is {size[1]}x{size[0]} but the camera model is '
                         f'{camera.width}x{camera.height}: scale or crop the model to the image first')
    detections = vision.detect(image_bgr, vision_config, colours=None if colour is None else [colour])
    observations = []
    for detection in detections:
        if shape is not None and detection.shape != shape:
            observation = _whole_blob_observation(image_bgr, detection, vision_config, shape, side, height, camera,
                                                  method, table_plane, edge_radius)
            if observation is not None and observation.pose is not None:
                observations.append(observation)
            continue
        model = models.seen_model(detection.shape, side, height, edge_radius)
        try:
            estimate = pose.estimate_pose(detection.vertices_px, camera, model, method=method,
                                          table_plane=table_plane)
        except pose.PoseEstimationError as exc:
            observation = _whole_blob_observation(image_bgr, detection, vision_config, detection.shape, side, height,
                                                  camera, method, table_plane, edge_radius)
            if observation is None or observation.pose is None:
                error = str(exc) + ('' if observation is None else f'; the whole blob: {observation.error}')
                observation = BlockObservation(detection, None, error)
            observations.append(observation)
            continue
        observation = BlockObservation(detection, estimate)
        if estimate.residual_px > SPLIT_FACE_MAX_RESIDUAL_PX:
            whole = _whole_blob_observation(image_bgr, detection, vision_config, detection.shape, side, height, camera,
                                            method, table_plane, edge_radius)
            if whole is not None and whole.pose is not None and whole.pose.residual_px < estimate.residual_px:
                observation = whole
        observations.append(observation)
    return observations


def _whole_blob_observation(image_bgr, detection, vision_config, shape, side, height, camera, method, table_plane,
                            edge_radius):
    """The observation of ``detection``'s whole blob (``vision.blob_detection``) as a ``shape`` block, when the top
    face split off it got no pose, a poor fit or has another shape (a shadow's edge across the face taken for a side
    face's): with its pose, or with the pose's error; None when there was no split or the blob is no ``shape``."""
    whole = vision.blob_detection(image_bgr, detection, vision_config, shape)
    if whole is None:
        return None
    try:
        model = models.seen_model(shape, side, height, edge_radius)
        return BlockObservation(whole, pose.estimate_pose(whole.vertices_px, camera, model, method=method,
                                                          table_plane=table_plane))
    except pose.PoseEstimationError as exc:
        return BlockObservation(whole, None, str(exc))


def annotate(image_bgr, observations, camera, axis_length=0.02):
    """Copy of the image with each block's contour, vertices, pose axes (m) and depth drawn on it."""
    canvas = vision.draw_detections(image_bgr, [o.detection for o in observations])
    for observation in observations:
        estimate = observation.pose
        if estimate is None:
            continue
        rvec, _ = cv2.Rodrigues(estimate.T_camera_object[:3, :3])
        tvec = estimate.T_camera_object[:3, 3].reshape(3, 1)
        cv2.drawFrameAxes(canvas, camera.K, camera.D, rvec, tvec, axis_length, 2)
        u, v = (int(round(c)) for c in observation.detection.centroid_px)
        cv2.putText(canvas, 'Z=%.1f mm' % (1000.0 * estimate.depth_m), (u + 8, v + 22),
                    cv2.FONT_HERSHEY_SIMPLEX, 0.5, (0, 0, 255), 1, cv2.LINE_AA)
    return canvas
