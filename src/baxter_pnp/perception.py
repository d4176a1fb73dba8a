"""Perception: one camera image in -> detected blocks with their 3D pose out (no ROS).

Composes the vision pipeline (``vision.detect``) with the model-based pose estimator
(``pose.estimate_pose``; with the table plane known, ``on_table.fit_top_face`` and ``silhouette.fit_on_table``
for the polygons it cannot pose well), and draws the annotated debug image. Used by ``scripts/detect_image.py``,
the perception benchmark and the pick application.
"""
import dataclasses
from dataclasses import dataclass
from typing import Optional

import cv2
import numpy as np

from baxter_pnp import models, on_table, pose, silhouette, vision

# px: a top face split off its blob whose pose leaves a larger RMS residual has its whole blob tried too (the better
# fit is kept): a shadow's edge across the face cut a corner off it (pick.PickConfig.max_residual_px believes 2 px)
SPLIT_FACE_MAX_RESIDUAL_PX = 2.0
# With the table plane known, a block whose polygon got no pose or one with a residual over
# SPLIT_FACE_MAX_RESIDUAL_PX, or whose polygon's mean side is under SILHOUETTE_MAX_SIDE_PX (px) and its pose misses
# the table's height by more than three of its stds, is posed from its silhouette on the table
# (``silhouette.fit_on_table``) when that fit overlaps its blob's outline by at least SILHOUETTE_MIN_OVERLAP
# (intersection over union), or, for a small blob, as much as outlines SILHOUETTE_SLACK_PX apart all round do
# (``silhouette_min_overlap``): a 15-30 px polygon's size fixes its depth to centimetres only, the table to
# millimetres (docs/perception.md, "A small block's pose from its silhouette on the table").
SILHOUETTE_MAX_SIDE_PX = 30.0
# Before its silhouette, such a polygon (and any under SILHOUETTE_MAX_SIDE_PX) is posed by its top face fitted on the
# table (``on_table.fit_top_face``) when that face's shape fits within SPLIT_FACE_MAX_RESIDUAL_PX and its size is the
# model's within TOP_FACE_SIZE_FRACTION plus TOP_FACE_SIZE_PX over its side (px): a face's edges are found to a pixel
# or two whatever its size (the independent renderer's true 15-30 px faces: 95 % within 4.5 px of their size), a
# block of another size differs by a fraction of it (docs/perception.md, "A small face's pose on the table").
TOP_FACE_SIZE_FRACTION = 0.1
TOP_FACE_SIZE_PX = 3.0
SILHOUETTE_MIN_OVERLAP = 0.85
SILHOUETTE_SLACK_PX = 1.25
# m: a larger polygon's good pose is kept while it puts the top face within this of the table's height (the pick's
# max_height_error, beyond which its height rule refuses a certain pose; four of the table height's standard
# deviations, table_height_sigma); beyond, its polygon holds a side face or misses a rim (a real cube's pose 15 cm
# too close from 1 m) and it is tried on the table as a poor one is (docs/perception.md, "A larger polygon off the
# table").
TABLE_MISS_M = 0.02
ON_THE_TABLE_METHODS = ('on_table', 'silhouette')    # PoseEstimate.method of the poses taken on the table
# A hexagon whose cast onto the table leaves this RMS residual over its side, or more, against a regular hexagon is
# no hexagonal block's top face; asked for a square, it is fitted as a cube seen from a corner
# (``_cube_seen_from_a_corner``)
CORNER_VIEW_MIN_IRREGULARITY = 0.15


@dataclass
class BlockObservation:
    """A detected block and, when estimation succeeded, its pose in the camera optical frame."""

    detection: vision.Detection
    pose: Optional[pose.PoseEstimate]
    error: Optional[str] = None

    def to_json(self):
        """JSON-ready dict (pixels, metres, quaternion x y z w; ``method``: what posed it, e.g. ``sqp`` or
        ``silhouette``); pose fields are None on failure."""
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
            'method': None if estimate is None else estimate.method,
            'error': self.error,
        }


def observe_blocks(image_bgr, camera, vision_config, side, height=0.02, shape=None, colour=None,
                   method='sqp', table_plane=None, edge_radius=0.0, towers=False):
    """Detect blocks in ``image_bgr`` and estimate the pose of each.

    ``side`` and ``height`` (m) describe the block model, ``edge_radius`` (m) how far its top rim is rounded over
    (``models.seen_model``: 0 for sharp blocks); ``shape``/``colour`` restrict the detections (None = any).
    ``table_plane`` is the table-top ``models.Plane`` in the camera frame, if known; ``towers``: blocks may stand
    on others (the table task's towers), so a polygon's pose above the table is not taken for a poor one.
    Returns a list of ``BlockObservation`` (pose None and ``error`` set where estimation failed). Where a top face
    split off its blob gets no pose, is not ``shape``, or is posed with a residual above
    ``SPLIT_FACE_MAX_RESIDUAL_PX``, the whole blob is tried (``vision.blob_detection``; of two poses the one with the
    smaller residual is kept): a shadow across the face (the arm's, over the block it approaches) cuts the face as a
    side face would; a blob that is not ``shape`` or gets no pose either adds nothing of another shape. With a
    ``table_plane``, a polygon that got no pose or a poor one, a small one, or one whose pose misses the table
    (``_on_the_table``), is posed on the table by its top face or its silhouette when that fits (method
    ``'on_table'`` or ``'silhouette'``); asked for a square, a hexagon that is no hexagonal block's top face is tried
    as a cube seen from a corner (``_cube_seen_from_a_corner``).
    ValueError when the image is not the camera model's size (its poses would be silently wrong).
    """
    size = vision.validate_image(image_bgr).shape[:2]
    if size != (camera.height, camera.width):
        raise ValueError(f'observe_blocks: the image is {size[1]}x{size[0]} but the camera model is '
                         f'{camera.width}x{camera.height}: scale or crop the model to the image first')
    detections = vision.detect(image_bgr, vision_config, colours=None if colour is None else [colour])
    observations = []
    for detection in detections:
        observation = _polygon_observation(image_bgr, detection, vision_config, shape, side, height, camera, method,
                                           table_plane, edge_radius)
        if observation is not None and table_plane is not None:
            observation = _on_the_table(observation, camera, side, height, table_plane, edge_radius, towers)
        elif table_plane is not None and (shape, detection.shape) == ('square', 'hexagon'):
            observation = _cube_seen_from_a_corner(detection, camera, side, height, table_plane, edge_radius)
        if observation is not None:
            observations.append(observation)
    return observations


def _polygon_observation(image_bgr, detection, vision_config, shape, side, height, camera, method, table_plane,
                         edge_radius):
    """``detection``'s observation from its polygon (``observe_blocks``), or None for a detection of another shape
    than ``shape`` whose whole blob is no posed ``shape`` either."""
    if shape is not None and detection.shape != shape:
        observation = _whole_blob_observation(image_bgr, detection, vision_config, shape, side, height, camera,
                                              method, table_plane, edge_radius)
        return observation if observation is not None and observation.pose is not None else None
    model = models.seen_model(detection.shape, side, height, edge_radius)
    try:
        estimate = pose.estimate_pose(detection.vertices_px, camera, model, method=method, table_plane=table_plane)
    except pose.PoseEstimationError as exc:
        observation = _whole_blob_observation(image_bgr, detection, vision_config, detection.shape, side, height,
                                              camera, method, table_plane, edge_radius)
        if observation is None or observation.pose is None:
            error = str(exc) + ('' if observation is None else f'; the whole blob: {observation.error}')
            observation = BlockObservation(detection, None, error)
        return observation
    observation = BlockObservation(detection, estimate)
    if estimate.residual_px > SPLIT_FACE_MAX_RESIDUAL_PX:
        whole = _whole_blob_observation(image_bgr, detection, vision_config, detection.shape, side, height, camera,
                                        method, table_plane, edge_radius)
        if whole is not None and whole.pose is not None and whole.pose.residual_px < estimate.residual_px:
            observation = whole
    return observation


def _on_the_table(observation, camera, side, height, table_plane, edge_radius, towers=False):
    """``observation`` posed on the table when its polygon is small (under ``SILHOUETTE_MAX_SIDE_PX``), got no good
    pose or a good one more than ``TABLE_MISS_M`` off the table's height (with ``towers``, below it only): by its top
    face fitted on the table (method ``'on_table'``, ``residual_px`` that fit's, no covariance) when
    that face is the model's in shape and size; else, unless its own pose sits on the table (``_sits_on``), from its
    silhouette (``_silhouette_observation``); else itself. The shape stays the polygon's: at 15-30 px a pentagon's
    or a hexagon's silhouette fits a square prism's as well (intersection over union 0.88-0.90)."""
    detection, estimate = observation.detection, observation.pose
    polygon = detection.vertices_px
    mean_side = float(np.linalg.norm(polygon - np.roll(polygon, -1, axis=0), axis=1).mean())
    good = estimate is not None and estimate.residual_px <= SPLIT_FACE_MAX_RESIDUAL_PX
    small = mean_side < SILHOUETTE_MAX_SIDE_PX
    if good and not small:
        miss = _height_error_m(estimate, table_plane, height)
        if abs(miss) <= TABLE_MISS_M or (towers and miss > 0.0):
            return observation
    on_top = top_face_on_plane(detection, camera, side, height, table_plane, edge_radius)
    if on_top is not None:
        return BlockObservation(detection, on_top[0])
    if good and _sits_on(estimate, table_plane, height):
        return observation
    return _silhouette_observation(detection, detection.shape, camera, side, height, table_plane,
                                   edge_radius) or observation


def top_face_on_plane(detection, camera, side, height, plane, edge_radius=0.0):
    """``(PoseEstimate, fit)``: ``detection``'s polygon fitted as the top face of a ``side`` x ``height`` (m) block
    standing on ``plane`` (camera frame; ``on_table.fit_top_face``'s ``TopFaceFit``; the estimate's method
    ``'on_table'``, its ``residual_px`` the fit's, no covariance) when that face is the model's in shape (within
    ``SPLIT_FACE_MAX_RESIDUAL_PX``) and size (within ``TOP_FACE_SIZE_FRACTION`` plus ``TOP_FACE_SIZE_PX`` over its
    side); else None."""
    seen = models.seen_model(detection.shape, side, height, edge_radius)
    face = on_table.fit_top_face(detection.vertices_px, camera, seen, plane)
    if (face is None or face.residual_px > SPLIT_FACE_MAX_RESIDUAL_PX
            or abs(face.scale - 1.0) > TOP_FACE_SIZE_FRACTION + TOP_FACE_SIZE_PX / face.side_px):
        return None
    T = face.T_camera_block.copy()
    T[:3, :3] = pose.canonical_rotation(T[:3, :3], seen)
    return pose.PoseEstimate(T, face.residual_px, 'on_table'), face


def pose_on_plane(detection, camera, side, height, plane, edge_radius=0.0):
    """The pose (``PoseEstimate``, camera frame) of ``detection`` as a ``side`` x ``height`` (m) block standing on
    ``plane`` (camera frame): by its top face (``top_face_on_plane``) where that fits, else by its silhouette
    (``_silhouette_observation``: the blob's outline with the side faces it shows) where that does; else None."""
    on_top = top_face_on_plane(detection, camera, side, height, plane, edge_radius)
    if on_top is not None:
        return on_top[0]
    observation = _silhouette_observation(detection, detection.shape, camera, side, height, plane, edge_radius)
    return None if observation is None else observation.pose


def _cube_seen_from_a_corner(detection, camera, side, height, table_plane, edge_radius):
    """The observation of a square block of ``side`` and ``height`` (m) on the table that the hexagon ``detection``
    may be, or None: a cube seen from a corner with its top and two side faces lit alike, vision's one blob and
    polygon. Cast onto the table (``on_table.fit_top_face``) a hexagonal block's top face is a regular hexagon (the
    independent renderer's from 30 px: RMS residual up to 0.14 of the side), a cube's top and side faces are not
    (dice: 0.11-0.55); from ``CORNER_VIEW_MIN_IRREGULARITY`` on, its silhouette on the table is fitted with the
    cube's (``_silhouette_observation``)."""
    hexagon = on_table.fit_top_face(detection.vertices_px, camera, models.model_for('hexagon', side, height),
                                    table_plane)
    if hexagon is None or hexagon.residual_px < CORNER_VIEW_MIN_IRREGULARITY * hexagon.side_px:
        return None
    return _silhouette_observation(detection, 'square', camera, side, height, table_plane, edge_radius)


def _silhouette_observation(detection, shape, camera, side, height, table_plane, edge_radius):
    """``detection`` posed as a ``shape`` block from its blob's silhouette on the table (method ``'silhouette'``:
    ``residual_px`` the mean gap between the fitted prism's outline and the blob's, no covariance; its vertices and
    shape the seen top face's) when the fit overlaps the blob by ``silhouette_min_overlap``; else None."""
    outline = detection.blob_contour if detection.blob_contour is not None else detection.contour
    fit = silhouette.fit_on_table(outline, camera, models.model_for(shape, side, height), table_plane)
    if fit is None or fit.overlap < silhouette_min_overlap(outline):
        return None
    seen = models.seen_model(shape, side, height, edge_radius)
    T = fit.T_camera_block.copy()
    T[:3, :3] = pose.canonical_rotation(T[:3, :3], seen)
    vertices = camera.project(seen.vertices @ fit.T_camera_block[:3, :3].T + fit.T_camera_block[:3, 3])
    seen_detection = dataclasses.replace(detection, shape=shape, vertices_px=vertices,
                                         centroid_px=vertices.mean(axis=0))
    return BlockObservation(seen_detection, pose.PoseEstimate(T, fit.gap_px, 'silhouette'))


def silhouette_min_overlap(outline):
    """The intersection over union a silhouette fit must reach on the blob ``outline`` ((M, 1, 2) px) to be taken:
    ``SILHOUETTE_MIN_OVERLAP``, or, on a blob small enough, that of an outline ``SILHOUETTE_SLACK_PX`` off the
    blob's all round (1 - slack x perimeter / area, to first order): a pixel of blur, mask or fit error all round a
    16 px die is 0.25 of it, 0.1 of a 40 px block's (docs/perception.md, "A small blob's silhouette overlap")."""
    area = cv2.contourArea(outline)
    if area <= 0.0:
        return SILHOUETTE_MIN_OVERLAP
    return min(SILHOUETTE_MIN_OVERLAP, 1.0 - SILHOUETTE_SLACK_PX * cv2.arcLength(outline, True) / area)


def _height_error_m(estimate, table_plane, height):
    """How far (m) ``estimate`` puts the top face above ``height`` over ``table_plane`` (along the plane's normal;
    negative: below)."""
    return float(table_plane.normal @ estimate.T_camera_object[:3, 3]) - (table_plane.offset + height)


def _sits_on(estimate, table_plane, height):
    """True when ``estimate`` puts the top face ``height`` above ``table_plane`` within three of its standard
    deviations along the plane's normal (false without a covariance)."""
    if estimate.covariance is None:
        return False
    normal = table_plane.normal
    error = normal @ estimate.T_camera_object[:3, 3] - (table_plane.offset + height)
    return abs(error) <= 3.0 * float(np.sqrt(normal @ estimate.covariance[:3, :3] @ normal))


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
    """Copy of the image with each block's contour, vertices, pose axes (m) and depth drawn on it (marked when the
    pose came from the table: the block's top face or its silhouette on it)."""
    canvas = vision.draw_detections(image_bgr, [o.detection for o in observations])
    for observation in observations:
        estimate = observation.pose
        if estimate is None:
            continue
        rvec, _ = cv2.Rodrigues(estimate.T_camera_object[:3, :3])
        tvec = estimate.T_camera_object[:3, 3].reshape(3, 1)
        cv2.drawFrameAxes(canvas, camera.K, camera.D, rvec, tvec, axis_length, 2)
        u, v = (int(round(c)) for c in observation.detection.centroid_px)
        label = 'Z=%.1f mm%s' % (1000.0 * estimate.depth_m, ' (%s)' % estimate.method.replace('_', ' ')
                                 if estimate.method in ON_THE_TABLE_METHODS else '')
        cv2.putText(canvas, label, (u + 8, v + 22),
                    cv2.FONT_HERSHEY_SIMPLEX, 0.5, (0, 0, 255), 1, cv2.LINE_AA)
    return canvas
