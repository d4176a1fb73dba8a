"""Pose estimation: exact recovery, vertex order and symmetry, degenerate input, solver fallback, noise.

Vertices are exact projections through ``CameraModel.project`` (the thesis camera, with distortion)
plus Gaussian pixel noise where stated, so the ground truth is exact.
"""
import math
import time

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from baxter_pnp import pose
from baxter_pnp.camera import CameraModel, load_default_camera
from baxter_pnp.models import SHAPES, Plane, model_for
from baxter_pnp.pose import PoseEstimationError, estimate_pose

SIDE = 0.04


@pytest.fixture(scope='module')
def camera():
    return load_default_camera()


def random_pose(rng, camera, model, distance=(0.1, 0.4), max_tilt=math.radians(35)):
    """T_camera_object: top face seen from above, tilted up to ``max_tilt``, random yaw, fully in the image."""
    while True:
        tilt, azimuth = rng.uniform(0, max_tilt), rng.uniform(-math.pi, math.pi)
        rotation = (Rotation.from_euler('x', math.pi)
                    * Rotation.from_rotvec(tilt * np.array([math.cos(azimuth), math.sin(azimuth), 0.0]))
                    * Rotation.from_euler('z', rng.uniform(-math.pi, math.pi)))
        depth = rng.uniform(*distance)
        T = np.eye(4)
        T[:3, :3] = rotation.as_matrix()
        T[:3, 3] = [rng.uniform(-0.3, 0.3) * depth, rng.uniform(-0.25, 0.25) * depth, depth]
        px = camera.project(vertices_in_camera(T, model))
        if np.all((px > 0) & (px < [camera.width - 1, camera.height - 1])):
            return T


def straight_on_pose(rng, depth=0.161, jitter=0.002):
    """The thesis's 'camera above' case: face normal along -z_camera, random yaw, small lateral jitter (m)."""
    T = np.eye(4)
    yaw = rng.uniform(-math.pi, math.pi)
    T[:3, :3] = (Rotation.from_euler('x', math.pi) * Rotation.from_euler('z', yaw)).as_matrix()
    T[:3, 3] = [rng.normal(0, jitter), rng.normal(0, jitter), depth]
    return T


def vertices_in_camera(T, model):
    return model.vertices @ T[:3, :3].T + T[:3, 3]


def detector_order(px):
    """The detector's order: increasing atan2(v - vc, u - uc)."""
    centre = px.mean(axis=0)
    return px[np.argsort(np.arctan2(px[:, 1] - centre[1], px[:, 0] - centre[0]))]


def observe(T, camera, model, rng=None, sigma_px=0.0):
    px = camera.project(vertices_in_camera(T, model))
    if sigma_px:
        px = px + rng.normal(0, sigma_px, px.shape)
    return detector_order(px)


def table_plane_for(T, model, tilt_error=0.0, rng=None):
    """Table-top plane in the camera frame under the block posed at T; normal optionally off by ``tilt_error`` rad."""
    normal = T[:3, 2]
    if tilt_error:
        axis = np.cross(normal, rng.normal(size=3))
        normal = Rotation.from_rotvec(tilt_error * axis / np.linalg.norm(axis)).apply(normal)
    return Plane(normal, normal @ T[:3, 3] - model.height)


def rotation_error(R_estimate, R_true, n):
    """Rotation angle (rad) between two block orientations, modulo the n-fold symmetry about +z."""
    return min(Rotation.from_matrix(R_estimate.T @ R_true @ Rotation.from_euler('z', 2 * math.pi * k / n).as_matrix())
               .magnitude() for k in range(n))


# --------------------------------------------------------------------------------------- exactness
CASES = [(shape, method) for shape in sorted(SHAPES) for method in pose.METHODS
         if (shape, method) != ('triangle', 'sqpnp')]    # OpenCV 4.10's SQPnP is inexact on 3 points


@pytest.mark.parametrize('shape, method', CASES)
def test_exact_vertices_give_the_exact_pose(camera, shape, method):
    model = model_for(shape, SIDE)
    rng = np.random.default_rng(10)
    for trial in range(24):
        T = random_pose(rng, camera, model)
        # three points have up to four exact P3P poses: a triangle needs the table plane; others alternate
        plane = table_plane_for(T, model) if shape == 'triangle' or trial % 2 else None
        estimate = estimate_pose(observe(T, camera, model), camera, model, method=method, table_plane=plane)
        assert estimate.method == method
        assert np.linalg.norm(estimate.position_m - T[:3, 3]) < 1e-6
        assert rotation_error(estimate.T_camera_object[:3, :3], T[:3, :3], model.n) < 1e-6
        assert estimate.residual_px < 1e-6
        assert estimate.depth_m == estimate.T_camera_object[2, 3]
        assert -math.pi / model.n < estimate.yaw_rad <= math.pi / model.n + 1e-12
        np.testing.assert_allclose(Rotation.from_quat(estimate.quaternion_xyzw).as_matrix(),
                                   estimate.T_camera_object[:3, :3], atol=1e-12)


def test_triangle_without_table_plane_reprojects_exactly(camera):
    """Without a prior, a P3P alternative may be returned, but it must reproduce the image exactly."""
    model = model_for('triangle', SIDE)
    rng = np.random.default_rng(11)
    correct = 0
    for _ in range(30):
        T = random_pose(rng, camera, model)
        estimate = estimate_pose(observe(T, camera, model), camera, model)
        assert estimate.residual_px < 1e-6
        correct += np.linalg.norm(estimate.position_m - T[:3, 3]) < 1e-6
    assert correct >= 15     # the most fronto-parallel solution is usually the right one


@pytest.mark.parametrize('shape', sorted(SHAPES))
def test_sqp_converges_from_a_perturbed_initial_pose(camera, shape):
    model = model_for(shape, SIDE)
    rng = np.random.default_rng(12)
    for trial in range(10):
        T = random_pose(rng, camera, model)
        initial = T.copy()    # 3 mm and 3 degrees off, and turned by a random multiple of the symmetry angle
        initial[:3, :3] = (Rotation.from_rotvec(rng.normal(0, 0.03, 3)).as_matrix() @ T[:3, :3]
                           @ Rotation.from_euler('z', model.symmetry_angle * rng.integers(model.n)).as_matrix())
        initial[:3, 3] += rng.normal(0, 0.003, 3)
        plane = table_plane_for(T, model) if trial % 2 else None
        estimate = estimate_pose(observe(T, camera, model), camera, model, table_plane=plane, initial=initial)
        assert estimate.method == 'sqp'
        assert np.linalg.norm(estimate.position_m - T[:3, 3]) < 1e-6
        assert rotation_error(estimate.T_camera_object[:3, :3], T[:3, :3], model.n) < 1e-6


def test_undistortion_is_applied(camera):
    """A block near the image corner: ignoring the thesis camera's distortion costs over 0.1 mm."""
    model = model_for('square', SIDE)
    T = np.eye(4)
    T[:3, :3] = Rotation.from_euler('x', math.pi).as_matrix()
    T[:3, 3] = [0.13, 0.1, 0.2]
    px = observe(T, camera, model)
    assert np.all(px < [camera.width, camera.height])
    pinhole = CameraModel(camera.width, camera.height, camera.K)
    for method in pose.METHODS:
        assert np.linalg.norm(estimate_pose(px, camera, model, method).position_m - T[:3, 3]) < 1e-6
        assert np.linalg.norm(estimate_pose(px, pinhole, model, method).position_m - T[:3, 3]) > 1e-4


# ------------------------------------------------------------------------------- order and symmetry
@pytest.mark.parametrize('shape', sorted(SHAPES))
def test_vertex_order_reversed_or_shifted_gives_the_same_pose(camera, shape):
    model = model_for(shape, SIDE)
    rng = np.random.default_rng(13)
    T = random_pose(rng, camera, model)
    px = observe(T, camera, model, rng, sigma_px=0.5)
    plane = table_plane_for(T, model) if shape == 'triangle' else None
    reference = estimate_pose(px, camera, model, table_plane=plane)
    for order in (px, px[::-1]):
        for shift in range(model.n):
            estimate = estimate_pose(np.roll(order, shift, axis=0), camera, model, table_plane=plane)
            np.testing.assert_allclose(estimate.T_camera_object, reference.T_camera_object, atol=1e-7)
            assert estimate.residual_px == pytest.approx(reference.residual_px, abs=1e-7)


@pytest.mark.parametrize('shape', sorted(SHAPES))
def test_yaw_is_reported_modulo_the_symmetry_angle(camera, shape):
    """Looking straight down, yaw 0.2 rad (plus k symmetry turns) turns the block's x axis towards image up."""
    model = model_for(shape, SIDE)
    for k in range(model.n):
        T = np.eye(4)
        yaw = 0.2 + k * model.symmetry_angle
        T[:3, :3] = (Rotation.from_euler('x', math.pi) * Rotation.from_euler('z', yaw)).as_matrix()
        T[:3, 3] = [0.01, -0.01, 0.2]
        plane = table_plane_for(T, model)
        estimate = estimate_pose(observe(T, camera, model), camera, model, table_plane=plane)
        assert estimate.yaw_rad == pytest.approx(0.2, abs=1e-9)
        origin_and_x_axis = estimate.T_camera_object[:3, :] @ [[0, 0.01], [0, 0], [0, 0], [1, 1]]
        du, dv = np.diff(camera.project(origin_and_x_axis.T), axis=0)[0]
        assert du > 0 and dv < 0                          # image right and up
        assert math.atan2(-dv, du) == pytest.approx(0.2, abs=0.02)
    # the representative of the boundary -pi/n is +pi/n
    T[:3, :3] = (Rotation.from_euler('x', math.pi) * Rotation.from_euler('z', -math.pi / model.n)).as_matrix()
    estimate = estimate_pose(observe(T, camera, model), camera, model, table_plane=table_plane_for(T, model))
    assert estimate.yaw_rad == pytest.approx(math.pi / model.n, abs=1e-9)


# --------------------------------------------------------------------------------------- bad input
@pytest.mark.parametrize('vertices, message', [
    ([[300, 200], [340, 200], [340, 240]], 'needs'),                            # 3 vertices for a square
    ([[300, 200, 1], [340, 200, 1], [340, 240, 1], [300, 240, 1]], 'needs'),    # wrong shape
    ([[300, 200], [340, 200], [340, np.nan], [300, 240]], 'non-finite'),
    ([[300, 200], [340, 200], [np.inf, 240], [300, 240]], 'non-finite'),
    ([[300, 200], [320, 210], [340, 220], [360, 230]], 'degenerate'),           # collinear
    ([[300, 200], [300, 200], [300, 200], [300, 200]], 'degenerate'),           # coincident
    ([[300, 200], [340, 240], [340, 200], [300, 240]], 'self-intersecting'),    # bow tie
    ('not vertices', 'needs'),
])
def test_degenerate_vertices_raise(camera, vertices, message):
    with pytest.raises(PoseEstimationError, match=message):
        estimate_pose(vertices, camera, model_for('square', SIDE))


def test_self_intersecting_pentagram_order_raises(camera):
    model = model_for('pentagon', SIDE)
    T = straight_on_pose(np.random.default_rng(0))
    px = observe(T, camera, model)
    with pytest.raises(PoseEstimationError, match='self-intersecting'):
        estimate_pose(px[[0, 2, 4, 1, 3]], camera, model)


def test_invalid_arguments_raise_value_error(camera):
    model = model_for('square', SIDE)
    T = straight_on_pose(np.random.default_rng(0))
    px = observe(T, camera, model)
    with pytest.raises(ValueError, match='unknown pose method'):
        estimate_pose(px, camera, model, method='epnp')
    away = Plane(-T[:3, 2], -(T[:3, 2] @ T[:3, 3] - model.height))     # normal pointing away from the camera
    with pytest.raises(ValueError, match='table_plane'):
        estimate_pose(px, camera, model, table_plane=away)
    with pytest.raises(ValueError, match='initial'):
        estimate_pose(px, camera, model, initial=np.eye(3))
    # a previous PoseEstimate is accepted as the initial pose
    previous = estimate_pose(px, camera, model)
    assert np.allclose(estimate_pose(px, camera, model, initial=previous).T_camera_object, previous.T_camera_object)


# ------------------------------------------------------------------------------------ robustness
def test_centred_fronto_parallel_square_with_integer_corners_gives_a_finite_pose():
    """The servo's final view: exactly symmetric integer corners, where OpenCV's IPPE_SQUARE breaks down."""
    camera = CameraModel(640, 400, [[403.9, 0, 320], [0, 403.9, 200], [0, 0, 1]])   # integer principal point
    model = model_for('square', SIDE)
    used = {method: [] for method in pose.METHODS}
    for yaw in np.radians(np.arange(0.0, 90.0, 3.0)):
        for depth in (0.155, 0.158, 0.161, 0.164):
            T = np.eye(4)
            T[:3, :3] = (Rotation.from_euler('x', math.pi) * Rotation.from_euler('z', yaw)).as_matrix()
            T[2, 3] = depth
            px = np.round(observe(T, camera, model))
            for method in pose.METHODS:
                estimate = estimate_pose(px, camera, model, method=method)
                assert np.all(np.isfinite(estimate.T_camera_object))
                assert abs(estimate.depth_m - depth) < 2e-3
                used[method].append(estimate.method)
    # premise (opencv 4.10): IPPE_SQUARE gives non-finite or garbage poses here, so 'ippe' fell back
    assert used['ippe'].count('ippe') < len(used['ippe'])
    assert set(used['ippe']) <= {'ippe', 'sqp'} and set(used['sqp']) == {'sqp'}


def test_fallback_order_and_final_error(camera, monkeypatch):
    model = model_for('hexagon', SIDE)
    T = random_pose(np.random.default_rng(14), camera, model)
    px = observe(T, camera, model)

    def non_finite(*args):
        return np.full((3, 3), np.nan), np.full(3, np.nan)

    monkeypatch.setitem(pose._SOLVERS, 'ippe', non_finite)
    estimate = estimate_pose(px, camera, model, method='ippe')
    assert estimate.method == 'sqp'
    assert np.linalg.norm(estimate.position_m - T[:3, 3]) < 1e-6

    def behind(*args):
        return np.eye(3), np.array([0.0, 0.0, -0.2])

    monkeypatch.setitem(pose._SOLVERS, 'sqp', behind)
    assert estimate_pose(px, camera, model, method='sqp').method == 'sqpnp'
    monkeypatch.setitem(pose._SOLVERS, 'sqpnp', non_finite)
    with pytest.raises(PoseEstimationError, match=r'sqp: object behind.*ippe: non-finite.*sqpnp: non-finite'):
        estimate_pose(px, camera, model)


def test_polygon_unlike_the_model_is_rejected(camera):
    """A hexagon with one vertex pulled 100 px out is no view of a regular hexagon: every solver is rejected."""
    model = model_for('hexagon', SIDE)
    px = np.array([[300.0, 200.0], [340.0, 200.0], [360.0, 220.0], [340.0, 240.0], [300.0, 240.0], [200.0, 220.0]])
    with pytest.raises(PoseEstimationError, match=r'sqp: .*ippe: .*sqpnp: residual .* px exceeds'):
        estimate_pose(px, camera, model)


# ----------------------------------------------------------------------------------------- noise
def test_noise_sqp_depth_and_table_prior(camera):
    """40 mm square straight on at 161 mm, 0.5 px noise, 200 samples (the thesis's depth experiment)."""
    model = model_for('square', SIDE)
    rng = np.random.default_rng(15)
    depth_error = {'sqp': [], 'ippe': []}
    rotation_errors = {'sqp': [], 'sqp+plane': []}
    for _ in range(200):
        T = straight_on_pose(rng)
        px = observe(T, camera, model, rng, sigma_px=0.5)
        plane = table_plane_for(T, model, tilt_error=math.radians(1.0), rng=rng)   # FK normal good to ~1 degree
        for method in depth_error:
            estimate = estimate_pose(px, camera, model, method=method)
            depth_error[method].append(abs(estimate.depth_m - T[2, 3]))
            if method == 'sqp':
                rotation_errors['sqp'].append(rotation_error(estimate.T_camera_object[:3, :3], T[:3, :3], 4))
        with_plane = estimate_pose(px, camera, model, table_plane=plane)
        rotation_errors['sqp+plane'].append(rotation_error(with_plane.T_camera_object[:3, :3], T[:3, :3], 4))
        for covariance in (estimate.covariance, with_plane.covariance):
            np.testing.assert_allclose(covariance, covariance.T, rtol=1e-9, atol=1e-15)
            assert np.all(np.linalg.eigvalsh(covariance) > 0)
        # the prior shrinks the predicted tilt uncertainty (rotation about the camera's x and y axes)
        assert np.all(np.diag(with_plane.covariance)[3:5] < pose.TABLE_NORMAL_SIGMA_RAD ** 2)
        assert np.trace(with_plane.covariance[3:5, 3:5]) < 0.5 * np.trace(estimate.covariance[3:5, 3:5])
    mean_depth = {method: np.mean(errors) for method, errors in depth_error.items()}
    assert mean_depth['sqp'] <= mean_depth['ippe']
    assert mean_depth['sqp'] < 1e-3
    assert np.mean(rotation_errors['sqp+plane']) < 0.5 * np.mean(rotation_errors['sqp'])
    assert np.max(rotation_errors['sqp+plane']) < math.radians(5)


def test_covariance_matches_monte_carlo_spread(camera):
    """Predicted standard deviations agree with the spread over noisy repetitions (tilted 20 deg, 0.5 px)."""
    model = model_for('square', SIDE)
    T = np.eye(4)
    T[:3, :3] = (Rotation.from_euler('x', math.pi) * Rotation.from_euler('y', math.radians(20))
                 * Rotation.from_euler('z', 0.3)).as_matrix()
    T[:3, 3] = [0.01, 0.02, 0.2]
    rng = np.random.default_rng(16)
    positions, predicted = [], []
    for _ in range(300):
        estimate = estimate_pose(observe(T, camera, model, rng, sigma_px=0.5), camera, model)
        positions.append(estimate.position_m)
        predicted.append(np.sqrt(np.diag(estimate.covariance)[:3]))
    ratio = np.std(positions, axis=0) / np.median(predicted, axis=0)
    assert np.all((ratio > 0.6) & (ratio < 1.6)), ratio


# The README's perception benchmark ("Perception", make bench-perception) measured on rendered 40 mm squares:
# vertex error 0.084 px (green40) and 0.059 px (depth161), mean distance per vertex. Gaussian noise of
# sigma = mean / sqrt(pi / 2) per coordinate gives the estimator those vertex errors.
GREEN40_SIGMA_PX = 0.084 / math.sqrt(math.pi / 2)
DEPTH161_SIGMA_PX = 0.059 / math.sqrt(math.pi / 2)


def errors_mm_deg(samples, camera, model, method, use_plane):
    """(position errors mm, rotation errors deg, depth errors mm) over ``samples`` = [(T_camera_object, px)]."""
    position, rotation, depth = [], [], []
    for T, px in samples:
        plane = table_plane_for(T, model) if use_plane else None
        estimate = estimate_pose(px, camera, model, method=method, table_plane=plane)
        position.append(1e3 * np.linalg.norm(estimate.position_m - T[:3, 3]))
        rotation.append(math.degrees(rotation_error(estimate.T_camera_object[:3, :3], T[:3, :3], model.n)))
        depth.append(1e3 * (estimate.depth_m - T[2, 3]))
    return np.array(position), np.array(rotation), np.array(depth)


def test_accuracy_of_40_mm_squares_at_the_detectors_vertex_error(camera):
    """README green40 (100 random views 0.10-0.40 m, tilt up to 35 deg, 0.084 px vertex error): SQP position
    median 0.15 mm, p90 1.00 mm (targets 1 and 3 mm), orientation p90 0.86 deg; with the table plane p90
    0.82 mm and 0.27 deg, 4x better in orientation than IPPE. Bounds: the README's numbers; the median gets
    0.1 mm more (i.i.d. Gaussian noise is not the detector's error; 0.12-0.17 mm over three seeds)."""
    model = model_for('square', SIDE)
    rng = np.random.default_rng(17)
    frames = [(T, observe(T, camera, model, rng, sigma_px=GREEN40_SIGMA_PX))
              for T in (random_pose(rng, camera, model) for _ in range(100))]
    position, rotation, _ = errors_mm_deg(frames, camera, model, 'sqp', use_plane=False)
    assert np.median(position) < 0.25 and np.percentile(position, 90) < 1.0
    assert np.percentile(rotation, 90) < 0.86
    position, rotation_plane, _ = errors_mm_deg(frames, camera, model, 'sqp', use_plane=True)
    assert np.percentile(position, 90) < 0.82 and np.percentile(rotation_plane, 90) < 0.27
    _, rotation_ippe, _ = errors_mm_deg(frames, camera, model, 'ippe', use_plane=False)
    assert np.percentile(rotation_plane, 90) < np.percentile(rotation_ippe, 90) / 3      # README: 4x (5x measured)


def test_depth_straight_on_at_161_mm_at_the_detectors_vertex_error(camera):
    """README depth161 (56 views of a 40 mm square straight on at 161 mm, 0.059 px vertex error): SQP mean |dZ|
    0.06 mm (target 0.5 mm), orientation p90 0.56 deg vs IPPE's 2.07, 0.12 deg with the plane. Bounds: those
    numbers plus 0.04 mm / 0.04 deg for the 56-sample spread (0.03-0.04 mm, 0.48-0.50 deg over three seeds)."""
    model = model_for('square', SIDE)
    rng = np.random.default_rng(18)
    samples = [(T, observe(T, camera, model, rng, sigma_px=DEPTH161_SIGMA_PX))
               for T in (straight_on_pose(rng) for _ in range(56))]
    _, rotation, depth = errors_mm_deg(samples, camera, model, 'sqp', use_plane=False)
    assert np.mean(np.abs(depth)) < 0.1
    assert np.percentile(rotation, 90) < 0.6
    _, rotation_plane, _ = errors_mm_deg(samples, camera, model, 'sqp', use_plane=True)
    assert np.percentile(rotation_plane, 90) < 0.16
    _, rotation_ippe, _ = errors_mm_deg(samples, camera, model, 'ippe', use_plane=False)
    assert np.percentile(rotation, 90) < np.percentile(rotation_ippe, 90) / 2        # README: 3.7x


def test_report_speed_and_depth_error(camera):
    """Median CPU time per call (run with -s to see) and depth error vs vertex noise: the error grows with the
    noise, and SQP (0.5 px noise) stays within 10 ms: a guard against a gross slowdown, not the README's number
    (3 ms per frame for vision + SQP, about 0.8 ms for SQP alone, measured by make bench-perception on a quiet
    machine). CPU time of this process, the fastest of three repetitions, not wall time; still, on this shared
    virtual machine it includes the load: 1.8-3.4 ms per SQP call measured at load averages of 3-7 on 2 cores."""
    model = model_for('square', SIDE)
    rng = np.random.default_rng(17)
    frames = [(T, observe(T, camera, model, rng, sigma_px=0.5))
              for T in (random_pose(rng, camera, model) for _ in range(100))]
    lines, cpu_ms = [], {}
    for method in pose.METHODS:
        for use_plane in (False, True):
            repetitions = []          # SQP's fastest of three: what the estimator costs, not what the load adds
            for _ in range(3 if method == 'sqp' else 1):
                start = time.process_time()
                for T, px in frames:
                    estimate_pose(px, camera, model, method=method,
                                  table_plane=table_plane_for(T, model) if use_plane else None)
                repetitions.append(1e3 * (time.process_time() - start) / len(frames))
            cpu_ms[method, use_plane] = min(repetitions)
            lines.append(f'{method}{" +plane" if use_plane else ""}: {cpu_ms[method, use_plane]:.3f} ms CPU per call')
    errors = {}
    for sigma in (0.1, 0.3, 0.5):
        for method in pose.METHODS:
            rng = np.random.default_rng(18)
            poses = [straight_on_pose(rng) for _ in range(100)]
            samples = [(T, observe(T, camera, model, rng, sigma_px=sigma)) for T in poses]
            errors[sigma, method] = np.mean([abs(estimate_pose(px, camera, model, method=method).depth_m - T[2, 3])
                                             for T, px in samples])
            lines.append(f'40 mm square straight on at 161 mm, sigma {sigma} px, {method}: '
                         f'depth MAE {1e3 * errors[sigma, method]:.3f} mm')
    print('\n' + '\n'.join(lines))
    for method in pose.METHODS:
        assert errors[0.1, method] < errors[0.3, method] < errors[0.5, method]
    assert max(cpu_ms['sqp', False], cpu_ms['sqp', True]) < 10.0
