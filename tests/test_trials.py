"""Batch-trials runner (baxter_pnp.bench: trials, trial_scenes, ground_truth, soak): random scenes,
ground-truth scoring, summary, the soak's pure parts; one real trial and a two-cycle soak."""
import collections
import json
import math
import os

import cv2
import numpy as np
import pytest
import yaml
from scipy.spatial.transform import Rotation

from baxter_pnp.bench import ground_truth, soak, trial_scenes, trials
from baxter_pnp.models import model_for
from baxter_pnp.runtime import PACKAGE_ROOT
from baxter_pnp.sim.appearance import AppearanceConfig, expand
from baxter_pnp.sim.launcher import RosMaster, free_port, run_script
from baxter_pnp.sim.scene import Scene, SceneError, Table
from baxter_pnp.sim.world import SimWorld
from baxter_pnp.transforms import invert, make_transform, transform_points

GREEN = tuple(trial_scenes.COLOURS_RGB['green'])


def projected_top_face(obj, start_pose, top_z=-0.15):
    """Distorted pixels of a scene object's top-face vertices, via OpenCV (independent of CameraModel.project)."""
    T_base_camera, _, camera, _ = trial_scenes.start_view(start_pose)
    T_base_block = make_transform(Rotation.from_euler('z', obj['yaw']), (*obj['xy'], top_z + obj['height']))
    points_camera = transform_points(invert(T_base_camera) @ T_base_block,
                                     model_for(obj['shape'], obj['side'], obj['height']).vertices)
    pixels, _ = cv2.projectPoints(points_camera, np.zeros(3), np.zeros(3), camera.K, camera.D)
    return pixels.reshape(-1, 2), points_camera[:, 2], camera


@pytest.mark.parametrize('start_pose', ['down', 'angled'])
def test_random_scenes_put_a_pickable_green_square_in_view_with_distant_distractors(start_pose):
    sides, positions = [], []
    for seed in range(12):
        scene = trial_scenes.random_scene(np.random.default_rng(seed), start_pose, distractors=2)
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
        assert np.all(gaps >= trial_scenes.DISTRACTOR_MIN_DISTANCE)
        sides.append(target['side'])
        positions.append(target['xy'])
    assert np.ptp(sides) > 0.01                              # sizes spread over the range
    assert np.all(np.ptp(positions, axis=0) > 0.1)           # positions spread over the view
    again = trial_scenes.random_scene(np.random.default_rng(3), start_pose, distractors=2)
    assert again == trial_scenes.random_scene(np.random.default_rng(3), start_pose, distractors=2)


def test_pick_and_place_scenes_keep_every_block_off_the_place_position():
    """With ``--place`` no block stands where the application would take it for one already placed (within two
    sides of the place position: seed 21 down 4 of the place batch put the target 2.2 cm from it, and the
    application, rightly, never picked it)."""
    place, found_near = (0.62, 0.12), False
    for seed in range(40):
        free = trial_scenes.random_scene(np.random.default_rng(seed), 'down', distractors=1)
        found_near |= any(np.hypot(*np.subtract(o['xy'], place)) < 2 * o['side'] for o in free['objects'])
        scene = trial_scenes.random_scene(np.random.default_rng(seed), 'down', distractors=1, place_xy=place)
        for obj in scene['objects']:
            assert np.hypot(*np.subtract(obj['xy'], place)) >= trial_scenes.PLACE_CLEARANCE >= 2 * obj['side']
    assert found_near                                     # without the place position, blocks land there


def table_point_seen_at(pixel, start_pose, plane_z=-0.13):
    """Base (x, y) of the table-top point (plane z = ``plane_z``) seen at a distorted ``pixel`` from a start pose."""
    T_base_camera, _, camera, _ = trial_scenes.start_view(start_pose)
    ray = T_base_camera[:3, :3] @ np.append(camera.undistort_points(np.array([pixel], float))[0], 1.0)
    return (T_base_camera[:3, 3] + ray * (plane_z - T_base_camera[2, 3]) / ray[2])[:2]


def test_view_and_reach_checks_reject_what_the_arm_cannot_see_or_reach():
    T_base_camera, _, camera, _ = trial_scenes.start_view('down')
    clearance = trial_scenes.rendered_hand_clearance_px('down')
    model = model_for('square', 0.04)

    def visible(xy):
        return trial_scenes.top_face_in_view(trial_scenes.block_pose(xy, 0.3, -0.15), model, T_base_camera, camera,
                                             20, clearance)
    assert clearance.shape == (400, 640) and 0.03 < np.mean(clearance == 0) < 0.2     # the fingers hide the top
    centre = table_point_seen_at((320, 250), 'down')
    assert visible(centre) and trial_scenes.pickable(trial_scenes.block_pose(centre, 0.3, -0.15), 0.04, 'down')
    assert not visible(table_point_seen_at((320, 420), 'down'))        # beyond the bottom border
    assert not visible(table_point_seen_at((245, 70), 'down'))         # behind a finger
    far = trial_scenes.block_pose((1.15, -0.6), 0.0, -0.15)                  # on the table, out of reach
    assert trial_scenes.on_table(far, model, Table()) and not trial_scenes.pickable(far, 0.04, 'angled')


@pytest.mark.parametrize('start_pose', ['down', 'angled'])
def test_the_fake_renders_the_random_target_unoccluded_where_it_is_projected(start_pose):
    for seed in range(3):
        scene = trial_scenes.random_scene(np.random.default_rng(seed), start_pose, distractors=2)
        world = SimWorld(Scene.from_dict(scene))
        world.command_gripper('left', 100.0, velocity_percent=100.0)      # as the application's first look
        world.step(240)
        _, _, camera, _ = trial_scenes.start_view(start_pose)
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
    samples = [ground_truth.GroundTruthSample(0.1 * k, T * k, T, p) for k, p in enumerate(positions)]
    assert ground_truth.pre_close_sample(samples) is samples[4]      # 97 is the first point more than 2 below 100
    assert ground_truth.pre_close_sample(samples[:5]) is None
    assert ground_truth.pre_close_sample(samples[:2]) is None          # calibrating is not closing


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
    scene = trial_scenes.random_scene(np.random.default_rng(7), 'down')
    # at 1x: the time to grasp is then a robot's (unpaced, the application's computing counts at the fake's 2-5x)
    row = trials.run_trial(ros_master, scene, 'pbvs', 'down', 0.35, str(tmp_path / 'trial'), timeout=150.0, seed=7,
                           real_time_factor=1.0)
    assert (row['returncode'], row['app_success'], row['failure_reason']) == (0, True, None), row
    # the app lifts 10 cm (lift_height); 5 mm of margin for the block settling in the fingers
    assert row['lifted'] and row['verified'] and row['rise_mm'] == pytest.approx(100.0, abs=5.0), row
    # README: centring 0.2-0.3 mm median, p90 0.5 mm over the trial batches; 2 mm leaves room for noise
    assert row['centring_mm'] < 2.0, row
    # README: PBVS time to grasp 6.8 s median, 9.9 s p90 (robot time); target <= 15 s
    assert 0.0 < row['time_s'] < 15.0 and row['steps'] > 0, row
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


# ============================================================================================ faults, distractors
def test_same_colour_distractor_and_faults_go_into_the_scene(tmp_path):
    faults = trial_scenes.load_faults_mapping(os.path.join(PACKAGE_ROOT, 'config', 'faults_batch.yaml'))
    assert faults == {'camera': {'drop_probability': 0.2, 'latency': 0.1}}
    for seed in range(6):
        scene = trial_scenes.random_scene(np.random.default_rng(seed), 'down', distractors=1,
                                          same_colour_distractor=True, faults=faults)
        parsed = Scene.from_dict(scene)
        assert (parsed.faults.camera.drop_probability, parsed.faults.camera.latency) == (0.2, 0.1)
        assert len(scene['objects']) == 3 and scene['objects'][0]['shape'] == 'square'
        same = [o for o in scene['objects'][1:] if tuple(o['color']) == GREEN]
        assert len(same) == 1 and same[0]['shape'] in ('triangle', 'pentagon', 'hexagon'), scene['objects']
        pixels, depths, camera = projected_top_face(same[0], 'down')
        assert np.all(depths > 0) and np.all(pixels >= 19.9)
    clean = trial_scenes.random_scene(np.random.default_rng(seed), 'down', distractors=1)
    assert 'faults' not in clean and Scene.from_dict(clean).faults.summary() == 'none'
    assert clean['objects'] == scene['objects'][:2]          # same seed: same scene, plus the extra block
    bad = tmp_path / 'bad.yaml'
    bad.write_text(yaml.safe_dump({'faults': {'camera': {'drop_probability': 1.5}}}))
    with pytest.raises(SceneError, match=r'faults.camera.drop_probability: must be a probability'):
        trial_scenes.load_faults_mapping(str(bad))


def test_rows_carry_their_conditions_and_are_summarised_per_condition(tmp_path, capsys):
    def row(verified, faults, same=False, mode='pbvs'):
        return {'mode': mode, 'start_pose': 'down', 'verified': verified, 'app_success': verified,
                'failure_reason': None if verified else 'block_lost', 'centring_mm': 1.0 if verified else None,
                'centring_x_mm': 1.0 if verified else None, 'centring_y_mm': 0.0 if verified else None,
                'pre_close_offset_mm': 1.0, 'time_s': 8.0, 'wall_s': 20.0, 'timed_out': False,
                'distractors': 1 if same else 0, 'same_colour_distractor': same, 'faults': faults}
    faulty = 'camera.drop_probability=0.2, camera.latency=0.1'
    clean_rows = [row(True, 'none'), row(True, 'none')]
    faulty_rows = [row(True, faulty, True), row(False, faulty, True), row(False, faulty, True)]
    trials.write_csv(clean_rows, tmp_path / 'clean.csv')
    trials.write_csv(faulty_rows, tmp_path / 'faulty.csv')
    merged = trials.read_csv(tmp_path / 'clean.csv') + trials.read_csv(tmp_path / 'faulty.csv')
    assert merged[2]['faults'] == faulty and merged[2]['same_colour_distractor'] is True
    summary = trials.summarise(merged, by_condition=True)
    assert list(summary) == ['pbvs [faults: none; distractors: 0]',
                             f"pbvs [faults: {faulty}; distractors: 1 (1 of the target's colour)]"]
    assert [(s['trials'], s['verified']) for s in summary.values()] == [(2, 2), (3, 1)]
    assert trials.summarise(merged)['pbvs']['trials'] == 5
    old = {k: v for k, v in row(True, None).items() if k not in ('faults', 'same_colour_distractor')}
    assert trials.condition(old) == 'faults: none; distractors: 0'       # a CSV from before the columns
    trials.report(merged, str(tmp_path), 'test')
    printed = capsys.readouterr().out
    assert f'pbvs [faults: {faulty}; distractors: 1' in printed and '| 1/3 (33 %)' in printed
    with open(tmp_path / 'summary.json') as f:
        assert len(json.load(f)['per_mode_and_condition']) == 2



def test_appearance_option_puts_a_look_per_seed_into_the_scene_and_the_records(tmp_path):
    args = trials.parse_args(['--appearance', 'random'])
    assert args.appearance == 'random' and trials.parse_args([]).appearance == 'baxter'      # the fake's default
    for bad in (['--appearance', 'sunny'], ['--soak', '3', '--appearance', 'random']):
        with pytest.raises(SystemExit):
            trials.parse_args(bad)
    scenes = {seed: trial_scenes.random_scene(np.random.default_rng(seed), 'down',
                                              appearance=trial_scenes.trial_appearance(args.appearance, seed))
              for seed in (11, 12)}
    for seed, scene in scenes.items():
        loaded = yaml.safe_load(yaml.safe_dump(scene, default_flow_style=None, sort_keys=False))   # as run_trial
        assert isinstance(loaded['appearance'], dict) and 'exposure' in loaded['appearance']
        assert Scene.from_dict(loaded).appearance == AppearanceConfig.from_dict(expand(loaded['appearance']))
        assert loaded['appearance'] == trial_scenes.trial_appearance('random', seed)     # the seed fixes the look
    assert scenes[11]['appearance'] != scenes[12]['appearance']
    clean = trial_scenes.random_scene(np.random.default_rng(11), 'down',
                                      appearance=trial_scenes.trial_appearance('clean', 11))
    assert clean['appearance'] == 'clean' and clean['objects'] == scenes[11]['objects']   # same placements
    assert trials.scene_conditions(clean)['appearance'] == 'clean'
    baxter = trial_scenes.random_scene(np.random.default_rng(11), 'down', appearance='baxter')
    assert trials.scene_conditions(baxter)['appearance'] == 'baxter'
    rows = []
    for k, scene in enumerate([scenes[11], scenes[12], clean]):
        rows.append({'mode': 'pbvs', 'start_pose': 'down', 'trial': k, 'verified': True, 'app_success': True,
                     'failure_reason': None, 'centring_mm': 1.0, 'centring_x_mm': 1.0, 'centring_y_mm': 0.0,
                     'pre_close_offset_mm': 1.0, 'time_s': 8.0, 'wall_s': 20.0, 'timed_out': False,
                     **trials.scene_conditions(scene)})
    assert rows[0]['appearance'] == 'random' and rows[0]['appearance_look'] != rows[1]['appearance_look']
    assert 'vignetting=%.3g' % scenes[11]['appearance']['vignetting'] in rows[0]['appearance_look']
    trials.write_csv(rows, tmp_path / 'trials.csv')
    again = trials.read_csv(tmp_path / 'trials.csv')
    assert [(r['appearance'], r['appearance_look']) for r in again] == [
        (r['appearance'], r['appearance_look']) for r in rows]
    assert list(trials.summarise(again, by_condition=True)) == [
        'pbvs [faults: none; distractors: 0; appearance: random]', 'pbvs [faults: none; distractors: 0]']
    trials.report(again, str(tmp_path), 'test')
    with open(tmp_path / 'summary.json') as f:
        assert json.load(f)['looks'] == {'down 0': rows[0]['appearance_look'], 'down 1': rows[1]['appearance_look']}


def test_random_looks_bring_random_clutter_kept_off_the_blocks_and_the_targets_approach():
    """``--appearance random`` scenes also hold clutter (chessboards, tape of any block colour, black and white cubes,
    cups), drawn from the trial's own stream: the same seed gives the same blocks as without it; clutter keeps
    ``CLUTTER_MARGIN`` from the blocks, cups ``CUP_CLEARANCE`` from the target; the rows count it apart from the
    distractors."""
    shapes, cups = collections.Counter(), 0
    for seed in range(30):
        plain = trial_scenes.random_scene(np.random.default_rng(seed), 'down', distractors=1,
                                          same_colour_distractor=True)
        scene = trial_scenes.random_scene(np.random.default_rng(seed), 'down', distractors=1,
                                          same_colour_distractor=True,
                                          clutter_rng=trial_scenes.trial_clutter_rng('random', seed))
        assert trial_scenes.trial_clutter_rng('baxter', seed) is None
        assert scene['objects'][:3] == plain['objects']
        clutter = scene['objects'][3:]
        conditions = trials.scene_conditions(scene)
        assert conditions['distractors'] == 2 and conditions['same_colour_distractor']
        assert conditions['clutter'] == len(clutter)
        parsed = Scene.from_dict(scene)
        things = list(parsed.boards) + list(parsed.props) + list(parsed.objects[3:])
        for thing in things:
            outline = thing.footprint()
            for k, block in enumerate(parsed.objects[:3]):
                gap = np.min(np.linalg.norm(outline - block.xy, axis=1))
                assert gap > 0.03 + trial_scenes.CLUTTER_MARGIN - 0.01, (seed, thing)
            if getattr(thing, 'shape', '') == 'cup':
                cups += 1
                assert np.linalg.norm(np.subtract(thing.xy, parsed.objects[0].xy)) >= \
                    thing.radius + trial_scenes.CUP_CLEARANCE
        shapes.update(entry['shape'] for entry in clutter)
        shapes.update('black or white cube' for entry in clutter if entry['shape'] == 'square')
    assert cups >= 5 and shapes['chessboard'] >= 5 and shapes['tape'] >= 10 and shapes['black or white cube'] >= 10


# ============================================================================================ soak (pure parts)
def test_soak_poses_are_pickable_in_view_and_away_from_the_place_position():
    place = soak.SOAK_PLACE_XY
    T_base_camera, _, camera, _ = trial_scenes.start_view('down')
    clearance = trial_scenes.rendered_hand_clearance_px('down')
    side, poses = soak.soak_poses(np.random.default_rng(4), 'down', 6, place)
    assert 0.03 <= side <= 0.05 and len(poses) == 6 and len(set(poses)) == 6
    model = model_for('square', side)
    for x, y, yaw in poses:
        assert np.hypot(x - place[0], y - place[1]) >= trial_scenes.PLACE_CLEARANCE
        T = trial_scenes.block_pose((x, y), yaw, -0.15)
        assert trial_scenes.top_face_in_view(T, model, T_base_camera, camera, 19.9, clearance)
        assert trial_scenes.pickable(T, side, 'down')
    assert soak.soak_poses(np.random.default_rng(4), 'down', 6, place) == (side, poses)
    near = soak.soak_poses(np.random.default_rng(4), 'down', 30, (0.62, 0.26))[1]    # mid-view place position
    assert min(np.hypot(x - 0.62, y - 0.26) for x, y, _ in near) >= trial_scenes.PLACE_CLEARANCE
    scene = Scene.from_dict(soak.soak_scene(side, poses, 'down', faults={'camera': {'latency': 0.1}}))
    (block,) = scene.objects
    assert (block.shape, block.color, block.side) == ('square', GREEN, round(side, 5))
    assert (block.xy, block.yaw) == (poses[0][:2], poses[0][2])
    assert scene.respawn.poses == tuple(poses[1:]) and scene.respawn.object == 0 and scene.respawn.delay == 2.0
    assert scene.faults.camera.latency == 0.1 and scene.start == 'down'
    with pytest.raises(ValueError, match='at least two poses'):
        soak.soak_scene(side, poses[:1], 'down')


STATUS = '''Name:\tpython
State:\tS (sleeping)
VmPeak:\t  812344 kB
VmRSS:\t  204800 kB
RssAnon:\t  150000 kB
Threads:\t12
'''


def fake_proc(root, processes):
    """A /proc-like tree: processes = {pid: (parent pid, comm, VmRSS kB or None)}."""
    for pid, (parent, comm, rss) in processes.items():
        d = root / str(pid)
        d.mkdir()
        (d / 'stat').write_text(f'{pid} ({comm}) S {parent} {pid} {pid} 0 -1 4194560 1 0 0 0 3 1 0 0 20 0 1 0\n')
        (d / 'comm').write_text(comm + '\n')
        (d / 'status').write_text(f'Name:\t{comm}\n' + ('' if rss is None else f'VmRSS:\t {rss} kB\n'))
    (root / 'self').mkdir()                                      # not a PID: ignored
    return str(root)


def test_memory_of_the_python_process_in_a_process_tree(tmp_path):
    assert soak.vm_rss_mib(STATUS) == 200.0
    assert soak.vm_rss_mib('Name:\tzombie\nState:\tZ (zombie)\n') is None
    proc = fake_proc(tmp_path, {
        100: (1, 'bash', 4096),                  # the launched wrapper
        101: (100, 'python3', 307200),           # the application's interpreter: 300 MiB
        102: (101, 'python3', 10240),            # a helper it started
        103: (101, 'sh', 900000),                # not Python
        200: (1, 'python3', 999999),             # not in the tree
        201: (200, 'python', None)})             # a zombie
    assert sorted(soak.process_tree(100, proc)) == [100, 101, 102, 103]
    assert soak.python_rss_mib(100, proc) == (101, 300.0)
    assert soak.python_rss_mib(102, proc) == (102, 10.0)
    assert soak.python_rss_mib(201, proc) == (None, None)
    assert soak.python_rss_mib(999, proc) == (None, None)       # gone


def test_soak_cycles_are_scored_by_the_lifts_in_their_window():
    rest_z = -0.13
    heights = [0, 0, 0.06, 0.1, 0.06, 0.0, 0.0, 0.04, 0.0, 0.0, 0.07, 0.08, 0.0, 0.0, 0.0]   # rise above rest (m)
    samples = [ground_truth.GroundTruthSample(float(t), make_transform(None, (0.6, 0.2, rest_z + h)), np.eye(4), 100.0)
               for t, h in enumerate(heights)]
    lifts = ground_truth.lift_times(samples, rest_z)
    assert lifts == [2.0, 10.0]                  # 4 cm is not a lift; each lift counted once, when it starts
    results = [{'success': True, 'time_s': 5.0, 'failure_reason': None},      # lifted at 2: verified
               {'success': True, 'time_s': 6.0, 'failure_reason': None},      # no lift in (6, 9]: not verified
               {'success': False, 'time_s': 7.0, 'failure_reason': 'grasp_missed'},   # lifted at 10, app failed
               {'success': True, 'time_s': 4.0, 'failure_reason': None}]      # no lift in (12, 14]: not verified
    rows = soak.score_cycles(results, [6.0, 9.0, 12.0, 14.0], lifts, start=1.0)
    assert [(r['cycle'], r['lifted'], r['verified']) for r in rows] == [
        (1, True, True), (2, False, False), (3, True, False), (4, False, False)]
    assert [r['cycle_sim_s'] for r in rows] == [5.0, 3.0, 3.0, 2.0]
    for row, (app, fake) in zip(rows, [(100.0, 150.0), (None, None), (104.0, 150.0), (110.0, 153.0)]):
        row.update(app_rss_mib=app, fake_rss_mib=fake)
    summary = soak.summarise_soak(rows, cycles=5)
    assert (summary['finished'], summary['app_successes'], summary['verified']) == (4, 3, 1)
    assert summary['app_success_pct'] == 60.0 and summary['verified_pct'] == 20.0
    assert summary['failures'] == {'not_lifted': 2, 'grasp_missed': 1, 'not_finished': 1}
    assert summary['time_to_grasp_median_s'] == 5.0 and summary['cycle_median_s'] == 3.0
    assert summary['app_memory'] == {'start_mib': 100.0, 'start_cycle': 1, 'end_mib': 110.0, 'end_cycle': 4,
                                     'growth_pct': pytest.approx(10.0)}
    assert summary['fake_memory']['growth_pct'] == pytest.approx(2.0)
    text = soak.format_soak(summary)
    assert 'app-reported successes 3/5 (60 %), verified by ground truth 1/5 (20 %)' in text
    assert '100 MiB after cycle 1 -> 110 MiB after cycle 4 (+10.0 %)' in text


def test_soak_options():
    args = trials.parse_args(['--soak', '5'])
    assert (args.mode, args.start_pose, args.place) == ('pbvs', 'down', list(soak.SOAK_PLACE_XY))
    args = trials.parse_args(['--soak', '5', '--mode', 'ibvs', '--start-pose', 'angled', '--place', '0.6,0.1'])
    assert (args.mode, args.start_pose, args.place) == ('ibvs', 'angled', [0.6, 0.1])
    assert (trials.parse_args([]).mode, trials.parse_args([]).start_pose, trials.parse_args([]).place) == (
        'all', 'both', None)
    for bad in (['--soak', '1'], ['--soak', '3', '--mode', 'all'], ['--soak', '3', '--distractors', '1'],
                ['--soak', '3', '--distractor-same-colour'], ['--place', '0.6']):
        with pytest.raises(SystemExit):
            trials.parse_args(bad)


def test_sizes_option_draws_the_blocks_sides_the_gripper_grips():
    assert trials.parse_args([]).sizes == trials.SIZE_RANGE_M
    args = trials.parse_args(['--sizes', '0.019,0.025'])
    assert args.sizes == (0.019, 0.025)
    for bad in (['--sizes', '0.016,0.025'], ['--sizes', '0.03,0.02'], ['--sizes', '0.03,0.07'], ['--sizes', 'big'],
                ['--task', 'sort', '--sizes', '0.02,0.03'], ['--soak', '3', '--sizes', '0.02,0.03']):
        with pytest.raises(SystemExit):
            trials.parse_args(bad)
    for seed in range(6):
        scene = trial_scenes.random_scene(np.random.default_rng(seed), 'down', size_range=args.sizes)
        assert 0.019 <= scene['objects'][0]['side'] <= 0.025


def test_a_two_cycle_soak_in_one_session(ros_node, ros_master, tmp_path):
    """``pick_square.py --cycles 2`` through the soak runner: both cycles verified by the ground truth, exit status 0
    (every cycle succeeded; ``tests/test_cycles.py`` has a failed cycle and exit status 1). An application that
    does not run (e.g. rejects ``--cycles``) fails here: it is not skipped."""
    rows, summary = soak.run_soak(ros_master, 2, 'pbvs', 'down', soak.SOAK_PLACE_XY, str(tmp_path), seed=0,
                                  timeout_per_cycle=150.0)
    assert (summary['returncode'], summary['timed_out']) == (0, False), summary
    assert [(r['app_success'], r['lifted'], r['verified']) for r in rows] == [(True, True, True)] * 2, rows
    assert summary['respawns'] >= 1                  # the first block was put back at the second pose
    assert rows[0]['respawns'] == 0 and rows[1]['respawns'] >= 1
    assert summary['app_memory']['start_mib'] > 50 and summary['fake_memory']['start_mib'] > 50
    for name in ('soak.csv', 'soak_memory.csv', 'soak_memory.png', 'ground_truth.csv', 'scene.yaml', 'pick.log'):
        assert (tmp_path / name).exists(), name
