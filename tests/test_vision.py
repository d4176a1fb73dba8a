"""vision: the thesis stages one by one, shape classification, top-face isolation and sub-pixel
vertex accuracy on rendered images (synthetic.render_block_scene), bad inputs, target selection."""
import dataclasses
import re

import cv2
import numpy as np
import pytest
import yaml
from scipy.spatial.transform import Rotation

from baxter_pnp import synthetic, vision
from baxter_pnp.camera import load_default_camera
from baxter_pnp.transforms import make_transform

GREEN = (40, 170, 40)
# the benchmark's colours
COLOURS_BGR = {'green': GREEN, 'red': (40, 40, 200), 'blue': (200, 90, 30), 'yellow': (30, 200, 220)}


@pytest.fixture(scope='module')
def camera():
    return load_default_camera()


@pytest.fixture(scope='module')
def config():
    return vision.VisionConfig.from_yaml()


def block_pose(camera, pixel, distance, tilt_deg=0.0, tilt_azimuth_deg=0.0, yaw_deg=0.0):
    """T_camera_block: top-face centre at ``distance`` (m) along the ray of ``pixel``, tilted from facing the camera."""
    ray = np.append(camera.undistort_points(np.array([pixel], dtype=float))[0], 1.0)
    azimuth = np.radians(tilt_azimuth_deg)
    tilt = Rotation.from_rotvec(np.radians(tilt_deg) * np.array([np.cos(azimuth), np.sin(azimuth), 0.0]))
    rotation = tilt * Rotation.from_rotvec([np.pi, 0.0, 0.0]) * Rotation.from_rotvec([0.0, 0.0, np.radians(yaw_deg)])
    return make_transform(rotation, ray / np.linalg.norm(ray) * distance)


def vertex_errors(detected, truth):
    """Per-vertex distances (px) under the best cyclic correspondence (either direction)."""
    n = len(truth)
    assert len(detected) == n, f'{len(detected)} vertices detected, {n} expected'
    candidates = []
    for shift in range(n):
        for sign in (1, -1):
            candidates.append(np.linalg.norm(detected[[(sign * k + shift) % n for k in range(n)]] - truth, axis=1))
    return min(candidates, key=lambda e: e.max())


# ----------------------------------------------------------------------------------------- config
def test_default_config_is_the_thesis_pipeline(config):
    assert config.gamma == 0.6 and config.saturation_epsilon == 2.25 and config.lowpass_b == 2.0
    assert (config.oversaturated_s, config.oversaturated_v) == (250, 180)
    assert config.colours['green'] == (((50, 100, 100), (70, 255, 255)),)
    assert len(config.colours['red']) == 2                         # hue wraps around 0
    assert {'green', 'red', 'blue', 'yellow'} <= set(config.colour_names())


@pytest.mark.parametrize('change, message', [
    ({'gamma_typo': 0.6}, 'gamma_typo: unknown key'),
    ({'gamma': 'high'}, 'gamma: must be a number'),
    ({'gamma': 0}, 'gamma: must be > 0'),
    ({'colours': {'green': [[[50, 100], [70, 255, 255]]]}}, 'colours.green: each bound needs 3 values'),
    ({'colours': {'red': [[[10, 100, 100], [5, 255, 255]]]}}, 'colours.red: range'),
    ({'subpixel': {'enabled': 'yes'}}, 'subpixel.enabled: must be true or false'),
    ({'subpixel': {'passes': 1.5}}, r'subpixel.passes: must be an integer \(got 1.5\)'),
    ({'subpixel': {'passes': 0}}, r'subpixel.passes: must be >= 1'),
    ({'border_edge_max_rms_px': 0}, 'border_edge_max_rms_px: must be > 0'),
    ({'min_triangle_area_px': 0}, 'min_triangle_area_px: must be > 0'),
    ({'min_triangle_quality': 1.5}, r'min_triangle_quality: must be in \[0, 1\]'),
    ({'roi': {'downsample': 0}}, 'roi.downsample: must be >= 1'),
    ({'side_face_cut': {'max_depth_fraction': 0.6}}, r'side_face_cut.max_depth_fraction: must be in \(0, 0.5\)'),
    ({'side_face_cut': {'min_agreement': 0}}, r'side_face_cut.min_agreement: must be in \(0, 1\]'),
])
def test_config_errors_name_the_bad_key(tmp_path, change, message):
    path = tmp_path / 'vision.yaml'
    path.write_text(yaml.safe_dump(change))
    with pytest.raises(ValueError, match=f'^{re.escape(str(path))}: {message}'):
        vision.VisionConfig.from_yaml(str(path))


# ----------------------------------------------------------------------------------------- stages
def test_gamma_lut_values():
    lut = vision.gamma_lut(0.6)
    assert lut.dtype == np.uint8 and lut.shape == (256,)
    assert lut[0] == 0 and lut[255] == 255
    assert lut[64] == round(255 * (64 / 255) ** 0.6) == 111
    assert np.all(np.diff(lut.astype(int)) >= 0) and np.all(lut[1:250] > np.arange(1, 250))   # brightens


def test_dynamic_saturation_threshold_and_oversaturation():
    saturation = np.array([[10, 50, 99], [100, 101, 235]], np.uint8)
    threshold = vision.saturation_threshold(saturation, 2.25)
    assert threshold == pytest.approx((235 - 10) / 2.25) == 100.0
    s_out, v_out = vision.oversaturate(saturation, threshold, 250, 180)
    np.testing.assert_array_equal(s_out, [[0, 0, 0], [250, 250, 250]])       # s >= threshold is kept
    np.testing.assert_array_equal(v_out, [[0, 0, 0], [180, 180, 180]])
    s_out, _ = vision.oversaturate(saturation, 100.5, 250, 180)
    np.testing.assert_array_equal(s_out, [[0, 0, 0], [0, 250, 250]])


def test_lowpass_kernel_of_eq_3_17():
    kernel = vision.lowpass_kernel(2.0)
    np.testing.assert_allclose(kernel, np.outer([1, 2, 1], [1, 2, 1]) / 16.0)
    assert kernel.sum() == pytest.approx(1.0)
    assert vision.lowpass_kernel(5.0).sum() == pytest.approx(1.0)
    impulse = np.zeros((7, 7), np.float32)
    impulse[3, 3] = 1.0
    np.testing.assert_allclose(vision.lowpass(impulse, 2.0)[2:5, 2:5], kernel, atol=1e-7)


def test_colour_masks_of_named_colours(config):
    hues = {'green': 60, 'red': 2, 'blue': 115, 'yellow': 28}
    for name, hue in hues.items():
        hsv = np.array([[[hue, 250, 180], [hue, 250, 60], [(hue + 90) % 180, 250, 180]]], np.uint8)
        mask = vision.colour_mask(hsv, config.colours[name])
        np.testing.assert_array_equal(mask[0], [255, 0, 0], err_msg=name)   # bright in range / too dark / wrong hue
    hsv = np.array([[[178, 250, 180], [5, 250, 180], [90, 250, 180]]], np.uint8)
    red = vision.colour_mask(hsv, config.colours['red'])
    np.testing.assert_array_equal(red[0], [255, 255, 0])                     # both sides of the wrap-around


def test_laplacian_and_morphology_stages():
    mask = np.zeros((20, 20), np.uint8)
    mask[5:15, 5:15] = 255
    mask[2, 2] = 255                                                         # a speck
    mask[9, 9] = 0                                                           # a hole
    cleaned = vision.open_close(mask, 3)
    assert cleaned[2, 2] == 0 and cleaned[9, 9] == 255
    ring = vision.laplacian_sharpen(cleaned)
    assert ring[5, 9] == 255 and ring[9, 9] == 0 and ring[4, 9] == 0      # inner boundary only
    blobs = vision.find_blobs(ring, 50)
    assert len(blobs) == 1 and cv2.contourArea(blobs[0]) == pytest.approx(81)


def test_merge_close_vertices():
    square = np.array([[0, 0], [100, 0], [101, 1], [100, 100], [0, 100]], float)
    merged = vision.merge_close_vertices(square, 5.0)
    np.testing.assert_allclose(merged, [[0, 0], [100.5, 0.5], [100, 100], [0, 100]])
    wrapped = vision.merge_close_vertices(np.array([[1, 1], [100, 0], [100, 100], [0, 0]], float), 5.0)
    assert len(wrapped) == 3                                                 # first and last are neighbours
    assert len(vision.merge_close_vertices(square, 0.5)) == 5


def test_cut_corners_are_restored_and_true_corners_kept():
    square = np.array([[0, 0], [100, 0], [100, 100], [6, 100], [0, 94]], float)          # one corner cut
    np.testing.assert_allclose(vision.remove_cut_corners(square, 0.04), [[0, 0], [100, 0], [100, 100], [0, 100]],
                               atol=1e-9)
    on_a_side = np.array([[0, 0], [50, -0.5], [100, 0], [100, 100], [0, 100]], float)    # spurious vertex
    assert len(vision.remove_cut_corners(on_a_side, 0.04)) == 4
    angles = np.arange(6) * np.pi / 3
    hexagon = 50 * np.column_stack([np.cos(angles), 0.6 * np.sin(angles)])                # squashed: a tilted view
    np.testing.assert_array_equal(vision.remove_cut_corners(hexagon, 0.04), hexagon)
    triangle = np.array([[0, 0], [100, 0], [50, 80]], float)
    np.testing.assert_array_equal(vision.remove_cut_corners(triangle, 0.5), triangle)    # never below 3 vertices


def test_a_small_triangles_blunted_corners_are_restored_where_no_hexagon_is_at_stake():
    """An 18 px triangle whose three corners blur cut 3.5 px deep (4.3 % of its area each, over the 4 % allowance): its
    short edges are restored with the clear allowance (20 %); a regular pentagon (45 % a corner) and a squashed
    hexagon (17 %, every edge alike) keep every corner; without a clear allowance nothing changes."""
    corners = np.array([[0, 0], [18, 0], [9, 18 * np.sqrt(3) / 2]])
    blunted = []
    for k in range(3):
        a, b = corners[k], corners[(k + 1) % 3]
        blunted += [a + (b - a) * 3.5 / 18, b - (b - a) * 3.5 / 18]
    blunted = np.array(blunted)
    restored = vision.remove_cut_corners(blunted, 0.04, 0.2)
    assert len(restored) == 3
    assert max(min(np.linalg.norm(corners - v, axis=1)) for v in restored) < 1e-9
    assert len(vision.remove_cut_corners(blunted, 0.04)) == 6
    for n in (5, 6):
        angles = np.arange(n) * 2 * np.pi / n
        polygon = 10 * np.column_stack([np.cos(angles), 0.6 * np.sin(angles)])
        np.testing.assert_array_equal(vision.remove_cut_corners(polygon, 0.04, 0.2), polygon)


def test_a_15_px_triangle_is_looked_at_though_its_blob_is_under_min_area(camera, config):
    """The issue's smallest blocks are about 15 px a side: a 15 px triangle is 97 px^2 and blur blunts its corners,
    so its blob is under ``min_area_px`` (100). Blobs from ``min_triangle_area_px`` that are triangles (of
    ``min_triangle_quality``) are detected: 24 such red triangles of the independent renderer (random looks: blur,
    noise, JPEG) face-on at 0.5 m, all found where ``min_area_px`` alone found 21."""
    from baxter_pnp.bench import render_independent
    whole_blobs_only = vision.VisionConfig.from_dict({**config.as_dict(), 'min_triangle_area_px': config.min_area_px})
    found = {'default': 0, 'min_area_px only': 0}
    for seed in range(24):
        rng = np.random.default_rng(seed)
        side = 15.0 * 0.5 / camera.K[0, 0]
        rotation = Rotation.from_euler('x', np.pi) * Rotation.from_euler('z', rng.uniform(0.0, 2.0 * np.pi))
        T = make_transform(rotation.as_matrix(), [rng.uniform(-0.08, 0.08), rng.uniform(-0.05, 0.05), 0.5])
        image, truths = render_independent.render_scene(
            camera, [(render_independent.Block('triangle', side, 0.02, COLOURS_BGR['red']), T)], rng)
        for name, settings in (('default', config), ('min_area_px only', whole_blobs_only)):
            found[name] += any(d.shape == 'triangle' and d.colour == 'red'
                               and np.linalg.norm(d.centroid_px - truths[0]['centroid_px']) < 4.0
                               for d in vision.detect(image, settings))
    assert found['default'] >= 23, found
    assert found['min_area_px only'] <= 21, found


def test_a_near_pentagon_in_perspective_keeps_its_corners():
    """A 58 mm pentagon 0.10 m away tilted 35 deg (f = 600 px): a corner restored adds less than the clear
    allowance's 20 %, so that allowance applies to small (nearly affine) polygons only."""
    from scipy.spatial.transform import Rotation
    angles = np.arange(5) * 2 * np.pi / 5
    radius = 0.058 / (2 * np.sin(np.pi / 5))
    corners = np.column_stack([radius * np.cos(angles), radius * np.sin(angles), np.zeros(5)])
    points = corners @ Rotation.from_euler('x', 35, degrees=True).as_matrix().T + [0.0, 0.0, 0.10]
    pentagon = 600.0 * points[:, :2] / points[:, 2:]
    assert len(vision.remove_cut_corners(pentagon, 0.04, 0.2)) == 4            # what a size limit prevents
    np.testing.assert_array_equal(vision.remove_cut_corners(pentagon, 0.04, 0.2, 100.0), pentagon)


def _regular_polygon(n, radius, angle_deg=0.0, squash=1.0, centre=(160.0, 120.0)):
    """(n, 2) corners of a regular n-gon of circumradius ``radius`` (px), turned, squashed along v (a tilted view)."""
    angles = np.radians(angle_deg) + 2 * np.pi * np.arange(n) / n
    return np.column_stack([radius * np.cos(angles), squash * radius * np.sin(angles)]) + centre


def _blurred_outline(corners, size=(240, 320)):
    """The outer contour of ``corners`` filled, blurred (sigma 1 px) and thresholded: a small block's mask."""
    mask = np.zeros(size, np.uint8)
    cv2.fillPoly(mask, [np.round(corners * 16).astype(np.int32)], 255, cv2.LINE_8, shift=4)
    mask = cv2.threshold(cv2.GaussianBlur(mask, (0, 0), 1.0), 127, 255, cv2.THRESH_BINARY)[1]
    contours, _ = cv2.findContours(mask, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
    return max(contours, key=cv2.contourArea)


@pytest.mark.parametrize('n', [3, 4, 5, 6])
def test_the_outlines_harmonics_count_a_small_polygons_corners(n):
    """9-12 px circumradius, any turn, squashed to 0.8 (a 37 deg tilt): the spectrum's peak is the vertex count,
    twice the runner-up, at half a sharp polygon's amplitude or more; at 7 px never another count so clearly; a
    disc has no harmonic that stands out so, nor as strongly."""
    for radius in (7.0, 9.0, 12.0):
        for angle in (0.0, 13.0, 29.0):
            for squash in (1.0, 0.8):
                found = vision.shape_harmonics(_blurred_outline(_regular_polygon(n, radius, angle, squash)))
                assert found.count == n if found.margin > 2.0 else radius < 9.0, (radius, angle, squash, found)
                assert found.strength > 0.5 or radius < 9.0, (radius, angle, squash, found)
    disc = vision.shape_harmonics(_blurred_outline(_regular_polygon(64, 12.0)))
    assert disc.margin < 2.0 and disc.strength < 0.2
    assert vision.shape_harmonics(np.array([[[0, 0]], [[5, 0]], [[9, 0]], [[3, 0]], [[1, 0]]])).count is None


def test_a_hull_reduced_to_its_corners():
    """A square with rounded corners (each cut into 4 hull points) reduced to 4 vertices: one near each corner."""
    square = _regular_polygon(4, 20.0, 45.0)
    rounded = [c + 2.0 * np.array([np.cos(t), np.sin(t)]) - 2.0 * np.sign(c - (160.0, 120.0))
               for c in square for t in np.linspace(0, 2 * np.pi, 12, endpoint=False)]
    hull = cv2.convexHull(np.array(rounded, np.float32))
    reduced = vision.hull_polygon(hull, 4)
    assert reduced.shape == (4, 2)
    assert max(np.min(np.linalg.norm(square - v, axis=1)) for v in reduced) < 2.5
    assert len(vision.hull_polygon(hull, 40)) == len(hull)


def test_a_bend_in_a_side_is_dropped_and_true_corners_kept():
    """A side bent by 15 deg halfway (the outline following a sliver of side face): 3.3 % of the area, dropped at
    8 %; the corners of a squashed hexagon (a tilted view, 17 % each) and of a pentagon stay."""
    bent = np.array([[0, 0], [100, 0], [100, 100], [50, 100 + 50 * np.tan(np.radians(15))], [0, 100]], float)
    np.testing.assert_array_equal(vision.remove_flat_vertices(bent, 0.08), bent[[0, 1, 2, 4]])
    for n in (5, 6):
        angles = np.arange(n) * 2 * np.pi / n
        polygon = 50 * np.column_stack([np.cos(angles), 0.6 * np.sin(angles)])
        np.testing.assert_array_equal(vision.remove_flat_vertices(polygon, 0.08), polygon)
    triangle = np.array([[0, 0], [100, 0], [50, 1]], float)
    assert len(vision.remove_flat_vertices(triangle, 0.9)) == 3                              # never below 3 vertices


def test_vertex_order_and_classification():
    rng = np.random.default_rng(0)
    polygon = np.array([[10, 0], [0, 10], [-10, 0], [0, -10]], float) + [50, 60]
    ordered = vision.order_vertices(polygon[rng.permutation(4)])
    angles = np.arctan2(ordered[:, 1] - 60, ordered[:, 0] - 50)
    assert np.all(np.diff(angles) > 0)
    assert [vision.classify_shape(n) for n in range(2, 8)] == [None, 'triangle', 'square', 'pentagon', 'hexagon', None]


# ----------------------------------------------------------------------------------------- rendered images
@pytest.mark.parametrize('shape', ['triangle', 'square', 'pentagon', 'hexagon'])
def test_shapes_are_classified_from_rendered_images(camera, config, shape):
    rng = np.random.default_rng(7)
    spec = synthetic.BlockSpec(shape, 0.04, 0.02, GREEN)
    for pixel, tilt in [((320, 240), 5.0), ((200, 300), 20.0)]:
        T = block_pose(camera, pixel, 0.25, tilt, 40.0, 17.0)
        image, truths = synthetic.render_block_scene(camera, [(spec, T)], rng)
        detections = vision.detect(image, config)
        assert [d.shape for d in detections] == [shape]
        assert vertex_errors(detections[0].vertices_px, truths[0]['vertices_px']).max() < 1.0


def test_top_face_isolation_at_30_degrees(camera, config):
    spec = synthetic.BlockSpec('square', 0.04, 0.02, GREEN)
    T = block_pose(camera, (330, 250), 0.20, tilt_deg=30.0, tilt_azimuth_deg=-60.0, yaw_deg=30.0)
    image, truths = synthetic.render_block_scene(camera, [(spec, T)], np.random.default_rng(3))
    detections = vision.detect(image, config)
    assert len(detections) == 1 and len(detections[0].vertices_px) == 4
    assert vertex_errors(detections[0].vertices_px, truths[0]['vertices_px']).max() < 0.5
    # the thesis pipeline alone takes the side faces for part of the square: wrong polygon or corners pixels off
    # (without top-face isolation, the side-face cut alone now finds the crease and gets the square: both off)
    plain = dataclasses.replace(config, top_face=dataclasses.replace(config.top_face, enabled=False),
                                side_face_cut=dataclasses.replace(config.side_face_cut, enabled=False))
    [outline] = vision.detect(image, plain)
    assert len(outline.vertices_px) != 4 or vertex_errors(outline.vertices_px, truths[0]['vertices_px']).max() > 3.0


def test_subpixel_vertex_accuracy_on_random_views(camera, config):
    """40 mm squares, 0.10-0.40 m, tilt up to 35 deg, the renderer's default noise, blur and JPEG."""
    rng = np.random.default_rng(11)
    spec = synthetic.BlockSpec('square', 0.04, 0.02, GREEN)
    coarse = dataclasses.replace(config, subpixel=dataclasses.replace(config.subpixel, enabled=False))
    errors, coarse_errors, missed = [], [], 0
    for _ in range(30):
        T = synthetic.random_block_pose(rng, (0.10, 0.40), 35.0, camera, block=spec)
        image, truths = synthetic.render_block_scene(camera, [(spec, T)], rng)
        squares = vision.detect(image, config, shapes=['square'])
        if not squares:
            missed += 1
            continue
        errors.extend(vertex_errors(squares[0].vertices_px, truths[0]['vertices_px']))
        without = vision.detect(image, coarse, shapes=['square'])
        if without:
            coarse_errors.extend(vertex_errors(without[0].vertices_px, truths[0]['vertices_px']))
    errors = np.array(errors)
    assert missed == 0
    assert np.median(errors) <= 0.1
    assert np.percentile(errors, 90) <= 0.35                             # side faces (thin ones too) kept out
    assert np.median(coarse_errors) > 3 * np.median(errors)             # the refinement is what gets there


# Views where the previous pipeline failed (perception benchmark, seed 1): a dark side face, same hue as the
# top, merged with it (wrong shape), or a side face thinner than the previous split could see.
# (shape, side m, colour, rotation vector of T_camera_block, its translation m)
SIDE_FACE_VIEWS = [
    ('pentagon', 0.0321, 'blue', [-0.21972, -2.79245, -0.36780], [-0.12148, 0.08215, 0.20903]),   # seen as a hexagon
    ('triangle', 0.0365, 'blue', [-1.47063, 2.65387, -0.19294], [-0.05004, -0.08190, 0.22146]),   # ... as a square
    ('square', 0.0369, 'red', [-2.39328, -1.47663, 0.34447], [-0.03020, 0.04292, 0.26612]),       # ... as a pentagon
    ('triangle', 0.0356, 'green', [2.48702, -0.98596, 0.62654], [0.09720, -0.11644, 0.36210]),    # ... as a pentagon
    ('square', 0.0400, 'green', [2.82255, -1.22082, -0.54384], [0.09988, 0.03346, 0.20840]),      # 7 px side face kept
]
# Near face-on views slightly off-centre (where the servo ends): a 1-2.5 px side face along one or two
# edges, which the previous refinement took for part of the top face (those edges 1-2.5 px out). The
# darkening of such a face is assumed, not seen (``side_face_darkening``), hence a few tenths of a pixel.
THIN_SIDE_FACE_VIEWS = [
    ('square', 0.0400, 'green', [-2.75443, 1.38416, -0.11717], [-0.05498, 0.00507, 0.17122]),     # tilt 5 deg
    ('pentagon', 0.0370, 'blue', [0.34923, -2.85461, 0.08132], [0.01732, -0.00806, 0.16009]),     # tilt 15 deg
    ('hexagon', 0.0593, 'blue', [-0.82338, 3.01286, 0.06911], [0.06997, -0.00772, 0.23794]),      # tilt 3 deg
]


def polygon_area(vertices):
    """Area (px^2) of the polygon ``vertices`` (n, 2)."""
    u, v = np.asarray(vertices, float).T
    return 0.5 * abs(float(np.dot(u, np.roll(v, -1)) - np.dot(v, np.roll(u, -1))))


def _render_view(camera, view, seed):
    shape, side, colour, rotvec, position = view
    spec = synthetic.BlockSpec(shape, side, 0.02, COLOURS_BGR[colour])
    T = make_transform(Rotation.from_rotvec(rotvec), position)
    image, truths = synthetic.render_block_scene(camera, [(spec, T)], np.random.default_rng(seed))
    return image, truths[0]['vertices_px']


@pytest.mark.parametrize('view', SIDE_FACE_VIEWS, ids=lambda v: f'{v[0]}-{v[2]}')
def test_top_face_is_split_from_darker_side_faces(camera, config, view):
    for seed in (21, 22, 23, 24):            # the previous pipeline failed each view with one of these at least
        image, truth = _render_view(camera, view, seed)
        detections = vision.detect(image, config, colours=[view[2]])
        assert [d.shape for d in detections] == [view[0]], seed
        errors = vertex_errors(detections[0].vertices_px, truth)
        assert errors.mean() < 0.4 and errors.max() < 1.0, (seed, errors)


@pytest.mark.parametrize('view', THIN_SIDE_FACE_VIEWS, ids=lambda v: f'{v[0]}-{v[2]}')
def test_thin_side_face_does_not_pull_an_edge_out(camera, config, view):
    for seed in (31, 32):
        image, truth = _render_view(camera, view, seed)
        [detection] = vision.detect(image, config, colours=[view[2]])
        errors = vertex_errors(detection.vertices_px, truth)
        # The strips' darkening is assumed (0.5), not seen: the square's two faces darken by 0.47 and 0.68 (the
        # renderer's shading), so their widths (1.5 and 2.3 px) come out 0.4 px too wide and 0.2 px too narrow,
        # and the corner between them moves by up to ~1 px, along the edges; hence the max bound. What the
        # previous refinement did, strips taken for top face, puts edges out: the area bound catches it.
        assert errors.mean() < 0.35 and errors.max() < 1.1, errors
        perimeter = np.linalg.norm(truth - np.roll(truth, 1, axis=0), axis=1).sum()
        assert detection.area_px < polygon_area(truth) + 0.5 * perimeter, (detection.area_px, polygon_area(truth))


def test_top_face_under_a_lower_light(camera, config):
    """A light 35 deg from the table's normal: the brightest side face is 0.76 as bright as the top (as in the fake)."""
    rng = np.random.default_rng(5)
    for k in range(16):
        spec = synthetic.BlockSpec(['square', 'pentagon', 'triangle', 'hexagon'][k % 4], 0.04, 0.02, GREEN)
        T = synthetic.random_block_pose(rng, (0.15, 0.35), 35.0, camera, block=spec)
        image, truths = synthetic.render_block_scene(camera, [(spec, T)], rng, light_dir_camera=(0.6, 0.2, -1.0))
        detections = vision.detect(image, config)
        assert [d.shape for d in detections] == [spec.shape], k
        assert vertex_errors(detections[0].vertices_px, truths[0]['vertices_px']).mean() < 0.5, k


def _blob_and_hsv(faces, size=(48, 48)):
    """(outer contour of the union, HSV image) of ``faces``: [(x0, y0, x1, y1) inclusive px, V]; S = 200, H = 60."""
    return _blob_and_hsv_of_polygons([(np.array([[x0, y0], [x1, y0], [x1, y1], [x0, y1]], float), value)
                                      for x0, y0, x1, y1, value in faces], size)


def test_a_bright_patch_with_blob_around_it_is_no_top_face(config):
    """A 30 px face (V 120) with a brighter patch (V 170, 12 x 16 px) 2 px in from its left edge: a highlight or glare
    lying along the face's rim there, 7 px from the rim above and below it, 16 px to the right. The patch is solid and
    a third of its outline lies within 3.5 px of the rim, but the blob extends beyond it in every direction of any
    half-turn (7 px or more), which no top face with side faces beside it does: the whole blob is the face. A
    true split, a 20 px top face (V 170) above an 8 px side face (V 110), still is one: the top face reaches the
    silhouette on its three free sides."""
    blob, hsv = _blob_and_hsv([(8, 8, 37, 37, 120), (10, 15, 21, 30, 170)])
    face = vision.isolate_top_face(blob, hsv, config.top_face)
    assert cv2.contourArea(face) == cv2.contourArea(blob)
    blob, hsv = _blob_and_hsv([(10, 10, 29, 29, 170), (10, 30, 29, 37, 110)])
    face = vision.isolate_top_face(blob, hsv, config.top_face)
    assert cv2.boundingRect(face) == (10, 10, 20, 20)


def test_a_top_face_along_its_blobs_bounding_box_is_split_off(config):
    """A 30 px top face (V 170) whose side face (12 px, V 110) is below it: the face's three free edges lie on the
    blob's bounding box, the crop top-face isolation works in. They are its silhouette and count for the rim share
    (not counted, only the crease and the 3.5 px of it near the rim were: a share of 0.27, no split)."""
    blob, hsv = _blob_and_hsv([(10, 10, 39, 39, 170), (10, 40, 39, 51, 110)], size=(64, 64))
    face = vision.isolate_top_face(blob, hsv, config.top_face)
    assert cv2.boundingRect(face) == (10, 10, 30, 30)


def _blob_and_hsv_of_polygons(faces, size=(120, 120)):
    """(outer contour of the union, HSV image) of faces given as (corners (k, 2) px, V), drawn in order on black;
    S = 200, H = 60."""
    hsv = np.zeros(size + (3,), np.uint8)
    for corners, value in faces:
        cv2.fillPoly(hsv, [np.round(corners).astype(np.int32)], (60, 200, value))
    contours, _ = cv2.findContours(np.where(hsv[..., 2] > 0, 255, 0).astype(np.uint8), cv2.RETR_EXTERNAL,
                                   cv2.CHAIN_APPROX_NONE)
    return max(contours, key=cv2.contourArea), hsv


def test_a_cube_seen_from_a_corner_with_a_side_lit_as_the_top_gives_its_top(config):
    """A cube from a corner: top face (1400 px^2, V 150), one side face lit alike (704 px^2, V 148), the third side
    darker (V 90). Otsu's bright class is top and side together, a hexagon with one reflex corner (solidity 0.85,
    kept whole as the face before); cut along their shared edge, the larger part is the top face. A face with a shadowed corner
    (an L, one reflex corner too) is not two faces: its edges are not parallel in pairs, it is not cut in two."""
    corner, along, across, down = np.array([60.0, 70.0]), np.array([40.0, -8.0]), np.array([-25.0, -30.0]), \
        np.array([-6.5, 19.0])
    top = np.array([corner, corner + along, corner + along + across, corner + across])
    side = np.array([corner, corner + down, corner + along + down, corner + along])
    third = np.array([corner, corner + across, corner + across + down, corner + down])
    blob, hsv = _blob_and_hsv_of_polygons([(third, 90), (side, 148), (top, 150)])
    face = vision.isolate_top_face(blob, hsv, config.top_face)
    assert cv2.contourArea(face) == pytest.approx(1400, rel=0.08)
    assert cv2.pointPolygonTest(face, tuple(side.mean(axis=0)), False) < 0          # the lit side face is out
    assert cv2.pointPolygonTest(face, tuple(top.mean(axis=0)), False) > 0
    square = np.array([[20, 20], [80, 20], [80, 80], [20, 80]], float)
    shadow = np.array([[55, 55], [80, 55], [80, 80], [55, 80]], float)
    blob, hsv = _blob_and_hsv_of_polygons([(square, 150), (shadow, 90)])
    face = vision.isolate_top_face(blob, hsv, config.top_face)
    assert cv2.contourArea(cv2.convexHull(face)) > 0.85 * cv2.contourArea(blob)     # (cut: 0.39)


def test_roi_search_gives_the_full_frame_result(camera, config):
    rng = np.random.default_rng(5)
    blocks = [(synthetic.BlockSpec('square', 0.04, 0.02, GREEN), block_pose(camera, (200, 200), 0.3, 10.0)),
              (synthetic.BlockSpec('triangle', 0.04, 0.02, COLOURS_BGR['red']), block_pose(camera, (450, 300), 0.3))]
    image, _ = synthetic.render_block_scene(camera, blocks, rng)
    full = dataclasses.replace(config, roi=dataclasses.replace(config.roi, enabled=False))
    with_roi, without = vision.detect(image, config), vision.detect(image, full)
    assert [(d.shape, d.colour) for d in with_roi] == [(d.shape, d.colour) for d in without] \
        == [('square', 'green'), ('triangle', 'red')]
    for a, b in zip(with_roi, without):
        np.testing.assert_allclose(a.vertices_px, b.vertices_px, atol=0.05)


@pytest.mark.parametrize('colour', sorted(COLOURS_BGR))
def test_each_named_colour_is_detected_as_itself(camera, config, colour):
    spec = synthetic.BlockSpec('square', 0.04, 0.02, COLOURS_BGR[colour])
    centre = (camera.cx, camera.cy)                      # on the optical axis, facing it: no side face shows
    image, truths = synthetic.render_block_scene(camera, [(spec, block_pose(camera, centre, 0.2, 0.0, 0.0, 20.0))],
                                                 np.random.default_rng(1))
    detections = vision.detect(image, config)
    assert [(d.shape, d.colour) for d in detections] == [('square', colour)]
    assert vertex_errors(detections[0].vertices_px, truths[0]['vertices_px']).max() < 0.5
    assert 0.5 < detections[0].quality <= 1.0 and not detections[0].touches_border


def test_block_cut_by_the_border_is_flagged(camera, config):
    spec = synthetic.BlockSpec('square', 0.04, 0.02, GREEN)
    image, _ = synthetic.render_block_scene(camera, [(spec, block_pose(camera, (12, 240), 0.2, 0.0, 0.0, 10.0))],
                                            np.random.default_rng(2))
    detections = vision.detect(image, config)
    assert detections and all(d.touches_border for d in detections)


def _lumpy_blob(centre, lobes, amplitude, radius_px=30.0, size=(640, 400)):
    """A red blob on grey whose outline has no straight stretch: radius x (1 + amplitude sin(lobes theta))."""
    image = np.full((size[1], size[0], 3), (120, 125, 125), np.uint8)
    theta = np.linspace(0.0, 2.0 * np.pi, 400, endpoint=False)
    radius = radius_px * (1.0 + amplitude * np.sin(lobes * theta))
    outline = np.stack([centre[0] + radius * np.cos(theta), centre[1] + radius * np.sin(theta)], axis=1)
    cv2.fillPoly(image, [np.round(outline * 16).astype(np.int32)], (40, 40, 200), cv2.LINE_AA, shift=4)
    return cv2.GaussianBlur(image, (0, 0), 1.0)


@pytest.mark.parametrize('lobes, amplitude', [(7, 0.1), (7, 0.15), (9, 0.15), (11, 0.1)])
def test_a_fragment_cut_by_the_border_without_a_straight_edge_is_no_block(config, lobes, amplitude):
    """Like the real e-stop button cut by the image border: the border gives the fragment its one straight side,
    so without an edge of its own along a straight image edge it is nothing (each of these made a triangle or a
    square before; the block cut by the border above is kept)."""
    assert vision.detect(_lumpy_blob((10, 200), lobes, amplitude), config) == []


def test_detection_fields_and_drawing(camera, config):
    spec = synthetic.BlockSpec('pentagon', 0.04, 0.02, GREEN)
    image, truths = synthetic.render_block_scene(camera, [(spec, block_pose(camera, (320, 240), 0.2))],
                                                 np.random.default_rng(4))
    [detection] = vision.detect(image, config)
    v = detection.vertices_px
    assert v.shape == (5, 2) and detection.contour.dtype == np.int32 and detection.contour.shape[1:] == (1, 2)
    angles = np.arctan2(v[:, 1] - v[:, 1].mean(), v[:, 0] - v[:, 0].mean())
    assert np.all(np.diff(angles) > 0)
    np.testing.assert_allclose(detection.centroid_px, truths[0]['centroid_px'], atol=0.5)
    assert detection.area_px == pytest.approx(cv2.contourArea(truths[0]['vertices_px'].astype(np.float32)), rel=0.01)
    before = image.copy()
    drawn = vision.draw_detections(image, [detection])
    np.testing.assert_array_equal(image, before)
    assert drawn.shape == image.shape and np.count_nonzero(np.any(drawn != image, axis=2)) > 100


# ----------------------------------------------------------------------------------------- errors, selection
@pytest.mark.parametrize('image, message', [
    (np.zeros((48, 64, 3), np.float32), 'uint8'),
    (np.zeros((48, 64), np.uint8), 'mono8'),
    (np.zeros((48, 64, 4), np.uint8), r'\(H, W, 3\)'),
    (np.zeros((0, 64, 3), np.uint8), 'empty'),
    ([[0, 0, 0]], 'numpy array'),
])
def test_bad_images_are_rejected(config, image, message):
    with pytest.raises(ValueError, match=message):
        vision.detect(image, config)


def test_unknown_colour_or_shape_is_rejected(config):
    image = np.full((48, 64, 3), 200, np.uint8)
    with pytest.raises(ValueError, match='purple'):
        vision.detect(image, config, colours=['purple'])
    with pytest.raises(ValueError, match='star'):
        vision.detect(image, config, shapes=['star'])
    assert vision.detect(image, config) == []


def test_select_target_with_distractors(camera, config):
    blocks = [(synthetic.BlockSpec('square', 0.04, 0.02, GREEN), block_pose(camera, (180, 150), 0.30)),
              (synthetic.BlockSpec('square', 0.05, 0.02, GREEN), block_pose(camera, (450, 330), 0.25)),   # the target
              (synthetic.BlockSpec('square', 0.06, 0.02, COLOURS_BGR['red']), block_pose(camera, (460, 130), 0.2)),
              (synthetic.BlockSpec('triangle', 0.07, 0.02, GREEN), block_pose(camera, (170, 340), 0.2))]
    image, truths = synthetic.render_block_scene(camera, blocks, np.random.default_rng(8))
    detections = vision.detect(image, config)
    assert sorted((d.shape, d.colour) for d in detections) == [
        ('square', 'green'), ('square', 'green'), ('square', 'red'), ('triangle', 'green')]
    target = vision.select_target(detections, 'square', 'green', (camera.width, camera.height))
    np.testing.assert_allclose(target.centroid_px, truths[1]['centroid_px'], atol=1.0)
    assert vision.select_target(detections, 'hexagon', 'green', (640, 480)) is None
    assert vision.select_target(detections, None, 'red', (640, 480)).colour == 'red'


def test_select_target_breaks_ties_by_centrality():
    def fake(centroid, area):
        return vision.Detection('square', 'green', np.zeros((4, 2)), np.array(centroid, float), area, 1.0, False,
                                np.zeros((4, 1, 2), np.int32))
    far, near = fake((100, 100), 1000.0), fake((330, 250), 995.0)
    assert vision.select_target([far, near], 'square', 'green', (640, 480)) is near
    smaller = fake((320, 240), 900.0)
    assert vision.select_target([far, smaller], 'square', 'green', (640, 480)) is far


def test_a_close_top_face_brighter_at_one_end_is_still_split_from_its_side_face(config):
    """A 90 px top face (turned 10 deg) above a 10 px side face 17 grey levels (14 %) darker, both brightening from
    left to right by 25 levels (vignetting and the light's fall-off across a close block): Otsu's threshold on the
    raw V cuts the blob along the gradient (the classes then differ by less than ``min_contrast``) and the side face
    would stay in the polygon; with the gradient taken out the split holds and the face is the top's."""
    angle = np.radians(10.0)
    rotation = np.array([[np.cos(angle), -np.sin(angle)], [np.sin(angle), np.cos(angle)]])
    top = np.array([[-45, -45], [45, -45], [45, 45], [-45, 45]]) @ rotation.T + [70, 65]
    side = np.array([top[3], top[2], top[2] + [0, 10], top[3] + [0, 10]])
    value = np.zeros((140, 140), np.uint8)
    cv2.fillPoly(value, [np.round(side).astype(np.int32)], 108)
    cv2.fillPoly(value, [np.round(top).astype(np.int32)], 125)
    ramp = np.round(np.linspace(-12.5, 12.5, 140)).astype(np.int16)[None, :]
    value = np.where(value > 0, value + ramp, 0).astype(np.uint8)
    hsv = np.dstack([np.full_like(value, 60), np.where(value > 0, 200, 0).astype(np.uint8), value])
    contours, _ = cv2.findContours(np.where(value > 0, 255, 0).astype(np.uint8), cv2.RETR_EXTERNAL,
                                   cv2.CHAIN_APPROX_NONE)
    blob = max(contours, key=cv2.contourArea)
    face = vision.isolate_top_face(blob, hsv, config.top_face)
    assert cv2.contourArea(face) == pytest.approx(90 * 90, rel=0.03)
    assert cv2.pointPolygonTest(face, tuple(map(float, top[2] + [0, 8])), False) < 0     # the side face is out


def _face_with_strip(strip_value=None, mark=False, ramp=False, size=80, strip_px=10):
    """A green square face (V 150) on grey, its right-hand side face kept in the same colour class (a strip
    ``strip_px`` wide of V ``strip_value``), or a dark printed line inside the face (``mark``), or the face
    darkening smoothly towards its right edge (``ramp``); blurred. Returns (image, polygon of face + strip, the face's
    right edge's u)."""
    image = np.full((200, 200, 3), 120, np.uint8)
    x0, y0 = 50, 60
    x_face = x0 + size
    image[y0:y0 + size, x0:x_face] = (40, 150, 40)
    right = x_face
    if strip_value is not None:
        image[y0:y0 + size, x_face:x_face + strip_px] = (0, strip_value, 0)
        right = x_face + strip_px
    if mark:
        image[y0 + 5:y0 + size - 5, x_face - 14:x_face - 11] = (20, 60, 20)
    if ramp:
        columns = np.arange(x0, x_face)
        gain = np.clip(1.0 - 0.25 * (columns - (x_face - 12)) / 12.0, 0.75, 1.0)
        image[y0:y0 + size, x0:x_face] = (image[y0:y0 + size, x0:x_face] * gain[None, :, None]).astype(np.uint8)
    image = cv2.GaussianBlur(image, (5, 5), 1.0)
    polygon = np.array([[x0, y0], [right, y0], [right, y0 + size], [x0, y0 + size]], float) - 0.5
    return image, polygon, x_face - 0.5


def test_a_side_face_kept_in_the_polygon_is_cut_off_along_its_crease(config):
    """A side face lit almost like the top (V 135 against 150: 10 % darker, same colour class) and kept in the
    polygon: the edge moves onto the crease between the two faces, the other edges stay."""
    image, polygon, crease_u = _face_with_strip(strip_value=135)
    cut = vision.cut_side_faces(image, polygon, config.side_face_cut)
    assert np.abs(cut[:, 0].max() - crease_u) <= 1.0 and np.abs(cut[:, 0].min() - polygon[:, 0].min()) < 1e-9
    assert np.allclose(np.sort(cut[:, 1]), np.sort(polygon[:, 1]), atol=1.0)


def test_a_narrow_side_face_on_a_near_block_is_cut_off_too(config):
    """A side face 6 px wide beside a 120 px face (a block 0.19 m under the hand camera: the strip under the hand's
    penumbra in the trials): its crease lies shallower than the tilted lines' band starts (2.5 px + 5 px of
    slope at 120 px); the straight line finds it."""
    image, polygon, crease_u = _face_with_strip(strip_value=110, size=120, strip_px=6)
    image = np.ascontiguousarray(np.pad(image, ((0, 60), (0, 60), (0, 0)), mode='edge'))
    cut = vision.cut_side_faces(image, polygon, config.side_face_cut)
    assert np.abs(cut[:, 0].max() - crease_u) <= 1.0 and np.abs(cut[:, 0].min() - polygon[:, 0].min()) < 1e-9


def _face_with_wedge(near_px, far_px, strip_value=130, size=60):
    """A green face beside a side face seen in perspective: a strip (V ``strip_value``) ``near_px`` wide at the
    face's top row, ``far_px`` at its bottom (antialiased), on a grey table, blurred. Returns (image, polygon of face
    + strip, the face's right edge's u)."""
    image = np.full((200, 200, 3), 120, np.uint8)
    x0, y0 = 50, 60
    x_face = x0 + size
    columns = np.arange(x_face, x_face + 16)
    for row in range(size):
        width = near_px + (far_px - near_px) * (row + 0.5) / size
        cover = np.clip(x_face + width - columns, 0.0, 1.0)[:, None]
        table = image[y0 + row, x_face:x_face + 16].astype(float)
        image[y0 + row, x_face:x_face + 16] = (cover * (0, strip_value, 0) + (1 - cover) * table).astype(np.uint8)
    image[y0:y0 + size, x0:x_face] = (40, 150, 40)
    image = cv2.GaussianBlur(image, (5, 5), 1.0)
    polygon = np.array([[x0, y0], [x_face + near_px, y0], [x_face + far_px, y0 + size], [x0, y0 + size]], float)
    return image, polygon - 0.5, x_face - 0.5


@pytest.mark.parametrize('near_px, far_px', [(4, 10), (3, 9)])
def test_a_wedge_shaped_side_face_is_cut_off(config, near_px, far_px):
    """A side face seen in perspective, 3-4 px wide at one end and 9-10 px at the other (a 40 mm cube 0.2-0.4 m
    away, tilted): the sloped lines' band starts deeper than its narrow end, yet the strip is judged where the
    crease leaves it; the edge moves onto the crease."""
    image, polygon, crease_u = _face_with_wedge(near_px, far_px)
    cut = vision.cut_side_faces(image, polygon, config.side_face_cut)
    assert np.abs(cut[1:3, 0] - crease_u).max() <= 1.0
    assert np.allclose(cut[[0, 3]], polygon[[0, 3]])


@pytest.mark.parametrize('case', ['no strip', 'a printed line inside', 'shading towards the edge', 'too small',
                                  'a shadow across block and table'])
def test_no_crease_no_cut(config, case):
    """A face with nothing beside it, a dark line printed inside it (the strip before it as bright as the face),
    a face darkening smoothly towards an edge (no step), a face under ``min_size_px``, and the sharp edge of a
    shadow parallel to an edge, across the face and the table around it: the polygon unchanged."""
    if case == 'too small':
        image, polygon, _ = _face_with_strip(strip_value=135, size=30, strip_px=5)
    elif case.startswith('a shadow'):
        image, polygon, _ = _face_with_strip()
        image[:, 118:] = (image[:, 118:] * 0.85).astype(np.uint8)          # the shadow: x >= 118, face and table
    else:
        image, polygon, _ = _face_with_strip(mark=case == 'a printed line inside', ramp=case.startswith('shading'))
    assert np.array_equal(vision.cut_side_faces(image, polygon, config.side_face_cut), polygon)


def test_the_top_faces_rim_is_the_pixels_within_its_depth_of_the_outside():
    """``topface._rim`` (erosions) marks the same pixels as OpenCV's 3x3 L2 distance transform within
    ``_RIM_DEPTH_PX`` of an outside pixel, the crop's border outside: 300 random convex blobs with holes, 5-300 px."""
    from baxter_pnp.vision import topface
    rng = np.random.default_rng(3)
    for _ in range(300):
        h, w = (int(n) for n in rng.integers(5, 300, 2))
        inside = np.zeros((h, w), np.uint8)
        cv2.fillPoly(inside, [cv2.convexHull(rng.integers(0, [w, h], (int(rng.integers(3, 9)), 2)).astype(np.int32))],
                     255)
        cv2.circle(inside, tuple(int(c) for c in rng.integers(0, [w, h])), int(rng.integers(1, 10)), 0, -1)
        padded = cv2.copyMakeBorder(inside, 1, 1, 1, 1, cv2.BORDER_CONSTANT, value=0)
        distance = cv2.distanceTransform(padded, cv2.DIST_L2, 3)[1:-1, 1:-1]
        expected = cv2.bitwise_and(inside, cv2.compare(distance, topface._RIM_DEPTH_PX, cv2.CMP_LE))
        np.testing.assert_array_equal(topface._rim(inside), expected)
