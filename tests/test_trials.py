"""Batch-trials runner (baxter_pnp.sim.trials): random scenes, ground-truth scoring, summary; one real trial."""
import math

import cv2
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from baxter_pnp.sim import trials
from baxter_pnp.models import model_for
from baxter_pnp.sim.launcher import RosMaster, free_port, run_script
from baxter_pnp.sim.scene import Scene, Table
from baxter_pnp.sim.world import SimWorld
from baxter_pnp.transforms import invert, make_transform, transform_points

GREEN = tuple(trials.COLOURS_RGB['green'])


def projected_top_face(obj, start_pose, top_z=-0.15):
    """Distorted pixels of a scene object's top-face vertices, via OpenCV (independent of CameraModel.project)."""
    T_base_camera, _, camera, _ = trials.start_view(start_pose)
    T_base_block = make_transform(Rotation.from_euler('z', obj['yaw']), (*obj['xy'], top_z + obj['height']))
    points_camera = transform_points(invert(T_base_camera) @ T_base_block,
                                     model_for(obj['shape'], obj['side'], obj['height']).vertices)
    pixels, _ = cv2.projectPoints(points_camera, np.zeros(3), np.zeros(3), camera.K, camera.D)
    return pixels.reshape(-1, 2), points_camera[:, 2], camera


@pytest.mark.parametrize('start_pose', ['down', 'angled'])
def test_random_scenes_put_a_pickable_green_square_in_view_with_distant_distractors(start_pose):
    sides, positions = [], []
    for seed in range(12):
        scene = trials.random_scene(np.random.default_rng(seed), start_pose, distractors=2)
        parsed = Scene.from_dict(scene)
        assert parsed.start == start_pose and len(parsed.objects) == 3
        target = scene['objects'][0]
        assert (target['shape'], tuple(target['color'])) == ('square', GREEN)
        for obj in scene['objects']:
            assert 0.03 <= obj['side'] <= 0.05
            assert -math.pi <= obj['yaw'] <= math.pi
            pixels, depths, camera = projected_top_face(obj, start_pose)
            assert np.all(depths > 0)
            assert np.all(pixels >= 19.9) and np.all(pixels <= [camera.width - 20.9, camera.height - 20.9])
        for obj in scene['objects'][1:]:
            assert (obj['shape'], tuple(obj['color'])) != ('square', GREEN)
        centres = np.array([obj['xy'] for obj in scene['objects']])
        gaps = np.linalg.norm(centres[:, None] - centres[None], axis=2)[np.triu_indices(3, 1)]
        assert np.all(gaps >= trials.DISTRACTOR_MIN_DISTANCE)
        sides.append(target['side'])
        positions.append(target['xy'])
    assert np.ptp(sides) > 0.01                              # sizes spread over the range
    assert np.all(np.ptp(positions, axis=0) > 0.1)           # positions spread over the view
    again = trials.random_scene(np.random.default_rng(3), start_pose, distractors=2)
    assert again == trials.random_scene(np.random.default_rng(3), start_pose, distractors=2)


def table_point_seen_at(pixel, start_pose, plane_z=-0.13):
    """Base (x, y) of the table-top point (plane z = ``plane_z``) seen at a distorted ``pixel`` from a start pose."""
    T_base_camera, _, camera, _ = trials.start_view(start_pose)
    ray = T_base_camera[:3, :3] @ np.append(camera.undistort_points(np.array([pixel], float))[0], 1.0)
    return (T_base_camera[:3, 3] + ray * (plane_z - T_base_camera[2, 3]) / ray[2])[:2]


def test_view_and_reach_checks_reject_what_the_arm_cannot_see_or_reach():
    T_base_camera, _, camera, _ = trials.start_view('down')
    clearance = trials.hand_clearance_px('down')
    model = model_for('square', 0.04)

    def visible(xy):
        return trials.top_face_in_view(trials.block_pose(xy, 0.3, -0.15), model, T_base_camera, camera, 20, clearance)
    assert clearance.shape == (400, 640) and 0.03 < np.mean(clearance == 0) < 0.2     # the fingers hide the top
    centre = table_point_seen_at((320, 250), 'down')
    assert visible(centre) and trials.pickable(trials.block_pose(centre, 0.3, -0.15), 0.04, 'down')
    assert not visible(table_point_seen_at((320, 420), 'down'))        # beyond the bottom border
    assert not visible(table_point_seen_at((245, 70), 'down'))         # behind a finger
    far = trials.block_pose((1.15, -0.6), 0.0, -0.15)                  # on the table, out of reach
    assert trials.on_table(far, model, Table()) and not trials.pickable(far, 0.04, 'angled')


@pytest.mark.parametrize('start_pose', ['down', 'angled'])
def test_the_fake_renders_the_random_target_unoccluded_where_it_is_projected(start_pose):
    for seed in range(3):
        scene = trials.random_scene(np.random.default_rng(seed), start_pose, distractors=2)
        world = SimWorld(Scene.from_dict(scene))
        world.command_gripper('left', 100.0, velocity_percent=100.0)      # as the application's first look
        world.step(240)
        _, _, camera, _ = trials.start_view(start_pose)
        image = world.render_camera('left_hand_camera', camera, np.random.default_rng(seed)).astype(int)
        green = (image[:, :, 1] > image[:, :, 0] + 40) & (image[:, :, 1] > image[:, :, 2] + 40)
        pixels, _, _ = projected_top_face(scene['objects'][0], start_pose)
        face = np.zeros(green.shape, np.uint8)
        cv2.fillPoly(face, [np.round(pixels).astype(np.int32)], 1)
        assert np.mean(green[face > 0]) > 0.95, (start_pose, seed)    # the whole top face is seen, nothing hides it


def test_score_measures_the_lift_and_the_centring_in_the_gripper_frame():
    scene = {'table': {'top_z': -0.15}, 'objects': [{'side': 0.04, 'height': 0.02}]}
    R_down = Rotation.from_euler('xyz', [math.pi, 0.0, 0.7])      # fingers pointing down, yawed 0.7 rad
    T_base_gripper = make_transform(R_down, (0.6, 0.3, 0.0))
    offset_gripper = np.array([0.002, -0.0015, -0.012])          # block centre in the gripper frame (m)
    T_base_block = make_transform(Rotation.from_euler('z', 0.2), T_base_gripper[:3, :3] @ offset_gripper
                                  + T_base_gripper[:3, 3])
    scores = trials.score(scene, T_base_block, T_base_gripper, T_base_block, T_base_gripper)
    assert scores['lifted'] and scores['rise_mm'] == pytest.approx(142.0)    # z = 0 + 12 mm (gripper z is down)
    assert scores['centring_x_mm'] == pytest.approx(2.0) and scores['centring_y_mm'] == pytest.approx(-1.5)
    assert scores['centring_mm'] == pytest.approx(2.5) and scores['pre_close_offset_mm'] == pytest.approx(2.5)
    low = T_base_block.copy()
    low[2, 3] = -0.13 + 0.049
    assert not trials.score(scene, low, T_base_gripper)['lifted']


def test_pre_close_sample_is_the_last_one_before_the_first_close():
    T = np.eye(4)
    positions = [0.0, 40.0, 100.0, 100.0, 99.0, 97.0, 93.0, 93.0, 100.0, 50.0]    # calibrate, open, close, ...
    samples = [trials.GroundTruthSample(0.1 * k, T * k, T, p) for k, p in enumerate(positions)]
    assert trials.pre_close_sample(samples) is samples[4]      # 97 is the first point more than 2 below 100
    assert trials.pre_close_sample(samples[:5]) is None
    assert trials.pre_close_sample(samples[:2]) is None          # calibrating is not closing


def test_summary_counts_verified_picks_and_labels_failures(tmp_path):
    def row(mode, verified, app_success=True, reason=None, centring=1.0, time_s=10.0, timed_out=False):
        return {'mode': mode, 'start_pose': 'angled' if time_s > 20 else 'down', 'verified': verified,
                'app_success': app_success, 'failure_reason': reason,
                'centring_mm': centring if verified else None, 'pre_close_offset_mm': 1.0, 'time_s': time_s,
                'wall_s': 20.0, 'timed_out': timed_out}
    rows = [row('pbvs', True, centring=c, time_s=t) for c, t in [(1.0, 8.0), (2.0, 9.0), (3.0, 10.0), (4.0, 30.0)]]
    rows += [row('pbvs', False, app_success=False, reason='block_lost'), row('pbvs', False),
             row('ibvs', False, app_success=None, reason='fake did not start'),
             row('ibvs', False, app_success=None, timed_out=True)]
    summary = trials.summarise(rows)
    assert list(summary) == ['pbvs', 'ibvs']
    pbvs = summary['pbvs']
    assert (pbvs['trials'], pbvs['verified']) == (6, 4) and pbvs['success_pct'] == pytest.approx(200 / 3)
    assert pbvs['centring_median_mm'] == pytest.approx(2.5) and pbvs['time_median_s'] == pytest.approx(9.5)
    assert pbvs['time_p90_s'] == pytest.approx(np.percentile([8, 9, 10, 30], 90))
    assert pbvs['failures'] == {'block_lost': 1, 'not_lifted': 1}
    assert summary['ibvs']['failures'] == {'crashed': 1, 'wall_timeout': 1}
    assert summary['ibvs']['centring_median_mm'] is None
    table = trials.format_table(summary)
    assert '| pbvs | 4/6 (67 %) | 2.5 / 3.7 |' in table and 'n/a' in table
    by_pose = trials.summarise(rows, by_start_pose=True)
    assert (by_pose['pbvs down']['trials'], by_pose['pbvs angled']['verified']) == (5, 1)
    trials.write_csv(rows, tmp_path / 'trials.csv')
    assert trials.summarise(trials.read_csv(tmp_path / 'trials.csv')) == summary


def test_one_real_pbvs_trial_is_a_verified_pick(ros_node, ros_master, tmp_path):
    scene = trials.random_scene(np.random.default_rng(7), 'down')
    row = trials.run_trial(ros_master, scene, 'pbvs', 'down', 0.35, str(tmp_path / 'trial'), timeout=150.0, seed=7)
    assert (row['returncode'], row['app_success'], row['failure_reason']) == (0, True, None), row
    assert row['lifted'] and row['rise_mm'] > 50.0 and row['verified']
    assert row['centring_mm'] < 5.0, row
    assert 0.0 < row['time_s'] < 30.0 and row['steps'] > 0
    assert (tmp_path / 'trial' / 'pick.log').exists() and (tmp_path / 'trial' / 'errors.png').exists()


def test_run_script_captures_the_log_and_interrupts_a_script_that_overruns(tmp_path):
    script = tmp_path / 'slow.py'
    script.write_text('import os, sys, time\nprint("master", os.environ["ROS_MASTER_URI"], sys.argv[1:])\n'
                      'time.sleep(float(sys.argv[1]))\n')
    master = RosMaster(port=free_port())          # not started: run_script only uses its environment
    quick = run_script(master, str(script), [0.1], timeout=20.0, log_path=tmp_path / 'quick.log')
    assert (quick.returncode, quick.timed_out) == (0, False)
    assert f"master {master.uri} ['0.1']" in quick.log()
    slow = run_script(master, str(script), [60], timeout=1.0, log_path=tmp_path / 'slow.log')
    assert slow.timed_out and slow.returncode != 0 and slow.wall_seconds < 10.0
