"""CameraModel: projection/undistortion, YAML and CameraInfo round trips, scaling, rendering maps."""
import os

import numpy as np
import pytest
import yaml

from baxter_pnp.camera import CameraModel, SensorWindow, load_default_camera


@pytest.fixture(scope='module')
def camera():
    return load_default_camera()


def test_default_camera_is_the_thesis_calibration(camera):
    assert (camera.width, camera.height) == (640, 480)
    assert (camera.fx, camera.fy, camera.cx, camera.cy) == (409.20851, 408.54186, 309.69054, 226.60469)
    np.testing.assert_array_equal(camera.D, [0.02784, -0.05070, -0.00132, 0.00435, 0.0])


def test_project_undistort_round_trip(camera):
    rng = np.random.default_rng(1)
    # points whose images span the whole frame, corners included
    pixels = rng.uniform([0, 0], [camera.width - 1, camera.height - 1], size=(500, 2))
    pixels = np.vstack([pixels, [[0, 0], [639, 0], [0, 479], [639, 479]]])
    xy = camera.undistort_points(pixels)
    depth = rng.uniform(0.1, 2.0, size=len(xy))
    points = np.column_stack([xy * depth[:, None], depth])
    reprojected = camera.project(points)
    assert np.max(np.abs(reprojected - pixels)) < 1e-6
    # distortion matters here: the ideal pixels differ from the distorted ones by up to several pixels
    assert np.max(np.linalg.norm(camera.normalised_to_pixels(xy) - pixels, axis=1)) > 3.0


def test_project_matches_pinhole_without_distortion():
    camera = CameraModel(640, 480, [[500, 0, 320], [0, 510, 240], [0, 0, 1]])
    px = camera.project([[0.1, -0.05, 0.5]])
    np.testing.assert_allclose(px, [[320 + 500 * 0.2, 240 - 510 * 0.1]], atol=1e-9)


def test_yaml_round_trip(camera, tmp_path):
    path = tmp_path / 'cam.yaml'
    camera.to_yaml(path, rms=0.234)
    raw = yaml.safe_load(path.read_text())
    assert raw['distortion_model'] == 'plumb_bob'
    assert raw['projection_matrix']['cols'] == 4 and raw['rms_reprojection_error'] == 0.234
    loaded = CameraModel.from_yaml(path)
    assert (loaded.width, loaded.height, loaded.name) == (camera.width, camera.height, camera.name)
    np.testing.assert_array_equal(loaded.K, camera.K)
    np.testing.assert_array_equal(loaded.D, camera.D)


def test_camera_info_round_trip(camera):
    from std_msgs.msg import Header
    info = camera.to_camera_info()
    assert info.header.frame_id == 'left_hand_camera' and len(info.P) == 12 and info.distortion_model == 'plumb_bob'
    loaded = CameraModel.from_camera_info(info)
    np.testing.assert_array_equal(loaded.K, camera.K)
    np.testing.assert_array_equal(loaded.D, camera.D)
    assert (loaded.width, loaded.height, loaded.frame_id) == (640, 480, 'left_hand_camera')
    assert camera.to_camera_info(Header(frame_id='other', seq=7)).header.seq == 7


def test_camera_info_region_of_interest_and_binning_as_image_geometry(camera):
    """K of the full sensor; the image is the ROI, binned: principal point (c - offset) / binning, focal / binning."""
    info = camera.to_camera_info()
    info.width, info.height = 1280, 800
    info.roi.x_offset, info.roi.y_offset, info.roi.width, info.roi.height = 320, 200, 640, 400
    cropped = CameraModel.from_camera_info(info)
    assert (cropped.width, cropped.height) == (640, 400)
    assert (cropped.cx, cropped.cy) == pytest.approx((camera.cx - 320, camera.cy - 200))
    assert (cropped.fx, cropped.fy) == pytest.approx((camera.fx, camera.fy))
    info.binning_x = info.binning_y = 2
    binned = CameraModel.from_camera_info(info)
    assert (binned.width, binned.height) == (320, 200)
    assert (binned.cx, binned.cy, binned.fx) == pytest.approx(((camera.cx - 320) / 2, (camera.cy - 200) / 2, camera.fx / 2))
    info.header.frame_id = '/left_hand_camera'
    assert CameraModel.from_camera_info(info).frame_id == 'left_hand_camera'


REAL_DATA = os.environ.get('BAXTER_PNP_REAL_DATA',
                           os.path.join(os.path.dirname(__file__), '..', '..', 'shared', 'real'))
REAL_CAMERA_INFO = os.path.join(REAL_DATA, 'baxter_hand_a', 'camera_info_as_published.yaml')


@pytest.mark.skipif(not os.path.exists(REAL_CAMERA_INFO), reason='real data (../shared/real) absent')
def test_a_sensor_window_publishes_what_a_real_hand_camera_publishes():
    """The real robot's 640x400 CameraInfo, rebuilt from its sensor K and D and the centred 640x400 window of the
    1280x800 sensor: K, D, P, roi, binning, size and frame_id as published; ``windowed`` = the message's model."""
    with open(REAL_CAMERA_INFO) as f:
        real = yaml.safe_load(f)
    sensor = CameraModel(1280, 800, real['K'], real['D'], frame_id=real['header']['frame_id'])
    window = SensorWindow.centred(1280, 800, 640, 400)
    fields = sensor.camera_info_fields(window)
    for key in ('K', 'D', 'P', 'R'):
        np.testing.assert_allclose(fields[key], real[key], atol=1e-9, err_msg=key)
    for key in ('width', 'height', 'binning_x', 'binning_y', 'header'):
        assert fields[key] == real[key] or (key == 'header' and fields[key]['frame_id'] == real[key]['frame_id'])
    assert fields['roi'] == real['roi']
    image = CameraModel.from_yaml(REAL_CAMERA_INFO)
    windowed = sensor.windowed(window)
    np.testing.assert_allclose(windowed.K, image.K, atol=1e-9)
    assert (windowed.width, windowed.height, windowed.frame_id) == (640, 400, 'left_hand_camera')
    assert (image.cx, image.cy) == pytest.approx((331.31, 205.82), abs=0.01)     # P's, not K's (651, 406)


def test_sensor_windows_centred_binned_and_checked(camera):
    """A centred window of each size, binned 2x2 at half resolution; windows outside the sensor are refused;
    the camera of a centred crop keeps the rays (same pixel pitch, principal point shifted)."""
    assert SensorWindow.centred(1280, 800, 320, 200) == SensorWindow(480, 300, 320, 200, 1)
    assert SensorWindow.centred(1280, 800, 640, 400, binning=2) == SensorWindow(0, 0, 1280, 800, 2)
    assert SensorWindow(0, 0, 1280, 800, 2).image_size() == (640, 400)
    for bad in (lambda: SensorWindow.centred(1280, 800, 960, 600, binning=2),
                lambda: camera.camera_info_fields(SensorWindow(100, 0, 640, 480))):
        with pytest.raises(ValueError, match='not inside'):
            bad()
    crop = camera.windowed(SensorWindow.centred(640, 480, 640, 400))
    np.testing.assert_allclose(crop.K, camera.scaled(640, 400).K)        # same width: the scaled model is the crop
    binned = camera.windowed(SensorWindow(0, 0, 640, 480, 2))
    assert (binned.width, binned.height, binned.fx, binned.cx) == (320, 240, camera.fx / 2, camera.cx / 2)
    info = camera.to_camera_info(window=SensorWindow(0, 40, 640, 400))
    assert (info.roi.y_offset, info.height, info.P[6]) == (40, 400, pytest.approx(camera.cy - 40))


@pytest.mark.parametrize('field, value, message', [
    ('K', [0.0] * 9, 'focal length'),
    ('K', [float('nan'), 0, 320, 0, 400, 200, 0, 0, 1], 'finite'),
    ('K', [-400.0, 0, 320, 0, 400, 200, 0, 0, 1], 'focal lengths must be positive'),
    ('K', [400.0, 0, 320, 0, 400, 200, 0, 0, 0], 'last row'),
    ('D', [0.1, float('inf'), 0, 0, 0], 'finite'),
    ('K', [1.0] * 4, 'K must have 9'),
    ('D', [0.1, 0.2], 'D must have 5'),
    ('distortion_model', 'equidistant', 'distortion_model'),
])
def test_camera_info_rejects_bad_fields(camera, field, value, message):
    info = camera.to_camera_info()
    setattr(info, field, value)
    with pytest.raises(ValueError, match=message):
        CameraModel.from_camera_info(info)


@pytest.mark.parametrize('edit, message', [
    (lambda d: d['camera_matrix'].update(data=[0.0] * 9), 'zero focal length'),
    (lambda d: d['camera_matrix']['data'].__setitem__(0, float('nan')), 'finite'),
    (lambda d: d['camera_matrix']['data'].__setitem__(4, -410.0), 'focal lengths must be positive'),
    (lambda d: d['distortion_coefficients']['data'].__setitem__(1, float('nan')), 'finite'),
    (lambda d: d.update(image_width=0), 'size must be positive'),
    (lambda d: d['camera_matrix'].update(rows=2), 'camera_matrix must be 3x3'),
    (lambda d: d['distortion_coefficients'].update(data=[0.1, 0.2, 0.3]), 'distortion_coefficients must be 1x5'),
    (lambda d: d.update(distortion_model='rational_polynomial'), 'distortion_model'),
    (lambda d: d.pop('image_width'), 'image_width'),
])
def test_bad_yaml_is_rejected_naming_the_field(camera, tmp_path, edit, message):
    d = camera.to_dict()
    edit(d)
    path = tmp_path / 'bad.yaml'
    path.write_text(yaml.safe_dump(d))
    with pytest.raises(ValueError, match=message):
        CameraModel.from_yaml(path)


def test_scaled_same_rays(camera):
    # 1280x800 (a Baxter camera mode) from 640x480: s = 2, 16:10 crops 80 rows of the doubled image.
    big = camera.scaled(1280, 800)
    assert (big.width, big.height) == (1280, 800)
    assert big.fx == pytest.approx(2 * camera.fx) and big.fy == pytest.approx(2 * camera.fy)
    assert big.cy == pytest.approx((camera.cy + 0.5) * 2 - 0.5 - 80)
    np.testing.assert_array_equal(big.D, camera.D)
    # the same 3D point lands on the same place of the scene: pixel-centre exact scaling and the crop
    points = np.array([[0.05, -0.03, 0.4], [-0.1, 0.07, 0.3]])
    small_px, big_px = camera.project(points), big.project(points)
    np.testing.assert_allclose((big_px + [0.5, 0.5 + 80]) / 2 - 0.5, small_px, atol=1e-9)


def test_rendering_maps_send_each_pixel_to_its_ideal_ray(camera):
    ideal = CameraModel(700, 540, [[camera.fx, 0, camera.cx + 30], [0, camera.fy, camera.cy + 30], [0, 0, 1]])
    map_x, map_y = camera.rendering_maps(ideal)
    assert map_x.shape == (480, 640) and map_x.dtype == np.float32
    assert camera.rendering_maps(ideal)[0] is map_x            # cached
    # a 3D point seen by this camera at (distorted) pixel p is seen by the ideal camera at maps(p)
    rng = np.random.default_rng(2)
    points = np.column_stack([rng.uniform(-0.35, 0.35, 50), rng.uniform(-0.25, 0.25, 50), np.full(50, 0.45)])
    p = camera.project(points)
    inside = np.all((p >= 0) & (p <= [639, 479]), axis=1)
    assert inside.sum() > 30
    u, v = p[inside].T
    sample = np.column_stack([_bilinear(map_x, u, v), _bilinear(map_y, u, v)])
    np.testing.assert_allclose(sample, ideal.project(points[inside]), atol=2e-3)
    with pytest.raises(ValueError, match='zero distortion'):
        camera.rendering_maps(camera)


def _bilinear(image, u, v):
    """Bilinear sample of a 2-D float array at pixel positions (u, v)."""
    u0 = np.minimum(np.floor(u).astype(int), image.shape[1] - 2)
    v0 = np.minimum(np.floor(v).astype(int), image.shape[0] - 2)
    a, b = u - u0, v - v0
    return ((1 - a) * (1 - b) * image[v0, u0] + a * (1 - b) * image[v0, u0 + 1]
            + (1 - a) * b * image[v0 + 1, u0] + a * b * image[v0 + 1, u0 + 1])


def test_rendering_maps_match_per_pixel_undistortion():
    """The spline-interpolated maps equal undistorting every pixel exactly (to 1e-3 px), at every mode."""
    for width, height in ((640, 400), (320, 200), (640, 480)):
        camera = load_default_camera().scaled(width, height)
        ideal = CameraModel(width + 40, height + 40, camera.K + np.array([[0, 0, 20], [0, 0, 20], [0, 0, 0]]),
                            np.zeros(5))
        map_x, map_y = camera.rendering_maps(ideal)
        u, v = np.meshgrid(np.arange(width, dtype=float), np.arange(height, dtype=float))
        exact = ideal.normalised_to_pixels(camera.undistort_points(np.column_stack([u.ravel(), v.ravel()])))
        error = np.hypot(map_x.ravel() - exact[:, 0], map_y.ravel() - exact[:, 1])
        assert error.max() < 1e-3
