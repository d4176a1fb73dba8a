"""table_task.py end to end (issue 14): survey, sort, stack and clear with a real rosmaster, the real fake Baxter and
the real application; judged on the fake's ground truth (``/fake_baxter/object_poses``: every block, scene order),
which only the tests read.
"""
import json

import numpy as np
import pytest
import rospy
import yaml
from geometry_msgs.msg import PoseArray

from baxter_pnp.sim.launcher import run_script
from baxter_pnp.transforms import pose_msg_to_matrix

TABLE_TOP_Z = -0.15
BLOCK_HEIGHT = 0.02
GREEN, RED, BLUE = [0.1, 0.7, 0.1], [0.8, 0.1, 0.1], [0.1, 0.2, 0.8]


def scene_file(tmp_path, *objects):
    """A scene YAML of 40 mm blocks ``(shape, rgb, (x, y), yaw)`` on the default table, start pose down."""
    scene = {'objects': [{'shape': shape, 'side': 0.04, 'height': BLOCK_HEIGHT, 'color': rgb, 'xy': list(xy),
                          'yaw': yaw} for shape, rgb, xy, yaw in objects], 'start': 'down'}
    path = tmp_path / 'scene.yaml'
    path.write_text(yaml.safe_dump(scene))
    return path


def ground_truth_blocks():
    """T_base_block of every block, scene order, from the fake's ground truth."""
    poses = rospy.wait_for_message('/fake_baxter/object_poses', PoseArray, timeout=10.0)
    return [pose_msg_to_matrix(p) for p in poses.poses]


def run_task(ros_master, tmp_path, name, *args):
    """table_task.py ARGS to completion (600 s wall at most): (ScriptRun, result dict or None, output dir)."""
    out = tmp_path / name
    run = run_script(ros_master, 'table_task.py', [*args, '--output-dir', out, '--result-json', out / 'task.json'],
                     timeout=600, log_path=tmp_path / ('%s.log' % name))
    assert not run.timed_out, run.log()[-3000:]
    result_path = out / 'task.json'
    return run, (json.loads(result_path.read_text()) if result_path.exists() else None), out


def standing(T_base_block, level=1):
    """True if the block stands upright with its top face on stack ``level``'s height (2 mm)."""
    return T_base_block[2, 2] > np.cos(np.radians(5)) and abs(
        T_base_block[2, 3] - (TABLE_TOP_Z + level * BLOCK_HEIGHT)) < 0.002


def test_sort_puts_the_named_blocks_in_their_bin_and_leaves_the_others(ros_master, ros_node, fake_baxter, tmp_path):
    """Two green squares into the green bin (a row from the bin, 8 cm apart, placed within 1.5 cm); a red square
    and a blue triangle (the distractor) untouched within 2 mm; every step verified, the map printed and
    written."""
    scene = scene_file(tmp_path, ('square', GREEN, (0.70, 0.25), 0.4), ('square', GREEN, (0.62, -0.15), -0.3),
                       ('square', RED, (0.75, 0.05), 0.1), ('triangle', BLUE, (0.60, 0.15), 0.2))
    fake = fake_baxter('--real-time-factor', '0', '--scene', scene)
    try:
        before = ground_truth_blocks()
        run, result, out = run_task(ros_master, tmp_path, 'sort', 'sort', '--bin', 'green:0.45,0.35')
        log = run.log()
        assert run.returncode == 0 and result['success'], log[-3000:]
        after = ground_truth_blocks()
        bin_slots = np.array([[0.45, 0.35], [0.45, 0.27]])
        greens = np.array([after[0][:2, 3], after[1][:2, 3]])
        placed = np.linalg.norm(greens[:, None] - bin_slots[None], axis=2).min(axis=1)
        assert np.all(placed < 0.015), placed
        assert np.linalg.norm(greens[0] - greens[1]) > 0.06, 'the sorted blocks touch'
        assert all(standing(T) for T in after)
        for k in (2, 3):        # the red square and the distractor did not move
            assert np.linalg.norm(after[k][:3, 3] - before[k][:3, 3]) < 0.002, k
        assert len(result['steps']) == 2 and all(s['verified'] and s['error_mm'] < 15 for s in result['steps'])
        assert result['disturbed'] == [] and result['not_in_place'] == []
        assert len(result['initial_map']) == 4 and len(result['final_map']) == 4
        saved = json.loads((out / 'table_map.json').read_text())
        assert sorted((b['colour'], b['shape']) for b in saved['blocks']) == [
            ('blue', 'triangle'), ('green', 'square'), ('green', 'square'), ('red', 'square')]
        assert json.loads((out / 'result.json').read_text())['success']
    finally:
        fake.stop()


def test_stack_builds_a_standing_tower(ros_master, ros_node, fake_baxter, tmp_path):
    """A red square already at the tower's place, a green and a blue one elsewhere: ``stack --order
    red,green,blue`` puts green on red and blue on green, each guided by a look at the block below; the tower
    stands, each block upright on its level and within 1 cm of the one below."""
    at = (0.55, 0.10)
    scene = scene_file(tmp_path, ('square', RED, at, 0.3), ('square', GREEN, (0.70, 0.30), -0.4),
                       ('square', BLUE, (0.65, -0.12), 0.2))
    fake = fake_baxter('--real-time-factor', '0', '--scene', scene)
    try:
        run, result, _ = run_task(ros_master, tmp_path, 'stack', 'stack', '--at', '%s,%s' % at,
                                  '--order', 'red,green,blue')
        log = run.log()
        assert run.returncode == 0 and result['success'], log[-3000:]
        assert 'the red square already stands at' in log and 'below is seen' in log
        red, green, blue = ground_truth_blocks()
        assert standing(red, 1) and standing(green, 2) and standing(blue, 3), [red[:3, 3], green[:3, 3], blue[:3, 3]]
        assert np.linalg.norm(red[:2, 3] - at) < 0.002, 'the bottom block moved'
        assert np.linalg.norm(green[:2, 3] - red[:2, 3]) < 0.01 and np.linalg.norm(blue[:2, 3] - green[:2, 3]) < 0.01
        assert [s['move']['level'] for s in result['steps']] == [2, 3]
    finally:
        fake.stop()


def test_survey_prints_the_map_then_clear_moves_every_block_to_one_area(ros_master, ros_node, fake_baxter,
                                                                        tmp_path):
    """``survey`` prints one line a block (colour, shape, position within 8 mm of the truth) and writes
    table_map.json; ``clear --to`` then leaves the block already at the area's first place and puts the other in
    the next one, upright, apart (one move)."""
    area = np.array([[0.45, 0.0], [0.45, -0.08]])      # the area's first two places (a row along -y, 8 cm apart)
    scene = scene_file(tmp_path, ('square', GREEN, (0.70, 0.25), 0.4), ('square', RED, area[0].tolist(), -0.3))
    fake = fake_baxter('--real-time-factor', '0', '--scene', scene)
    try:
        before = ground_truth_blocks()
        run, result, out = run_task(ros_master, tmp_path, 'survey', 'survey')
        assert run.returncode == 0 and result['success'] and result['steps'] == [], run.log()[-3000:]
        lines = [line for line in run.log().splitlines() if line.startswith('block ')]
        assert len(lines) == 2, lines
        for line, colour in zip(sorted(lines, key=lambda text: 'red' in text), ('green', 'red')):
            assert ': %s square at x ' % colour in line, line
            x, y = (float(line.split(' %s ' % axis)[1].split()[0]) / 1000 for axis in ('x', 'y'))
            truth = before[0 if colour == 'green' else 1]
            # 12 mm: the red square at (0.45, 0) is seen by one survey view only, near its edge from 0.43 m up,
            # and the map reports it +-5.3-6.4 mm: 3.2-3.5 mm off in 11 runs alone or under load, 9.4 mm once in a
            # full suite (session 18; the frame's noise and blur depend on when it is taken). The map says how far
            # it may be: within 3 of its stds (session 9 reported +-1.2 mm, the lateral error only; the
            # estimator's covariance has the error along the ray)
            error, std = np.hypot(x - truth[0, 3], y - truth[1, 3]), float(line.split('+- ')[1].split()[0]) / 1000
            assert error < 0.012 and error <= 3 * std, line
        assert len(json.loads((out / 'table_map.json').read_text())['blocks']) == 2
        run, result, _ = run_task(ros_master, tmp_path, 'clear', 'clear', '--to', '%s,%s' % tuple(area[0]))
        assert run.returncode == 0 and result['success'], run.log()[-3000:]
        assert [s['move']['colour'] for s in result['steps']] == ['green']
        green, red = ground_truth_blocks()
        assert np.linalg.norm(red[:3, 3] - before[1][:3, 3]) < 0.002, 'the block already in the area moved'
        assert np.linalg.norm(green[:2, 3] - area[1]) < 0.015, green[:3, 3]
        assert standing(green) and standing(red)
    finally:
        fake.stop()


@pytest.mark.parametrize('args, message', [(['sort', '--bin', 'purple:0.5,0.1'], 'purple not in the vision'),
                                           (['stack', '--at', '0.5', '--order', 'red,green'], '--at: expected X,Y')])
def test_bad_options_exit_2_before_the_robot(ros_master, tmp_path, args, message):
    """A colour the vision does not know, a malformed position: exit 2 with a message naming it (no robot)."""
    run = run_script(ros_master, 'table_task.py', args, timeout=60, log_path=tmp_path / 'bad.log')
    assert run.returncode == 2 and message in run.log(), run.log()[-2000:]


def test_trial_scores_judge_sorts_and_towers_by_the_ground_truth():
    """bench/table_trials.py's scores (run_trials.py --task sort|stack): a sort is verified only with every named
    block upright in a slot of its bin and the distractor where it stood; a tower only when standing, each block
    within 1 cm of the one below."""
    from baxter_pnp.bench import table_trials
    from baxter_pnp.bench.trial_scenes import COLOURS_RGB, SORT_BINS, STACK_AT
    from baxter_pnp.transforms import make_transform

    def entry(colour, xy, shape='square'):
        return {'shape': shape, 'side': 0.04, 'height': BLOCK_HEIGHT, 'color': list(COLOURS_RGB[colour]),
                'xy': list(xy), 'yaw': 0.0}

    def pose(xy, level=1, tilt=0.0):
        from scipy.spatial.transform import Rotation
        return make_transform(Rotation.from_euler('x', tilt), (xy[0], xy[1], TABLE_TOP_Z + level * BLOCK_HEIGHT))

    sort_scene = {'table': {'top_z': TABLE_TOP_Z}, 'objects': [
        entry('green', (0.7, 0.2)), entry('green', (0.6, -0.2)), entry('red', (0.7, 0.0)), entry('red', (0.6, 0.3)),
        entry('blue', (0.65, 0.1), 'triangle')]}
    (gx, gy), (rx, ry) = SORT_BINS['green'], SORT_BINS['red']
    sorted_end = [pose((gx, gy - 0.08)), pose((gx + 0.005, gy)), pose((rx, ry)), pose((rx, ry - 0.08)),
                  pose((0.65, 0.1))]
    assert table_trials.score_sort(sort_scene, sorted_end)['ok']
    for broken in ([pose((gx, gy))] + sorted_end[1:],                        # two greens in one slot
                   sorted_end[:4] + [pose((0.66, 0.1))],                      # the distractor pushed 1 cm
                   sorted_end[:2] + [pose((rx, ry), tilt=0.5)] + sorted_end[3:]):   # a red one tipped
        assert not table_trials.score_sort(sort_scene, broken)['ok']
    stack_scene = {'table': {'top_z': TABLE_TOP_Z}, 'objects': [entry('green', (0.7, 0.2)), entry('red', (0.6, 0.0)),
                                                                entry('blue', (0.6, -0.2))]}
    x, y = STACK_AT
    tower = [pose((x + 0.004, y), 2), pose((x, y), 1), pose((x + 0.008, y), 3)]     # green on red, blue on green
    scores = table_trials.score_stack(stack_scene, tower)
    assert scores['ok'] and scores['tower_levels'] == 3 and round(scores['worst_stack_offset_mm']) == 4
    assert not table_trials.score_stack(stack_scene, tower[:2] + [pose((x + 0.016, y), 3)])['ok']    # 12 mm off
    assert table_trials.score_stack(stack_scene, tower[:2] + [pose((x + 0.06, y), 1)])['tower_levels'] == 2


def test_random_multi_block_scenes_and_the_task_option_of_run_trials():
    """run_trials.py --task sort|stack: the scenes (two green and two red squares and a blue or yellow distractor,
    or a red, a green and a blue square; apart from each other and from the bins / the tower) and the option's
    defaults and exclusions."""
    from baxter_pnp.bench import table_trials, trial_scenes, trials
    for task, expected in (('sort', ['green', 'green', 'red', 'red']), ('stack', ['blue', 'green', 'red'])):
        scene = trial_scenes.random_table_scene(np.random.default_rng(5), task)
        kinds = [(o['shape'], table_trials.colour_of(o)) for o in scene['objects']]
        assert sorted(colour for shape, colour in kinds[:len(expected)]) == expected
        assert all(shape == 'square' for shape, _ in kinds[:len(expected)])
        if task == 'sort':
            assert len(kinds) == 5 and kinds[4][1] in ('blue', 'yellow')
        spots = np.array([o['xy'] for o in scene['objects']] + trial_scenes.table_task_places(task))
        gaps = np.linalg.norm(spots[:, None] - spots[None], axis=2) + np.eye(len(spots))
        assert gaps[:len(kinds)].min() >= trial_scenes.TABLE_TASK_MIN_DISTANCE - 1e-9
    args = trials.parse_args(['--task', 'stack'])
    assert (args.mode, args.timeout) == ('pbvs', 900.0) and trials.parse_args([]).timeout == 300.0
    with pytest.raises(SystemExit):
        trials.parse_args(['--task', 'sort', '--soak', '3'])
