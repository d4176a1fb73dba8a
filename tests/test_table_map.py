"""TableMap (baxter_pnp.table_map): fusion of block sightings across looks, pure."""
from types import SimpleNamespace

import numpy as np
from scipy.spatial.transform import Rotation

from baxter_pnp import table_map as tm
from baxter_pnp.camera import load_default_camera
from baxter_pnp.models import model_for
from baxter_pnp.pose import estimate_pose
from baxter_pnp.transforms import make_transform, transform_points


def block(x, y, yaw=0.0, z=-0.13):
    T = np.eye(4)
    T[:2, :2] = [[np.cos(yaw), -np.sin(yaw)], [np.sin(yaw), np.cos(yaw)]]
    T[:3, 3] = [x, y, z]
    return T


def test_two_views_of_one_block_fuse_into_one_with_smaller_uncertainty():
    m = tm.TableMap()
    a = m.add_look([tm.Sighting('square', 'red', block(0.60, 0.20), 0.004)], stamp=1.0, view_id=0)
    b = m.add_look([tm.Sighting('square', 'red', block(0.61, 0.20), 0.002)], stamp=2.0, view_id=1)
    assert a == b and len(m) == 1
    fused = m.blocks()[0]
    assert fused.views == 2 and fused.last_seen == 2.0 and fused.view_ids == [0, 1]
    assert fused.std < 0.002
    # inverse-variance weights 1/16 and 1/4: 0.60 * 0.2 + 0.61 * 0.8
    assert abs(fused.position[0] - 0.608) < 1e-9


def test_two_different_blocks_stay_two():
    m = tm.TableMap()
    m.add_look([tm.Sighting('square', 'red', block(0.60, 0.20), 0.003),
                tm.Sighting('square', 'red', block(0.60, 0.24), 0.003)], 1.0, 0)   # 4 cm apart, one look
    m.add_look([tm.Sighting('square', 'red', block(0.60, 0.35), 0.003),         # 11 cm away: a new block
                tm.Sighting('square', 'blue', block(0.60, 0.20), 0.003)], 2.0, 1)  # same place, other colour
    assert len(m) == 4
    assert sorted(b.views for b in m.blocks()) == [1, 1, 1, 1]


def test_hungarian_association_of_two_nearby_blocks():
    m = tm.TableMap()
    first = m.add_look([tm.Sighting('hexagon', 'green', block(0.60, 0.20), 0.003),
                        tm.Sighting('hexagon', 'green', block(0.60, 0.24), 0.003)], 1.0, 0)
    # seen again at 0.225 and 0.26: matching each sighting in turn to its nearest block would give the first
    # to the second block (1.5 cm vs 2.5 cm) and leave the other new; the assignment matches both (2.5 + 2 cm)
    again = m.add_look([tm.Sighting('hexagon', 'green', block(0.60, 0.225), 0.003),
                        tm.Sighting('hexagon', 'green', block(0.60, 0.26), 0.003)], 2.0, 1)
    assert again == first and len(m) == 2


def test_square_yaw_fused_modulo_90_degrees():
    m = tm.TableMap()
    m.add_look([tm.Sighting('square', 'red', block(0.6, 0.2, np.radians(44.0)), 0.003)], 1.0, 0)
    m.add_look([tm.Sighting('square', 'red', block(0.6, 0.2, np.radians(-44.0)), 0.003)], 2.0, 1)
    yaw = np.degrees(m.blocks()[0].yaw)
    # 44 and -44 deg are 2 deg apart modulo 90: the mean is +-45, not 0 (a plain mean would say 0)
    assert abs(abs(yaw) - 45.0) < 1e-6
    m2 = tm.TableMap()
    m2.add_look([tm.Sighting('triangle', 'red', block(0.6, 0.2, np.radians(10.0)), 0.003)], 1.0, 0)
    m2.add_look([tm.Sighting('triangle', 'red', block(0.6, 0.2, np.radians(130.0)), 0.003)], 2.0, 1)
    assert abs(np.degrees(m2.blocks()[0].yaw) - 10.0) < 1e-6      # 130 = 10 + 120: the same triangle pose


def test_json_round_trip_remove_and_moved():
    m = tm.TableMap()
    m.add_look([tm.Sighting('square', 'red', block(0.60, 0.20, 0.3), 0.004),
                tm.Sighting('pentagon', 'yellow', block(0.70, -0.10, -0.2), 0.005)], 1.0, 'a')
    m.add_look([tm.Sighting('square', 'red', block(0.605, 0.20, 0.31), 0.003)], 2.5, 'b')
    back = tm.TableMap.from_json(m.to_json())
    assert back.to_json() == m.to_json()
    for x, y in zip(m.blocks(), back.blocks()):
        np.testing.assert_allclose(x.T_base_block, y.T_base_block)
        assert (x.views, x.last_seen, x.view_ids, x.std) == (y.views, y.last_seen, y.view_ids, y.std)
    # the restored map keeps fusing and numbering as the original
    assert back.add_look([tm.Sighting('square', 'red', block(0.60, 0.20), 0.003)], 3.0, 'c') == [1]
    assert back.add_look([tm.Sighting('square', 'red', block(0.90, 0.20), 0.003)], 3.0, 'c') == [3]
    picked = back.remove(2)
    assert picked.shape == 'pentagon' and [b.id for b in back.blocks()] == [1, 3]
    placed = back.moved(1, tm.Sighting('square', 'red', block(0.5, 0.5, 0.1), 0.002), 4.0)
    assert placed.views == 1 and np.allclose(placed.position, [0.5, 0.5, -0.13]) and abs(placed.yaw - 0.1) < 1e-9
    assert back.add_look([tm.Sighting('square', 'red', block(0.51, 0.5), 0.002)], 5.0, 'd') == [1]


def test_uncertainty_model_and_gate():
    assert tm.check_track_radius()
    near, far = tm.sighting_std(0.4, 0.5, 400.0), tm.sighting_std(0.8, 0.5, 400.0)
    assert abs(far - 2 * near) < 1e-12 and abs(near - 0.4 * np.hypot(0.5, 1.0) / 400.0) < 1e-12
    assert tm.sighting_std(0.4, 3.0, 400.0) > near


def test_views_from_two_sides_cancel_each_others_depth_error():
    """Each view knows the block well across its ray and poorly along it (10 mm); fused in information form, the
    two rays' depth errors cancel: the map is within 1.5 mm of the truth and says so (an inverse-variance mean
    of the scalar stds would keep half of each 8 mm error and claim 7 mm)."""
    along_x, along_y = np.diag([0.010, 0.001, 0.001]) ** 2, np.diag([0.001, 0.010, 0.001]) ** 2
    m = tm.TableMap()
    m.add_look([tm.Sighting('square', 'red', block(0.608, 0.200), 0.010, along_x)], 1.0, 0)
    m.add_look([tm.Sighting('square', 'red', block(0.600, 0.192), 0.010, along_y)], 2.0, 1)
    fused = m.blocks()[0]
    assert np.linalg.norm(fused.position[:2] - [0.600, 0.200]) < 0.0015
    assert fused.std < 0.0015
    restored = tm.TableMap.from_json(m.to_json()).blocks()[0]
    np.testing.assert_allclose(restored.covariance, fused.covariance)


def test_a_far_sighting_reports_the_error_it_has():
    """A 33 mm square 0.55 m from the camera, seen 45 deg off its normal, its vertices with 0.5 px of noise: the
    sighting's std is the error's size (3D RMS over 200 draws within 0.75-1.5 of the median std); the lateral
    model alone (``sighting_std``) would claim a seventh of it."""
    camera, model = load_default_camera(), model_for('square', 0.033)
    rng = np.random.default_rng(3)
    T_base_camera = make_transform(Rotation.from_euler('x', 180, degrees=True).as_matrix(), [0.6, 0.1, 0.4])
    errors, stds, laterals = [], [], []
    for _ in range(200):
        R = Rotation.from_euler('xz', [np.radians(45.0), rng.uniform(0, 1.5)]).as_matrix()
        T_camera_block = make_transform(R, [0.03, 0.02, 0.55])
        pixels = camera.project(transform_points(T_camera_block, model.vertices)) + rng.normal(0, 0.5, (4, 2))
        pose = estimate_pose(pixels, camera, model)
        observation = SimpleNamespace(pose=pose, detection=SimpleNamespace(shape='square', colour='green'))
        sighting, = tm.sightings_from_look([observation], T_base_camera, camera)
        errors.append(sighting.T_base_block[:3, 3] - (T_base_camera @ T_camera_block)[:3, 3])
        stds.append(sighting.std)
        laterals.append(tm.sighting_std(0.55, pose.residual_px, camera.K[0, 0]))
    rms = np.sqrt((np.array(errors) ** 2).sum(axis=1).mean())
    assert 0.75 * np.median(stds) < rms < 1.5 * np.median(stds), (rms, np.median(stds))
    assert np.median(laterals) < 0.25 * rms
