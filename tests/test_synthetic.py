"""Synthetic renderer: geometric exactness, shading, visibility, determinism, chessboards, random poses."""
import cv2
import numpy as np
import pytest
from scipy.spatial import cKDTree
from scipy.spatial.transform import Rotation

from baxter_pnp import synthetic
from baxter_pnp.camera import load_default_camera
from baxter_pnp.synthetic import BlockSpec, random_block_pose, render_block_scene, render_chessboard
from baxter_pnp.transforms import make_transform, transform_points

NO_EFFECTS = dict(lighting_gradient=0.0, noise_sigma=0.0, blur_sigma=0.0, jpeg_quality=None)
GREEN = (40, 170, 40)


@pytest.fixture(scope='module')
def camera():
    return load_default_camera()


def facing_camera(position, yaw=0.0, tilt=(0.0, 0.0, 0.0)):
    """T_camera_block with the top face towards the camera (rotated by rotvec ``tilt``), yawed by ``yaw``."""
    rotation = Rotation.from_rotvec(tilt) * Rotation.from_rotvec([np.pi, 0, 0]) * Rotation.from_rotvec([0, 0, yaw])
    return make_transform(rotation, position)


def green_excess(image):
    """G - R per pixel (float): ~5 on the table, large on green faces."""
    return image[..., 1].astype(float) - image[..., 2].astype(float)


def region_centroid_px(camera, T_camera_block, spec, samples_per_edge=200):
    """Area centroid (px) of the distorted image of the top face (dense outline, shoelace formula)."""
    vertices = spec.top_vertices()
    t = np.linspace(0.0, 1.0, samples_per_edge, endpoint=False)[:, None]
    outline = np.vstack([a + (b - a) * t for a, b in zip(vertices, np.roll(vertices, -1, axis=0))])
    p = camera.project(transform_points(T_camera_block, outline))
    x, y, x1, y1 = p[:, 0], p[:, 1], np.roll(p[:, 0], -1), np.roll(p[:, 1], -1)
    cross = x * y1 - x1 * y
    return np.array([((x + x1) * cross).sum(), ((y + y1) * cross).sum()]) / (3.0 * cross.sum())


POSITIONS = [(0.0, 0.0, 0.3), (0.05, -0.03, 0.25), (-0.12, 0.08, 0.3), (0.15, 0.1, 0.3), (0.2, -0.14, 0.3)]


@pytest.mark.parametrize('position', POSITIONS)
def test_top_face_centroid_from_a_colour_mask(camera, position):
    # a fronto-parallel green tile (negligible height: no side faces) with every image effect on
    spec = BlockSpec('square', 0.04, height=1e-4, colour_bgr=GREEN)
    T = facing_camera(position, yaw=0.4)
    image, truths = render_block_scene(camera, [(spec, T)], np.random.default_rng(3))
    excess = green_excess(image)
    mask = (excess > (5.0 + np.percentile(excess, 99.9)) / 2).astype(np.uint8)   # half-way table -> face
    m = cv2.moments(mask, binaryImage=True)
    centroid = np.array([m['m10'], m['m01']]) / m['m00']
    assert truths[0]['visible']
    assert np.linalg.norm(centroid - truths[0]['centroid_px']) < 0.5
    assert m['m00'] == pytest.approx(cv2.contourArea(truths[0]['vertices_px'].astype(np.float32)), rel=0.03)


@pytest.mark.parametrize('position', POSITIONS)
def test_rendering_is_geometrically_exact(camera, position):
    # without image effects, the coverage-weighted centroid and area of the rendered top face match
    # the exact distorted image of the face (the lens bends straight edges; its centroid is not the
    # projected centre near the corners, hence the dense outline)
    spec = BlockSpec('square', 0.04, height=1e-4, colour_bgr=GREEN)
    T = facing_camera(position, yaw=0.3)
    image, truths = render_block_scene(camera, [(spec, T)], np.random.default_rng(0), **NO_EFFECTS)
    light = synthetic._light_in_camera(T, synthetic.ImageEffects().light_dir_camera)
    top_excess = (GREEN[1] - GREEN[2]) * synthetic._brightness(T[:3, 2], light)
    coverage = np.clip((green_excess(image) - 5.0) / (top_excess - 5.0), 0.0, 1.0).astype(np.float32)
    m = cv2.moments(coverage)
    centroid = np.array([m['m10'], m['m01']]) / m['m00']
    assert np.linalg.norm(centroid - region_centroid_px(camera, T, spec)) < 0.06
    assert m['m00'] == pytest.approx(cv2.contourArea(truths[0]['vertices_px'].astype(np.float32)), rel=0.01)
    np.testing.assert_allclose(truths[0]['vertices_px'], camera.project(transform_points(T, spec.top_vertices())))


def test_side_faces_same_hue_darker_than_top(camera):
    spec = BlockSpec('square', 0.05, height=0.03, colour_bgr=GREEN)
    T = facing_camera((0.0, 0.0, 0.3), yaw=0.2, tilt=(0.6, 0.0, 0.0))
    image, _ = render_block_scene(camera, [(spec, T)], np.random.default_rng(1), **NO_EFFECTS)
    hsv = cv2.cvtColor(image, cv2.COLOR_BGR2HSV)
    faces = spec.faces()
    top_px = camera.project(transform_points(T, faces[0][0]))
    visible_sides = [transform_points(T, v) for v, n in faces[2:]
                     if (T[:3, :3] @ n) @ transform_points(T, v)[0] < 0]
    assert visible_sides, 'the tilt should show a side face'

    def interior(points_px):
        mask = np.zeros(image.shape[:2], np.uint8)
        cv2.fillPoly(mask, [np.round(points_px).astype(np.int32)], 1)
        return cv2.erode(mask, np.ones((5, 5), np.uint8)).astype(bool)

    top, side = interior(top_px), interior(camera.project(visible_sides[0]))
    assert top.sum() > 500 and side.sum() > 100
    top_hsv, side_hsv = np.median(hsv[top], axis=0), np.median(hsv[side], axis=0)
    assert abs(float(top_hsv[0]) - float(side_hsv[0])) <= 3          # hue (OpenCV: 0..180)
    assert side_hsv[2] < 0.8 * top_hsv[2]                            # value: darker


def test_visibility_occlusion_and_border(camera):
    near = (BlockSpec('square', 0.04), facing_camera((0.0, 0.0, 0.2)))
    far = (BlockSpec('hexagon', 0.03), facing_camera((0.005, 0.0, 0.35)))
    clear = (BlockSpec('triangle', 0.03), facing_camera((-0.12, 0.05, 0.3)))
    cut = (BlockSpec('pentagon', 0.04), facing_camera((0.27, 0.0, 0.3)))
    _, truths = render_block_scene(camera, [far, near, clear, cut], np.random.default_rng(0))
    assert [t['visible'] for t in truths] == [False, True, True, False]
    assert truths[3]['vertices_px'][:, 0].max() > camera.width - 1


def test_determinism_with_a_seeded_rng(camera):
    blocks = [(BlockSpec('pentagon', 0.04), facing_camera((0.02, 0.01, 0.3), yaw=0.5, tilt=(0.3, 0.2, 0)))]
    first, _ = render_block_scene(camera, blocks, np.random.default_rng(42))
    second, _ = render_block_scene(camera, blocks, np.random.default_rng(42))
    other, _ = render_block_scene(camera, blocks, np.random.default_rng(43))
    assert first.shape == (480, 640, 3) and first.dtype == np.uint8
    np.testing.assert_array_equal(first, second)
    assert np.abs(first.astype(int) - other.astype(int)).mean() > 0.5


def test_table_plane_horizon(camera):
    # a table seen at a grazing angle: the upper part of the image lies beyond its horizon (darker)
    T_camera_table = make_transform(Rotation.from_rotvec([np.pi - 1.35, 0, 0]), (0, 0, 0.3))
    image, _ = render_block_scene(camera, [], np.random.default_rng(0), T_camera_table=T_camera_table, **NO_EFFECTS)
    assert image[5].mean() < 0.6 * image[-5].mean()
    flat, _ = render_block_scene(camera, [], np.random.default_rng(0), **NO_EFFECTS)
    assert np.all(flat == flat[0, 0])


@pytest.mark.parametrize('T_camera_board', [
    make_transform(Rotation.from_euler('xyz', [np.pi, 0.0, 0.0]), (-0.12, 0.07, 0.40)),
    make_transform(Rotation.from_euler('xyz', [np.pi + 0.35, -0.3, 0.2]), (-0.10, 0.03, 0.45)),
])
def test_chessboard_corners_match_opencv(camera, T_camera_board):
    image, corners_px = render_chessboard(camera, T_camera_board, np.random.default_rng(5), supersample=3)
    gray = cv2.cvtColor(image, cv2.COLOR_BGR2GRAY)
    found, corners = cv2.findChessboardCorners(gray, (9, 6))
    assert found
    criteria = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 50, 1e-3)
    corners = cv2.cornerSubPix(gray, corners, (5, 5), (-1, -1), criteria).reshape(-1, 2)
    distance, index = cKDTree(corners_px).query(corners)
    assert len(set(index)) == 54
    assert distance.max() < 0.3


def test_random_block_pose_keeps_the_block_in_view(camera):
    rng = np.random.default_rng(11)
    spec = BlockSpec('hexagon', 0.04)
    for _ in range(30):
        T = random_block_pose(rng, distance_range=(0.15, 0.35), max_tilt_deg=35, camera=camera,
                              margin_px=10, block=spec)
        assert 0.15 <= np.linalg.norm(T[:3, 3]) <= 0.35
        tilt = np.degrees(np.arccos(np.clip(-T[2, 2], -1, 1)))     # block +z vs camera -z
        assert tilt <= 35.0 + 1e-9
        pixels = camera.project(transform_points(T, spec.corners()))
        assert np.all(pixels >= 10) and np.all(pixels <= [camera.width - 11, camera.height - 11])
    with pytest.raises(ValueError, match='no pose'):
        random_block_pose(rng, distance_range=(0.02, 0.03), camera=camera, block=spec, max_tries=20)
