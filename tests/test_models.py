"""Object models (regular polygonal prisms in the block frame) and the Plane helper."""
import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from baxter_pnp.models import EDGE_INSET_FRACTION, SHAPES, Plane, PolygonModel, model_for, seen_model
from baxter_pnp.transforms import invert, make_transform


@pytest.mark.parametrize('shape', sorted(SHAPES))
def test_polygon_vertices_follow_the_block_frame_convention(shape):
    side = 0.037
    model = model_for(shape, side, height=0.015)
    n = SHAPES[shape]
    vertices = model.vertices
    assert (model.n, vertices.shape, model.height) == (n, (n, 3), 0.015)
    np.testing.assert_allclose(vertices[:, 2], 0.0)
    np.testing.assert_allclose(vertices.mean(axis=0), 0.0, atol=1e-15)          # origin at the face centre
    np.testing.assert_allclose(np.linalg.norm(vertices, axis=1), side / (2 * math.sin(math.pi / n)))
    assert model.circumradius == pytest.approx(side / (2 * math.sin(math.pi / n)))
    edges = np.roll(vertices, -1, axis=0) - vertices
    np.testing.assert_allclose(np.linalg.norm(edges, axis=1), side)                 # regular, side s
    angles = np.arctan2(vertices[:, 1], vertices[:, 0])
    np.testing.assert_allclose(np.unwrap(angles), math.pi / n + 2 * math.pi * np.arange(n) / n)   # CCW about +z
    assert abs(edges[-1] @ [0.0, 1.0, 0.0]) == pytest.approx(side)   # edge n-1 -> 0 is perpendicular to +x
    assert model.symmetry_angle == pytest.approx(2 * math.pi / n)
    turned = vertices @ Rotation.from_euler('z', model.symmetry_angle).as_matrix().T
    np.testing.assert_allclose(turned, np.roll(vertices, -1, axis=0), atol=1e-15)  # symmetry maps k -> k + 1


def test_square_edges_are_parallel_to_the_axes():
    vertices = model_for('square', 0.04).vertices
    np.testing.assert_allclose(vertices[:, :2], [[0.02, 0.02], [-0.02, 0.02], [-0.02, -0.02], [0.02, -0.02]])


def test_vertices_are_read_only_and_models_compare_by_value():
    model = model_for('hexagon', 0.03)
    with pytest.raises(ValueError):
        model.vertices[0, 0] = 1.0
    assert model == PolygonModel('hexagon', 0.03, 0.02)


@pytest.mark.parametrize('args', [('octagon', 0.04), ('square', 0.0), ('square', -0.01), ('square', float('nan')),
                                  ('square', 0.04, -0.01)])
def test_invalid_models_raise(args):
    with pytest.raises(ValueError):
        model_for(*args)


def test_plane_normalises_and_measures_signed_distance():
    plane = Plane([0.0, 0.0, 2.0], -0.15)          # the table top in base, normal up
    np.testing.assert_allclose(plane.normal, [0.0, 0.0, 1.0])
    assert plane.signed_distance([0.3, 0.1, -0.13]) == pytest.approx(0.02)
    np.testing.assert_allclose(plane.signed_distance([[0, 0, -0.15], [0, 0, -0.2]]), [0.0, -0.05])
    for bad in ([0.0, 0.0, 0.0], [np.nan, 0.0, 1.0]):
        with pytest.raises(ValueError):
            Plane(bad, 0.0)


def test_plane_transformed_keeps_points_on_the_plane():
    rng = np.random.default_rng(3)
    plane_base = Plane([0.1, -0.2, 1.0], -0.15)
    T_camera_base = make_transform(Rotation.from_rotvec(rng.normal(size=3)), rng.normal(size=3))
    plane_camera = plane_base.transformed(T_camera_base)
    # points on / above the plane in base keep their signed distance when expressed in the camera frame
    points_base = rng.normal(size=(20, 3))
    points_camera = points_base @ T_camera_base[:3, :3].T + T_camera_base[:3, 3]
    np.testing.assert_allclose(plane_camera.signed_distance(points_camera), plane_base.signed_distance(points_base),
                               atol=1e-12)
    np.testing.assert_allclose(plane_camera.normal, T_camera_base[:3, :3] @ plane_base.normal)
    back = plane_camera.transformed(invert(T_camera_base))
    np.testing.assert_allclose(back.normal, plane_base.normal, atol=1e-12)
    assert back.offset == pytest.approx(plane_base.offset)


@pytest.mark.parametrize('shape', sorted(SHAPES))
def test_a_rounded_top_rim_is_seen_as_a_top_face_inset_by_a_fraction_of_its_radius(shape):
    """Each edge EDGE_INSET_FRACTION x r inside the sharp one: the side shrinks by 2 f r tan(pi / n), the centre and
    height stay; a sharp block is its own model."""
    sharp, seen = model_for(shape, 0.04, 0.02), seen_model(shape, 0.04, 0.02, 0.002)
    apothem = sharp.circumradius * math.cos(math.pi / sharp.n)
    assert seen.circumradius * math.cos(math.pi / seen.n) == pytest.approx(apothem - EDGE_INSET_FRACTION * 0.002)
    assert (seen.shape, seen.height) == (shape, 0.02) and seen_model(shape, 0.04, 0.02) is sharp
    np.testing.assert_allclose(seen.vertices.mean(axis=0), 0.0, atol=1e-12)


@pytest.mark.parametrize('edge_radius', [-0.001, float('nan'), float('inf'), 0.011, 0.02])
def test_a_bad_edge_radius_raises(edge_radius):
    """Negative, not finite, or as large as the triangle's apothem (0.0115 m at 0.04 m) or the block's height."""
    with pytest.raises(ValueError, match='edge_radius'):
        seen_model('triangle', 0.04, 0.011, edge_radius)
