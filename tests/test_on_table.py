"""A block's pose from its top-face polygon on a known table (``on_table.fit_top_face``) and its use in
``perception.observe_blocks``: polygons projected exactly (any winding and first vertex), shrunk as a rounded or
blurred face's are, a block of another size, bad input."""
import dataclasses
import math

import numpy as np
import pytest

from baxter_pnp import models, on_table, perception, pose, vision
from baxter_pnp.camera import load_default_camera
from test_silhouette import TABLE, block_on, outline_of

CAMERA = load_default_camera()


def top_face_px(T, model, scale=1.0):
    """Distorted pixels of ``model``'s top face at ``T``, ``scale`` times its size about its centre."""
    return CAMERA.project(scale * model.vertices @ T[:3, :3].T + T[:3, 3])


@pytest.mark.parametrize('shape', ['triangle', 'square', 'hexagon'])
@pytest.mark.parametrize('u, v, yaw', [(0.0, 0.0, 0.3), (0.08, -0.05, 1.1), (-0.1, 0.06, 0.7)])
def test_a_blocks_pose_comes_back_from_its_top_face(shape, u, v, yaw):
    """Exact vertices, in either winding from any vertex: the pose to 1e-6 m and 1e-4 rad (modulo the shape's
    symmetry), scale 1, no residual; the side in px is the polygon's."""
    model = models.model_for(shape, 0.03, 0.02)
    T = block_on(TABLE, model, u, v, yaw)
    vertices = top_face_px(T, model)
    for polygon in (vertices, vertices[::-1], np.roll(vertices, 2, axis=0)):
        fit = on_table.fit_top_face(polygon, CAMERA, model, TABLE)
        assert np.linalg.norm(fit.T_camera_block[:3, 3] - T[:3, 3]) < 1e-6
        assert np.allclose(fit.T_camera_block[:3, 2], TABLE.normal)
        turn = math.atan2(*(fit.T_camera_block[:3, :3].T @ T[:3, 0])[1::-1])
        half = model.symmetry_angle / 2
        assert abs((turn + half) % model.symmetry_angle - half) < 1e-4
        assert fit.scale == pytest.approx(1.0, abs=1e-6) and fit.residual_px < 1e-4
        assert fit.side_px == pytest.approx(np.mean(np.linalg.norm(polygon - np.roll(polygon, 1, axis=0), axis=1)))


def test_a_face_seen_smaller_keeps_its_position():
    """A face whose edges were found inside it all round (a rounded rim, blur: 0.8 of its size) is still centred
    where it is: the size is the scale's, the position the polygon's centre's (within 0.1 mm at 0.35 m, 25 deg)."""
    model = models.model_for('square', 0.02, 0.02)
    T = block_on(TABLE, model, 0.05, 0.03, 0.5)
    fit = on_table.fit_top_face(top_face_px(T, model, 0.8), CAMERA, model, TABLE)
    assert fit.scale == pytest.approx(0.8, abs=0.01) and fit.residual_px < 0.05
    assert np.linalg.norm(fit.T_camera_block[:3, 3] - T[:3, 3]) < 1e-4


def test_a_polygon_of_another_shape_leaves_a_residual():
    """A 30 mm square's polygon fitted as a pentagon's top face (its vertex count forced): residual over 2 px."""
    square = models.model_for('square', 0.03, 0.02)
    pentagon = models.model_for('pentagon', 0.03, 0.02)
    T = block_on(TABLE, square, 0.0, 0.02, 0.2)
    corners = top_face_px(T, square)
    polygon = np.vstack([corners[:1], 0.5 * (corners[0] + corners[1]), corners[1:]])   # a fifth vertex on an edge
    assert on_table.fit_top_face(polygon, CAMERA, pentagon, TABLE).residual_px > 2.0


def test_bad_input_is_refused():
    model = models.model_for('square', 0.02, 0.02)
    with pytest.raises(ValueError, match='needs 4 vertices'):
        on_table.fit_top_face(np.zeros((3, 2)), CAMERA, model, TABLE)
    behind = models.Plane(np.array([0.0, 0.0, 1.0]), 0.35)        # the camera on its underside
    with pytest.raises(ValueError, match='side the table plane'):
        on_table.fit_top_face([[300, 200], [320, 200], [320, 220], [300, 220]], CAMERA, model, behind)
    ceiling = models.Plane(np.array([0.0, 1.0, 0.0]), -0.35)      # 0.35 m above the optical axis, facing down
    assert on_table.fit_top_face([[300, 450], [320, 450], [320, 470], [300, 470]], CAMERA, model, ceiling) is None
    assert on_table.fit_top_face([[300, 200]] * 4, CAMERA, model, TABLE) is None
    assert on_table.fit_top_face([[300, 200], [np.nan, 200], [320, 220], [300, 220]], CAMERA, model, TABLE) is None


def _observation(vertices, estimate=None):
    detection = vision.Detection('square', 'green', vertices, vertices.mean(axis=0), 400.0, 1.0, False,
                                 np.round(vertices).astype(np.int32).reshape(-1, 1, 2))
    return perception.BlockObservation(detection, estimate)


@pytest.mark.parametrize('scale, posed', [(0.85, True), (1.12, True), (0.6, False), (1.3, False)])
def test_observe_blocks_takes_a_small_faces_pose_from_the_table_when_it_is_the_blocks_size(scale, posed):
    """A 20 mm die at 0.35 m (about 20 px) whose polygon came out ``scale`` times its size: its pose from the polygon
    (depth off by the inverse of the scale) gives way to its top face on the table when the size is the model's within
    10 % plus 3 px (method ``'on_table'``, within 0.1 mm of the truth); a face 0.6 or 1.3 times the size (a block of
    another size) keeps the polygon's pose."""
    model = models.model_for('square', 0.02, 0.02)
    T = block_on(TABLE, model, 0.02, -0.01, 0.4)
    vertices = top_face_px(T, model, scale)
    estimate = pose.estimate_pose(vertices, CAMERA, model, table_plane=TABLE)
    observation = perception._on_the_table(_observation(vertices, estimate), CAMERA, 0.02, 0.02, TABLE, 0.0)
    assert (observation.pose.method == 'on_table') == posed
    if posed:
        assert np.linalg.norm(observation.pose.T_camera_object[:3, 3] - T[:3, 3]) < 1e-4
        assert observation.pose.covariance is None and observation.pose.residual_px < 0.05
    else:
        assert observation.pose is estimate


@pytest.mark.parametrize('scale, posed', [(1.03, False), (1.09, True), (0.92, True)])
def test_a_larger_faces_pose_off_the_table_gives_way_to_its_top_face_on_the_table(scale, posed):
    """A 40 mm square at 0.35 m (about 75 px) whose polygon came out ``scale`` times its size: a polygon pose that
    keeps within ``TABLE_MISS_M`` of the table's height (3 %: about 10 mm) stays; one further off (8-9 %: 27-32 mm, a
    side face or a rim in the polygon) gives way to the top face on the table (within 0.1 mm), unless blocks may
    stand on others and it is above the table."""
    model = models.model_for('square', 0.04, 0.02)
    T = block_on(TABLE, model, 0.03, 0.02, 0.9)
    vertices = top_face_px(T, model, scale)
    estimate = pose.estimate_pose(vertices, CAMERA, model, table_plane=TABLE)
    miss = perception._height_error_m(estimate, TABLE, 0.02)
    assert (abs(miss) > perception.TABLE_MISS_M) == posed
    observation = perception._on_the_table(_observation(vertices, estimate), CAMERA, 0.04, 0.02, TABLE, 0.0)
    if posed:
        assert observation.pose.method == 'on_table'
        assert np.linalg.norm(observation.pose.T_camera_object[:3, 3] - T[:3, 3]) < 1e-4
    else:
        assert observation.pose is estimate
    # where blocks may stand on others (a tower), a pose above the table is believed, one below it is not
    tower = perception._on_the_table(_observation(vertices, estimate), CAMERA, 0.04, 0.02, TABLE, 0.0, towers=True)
    assert (tower.pose is estimate) == (not posed or miss > 0)


def _hexagon_detection(outline):
    return vision.Detection('hexagon', 'green', outline, outline.mean(axis=0), 400.0, 1.0, False,
                            np.round(outline).astype(np.int32).reshape(-1, 1, 2))


def test_a_cube_seen_from_a_corner_as_one_hexagon_is_posed_as_the_square_asked_for():
    """A 20 mm cube with its top and two side faces in one blob (vision's hexagon) is posed as the cube asked for, from
    its silhouette on the table (within 0.5 mm, shape ``square``); a hexagonal block whose silhouette a cube would fit
    as well (sides 0.6 of the cube's: overlap over 0.85) is not, its hexagon being regular on the table."""
    cube = models.model_for('square', 0.02, 0.02)
    T = block_on(TABLE, cube, 0.0, 0.0, 0.3)       # (0.08, -0.05, 1.1): irregularity 0.144, taken for a hexagon
    outline = outline_of(T, cube)
    assert len(outline) == 6
    observation = perception._cube_seen_from_a_corner(_hexagon_detection(outline), CAMERA, 0.02, 0.02, TABLE, 0.0)
    assert observation.detection.shape == 'square' and observation.pose.method == 'silhouette'
    assert np.linalg.norm(observation.pose.T_camera_object[:3, 3] - T[:3, 3]) < 5e-4
    hexagonal = models.model_for('hexagon', 0.012, 0.02)
    T_hexagonal = block_on(TABLE, hexagonal, 0.0, 0.0, 0.3)
    hexagon = top_face_px(T_hexagonal, hexagonal)
    detection = dataclasses.replace(_hexagon_detection(hexagon),
                                    blob_contour=outline_of(T_hexagonal, hexagonal).astype(np.int32).reshape(-1, 1, 2))
    assert perception._silhouette_observation(detection, 'square', CAMERA, 0.02, 0.02, TABLE, 0.0) is not None
    assert perception._cube_seen_from_a_corner(detection, CAMERA, 0.02, 0.02, TABLE, 0.0) is None
