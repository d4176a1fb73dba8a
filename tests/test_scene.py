"""Scene YAML of the fake Baxter: defaults, start poses, chessboards and every validation error."""
import copy
import os

import numpy as np
import pytest
import yaml

from baxter_pnp.calibration import board_object_points
from baxter_pnp.kinematics import load_start_poses
from baxter_pnp.runtime import PACKAGE_ROOT
from baxter_pnp.sim.scene import (BOARD_THICKNESS, DEFAULT_SCENE_YAML, RESPAWN_DELAY, Chessboard, Respawn, Scene,
                                  SceneError, _overlap, load_scene)
from baxter_pnp.transforms import transform_points

VALID = {
    'table': {'top_z': -0.15, 'center': [0.75, 0.0], 'size': [0.9, 1.5]},
    'objects': [
        {'shape': 'square', 'side': 0.04, 'height': 0.02, 'color': [0.1, 0.7, 0.1], 'xy': [0.70, 0.25], 'yaw': 0.4},
        {'shape': 'hexagon', 'side': 0.03, 'color': [0.8, 0.1, 0.1], 'xy': [0.60, 0.10]},
    ],
    'start': 'down',
    'camera_error': {'xyz': [0.0, 0.0, 0.0], 'rpy': [0.0, 0.0, 0.0], 'focal_scale': 1.0},
}
JOINTS = {f'left_{j}': 0.1 for j in ('s0', 's1', 'e0', 'e1', 'w0', 'w1', 'w2')}


def test_default_scene_file():
    scene = load_scene()
    assert scene.table.top_z == -0.15
    assert scene.table.center == (0.75, 0.0) and scene.table.size == (0.9, 1.5)
    (block,) = scene.objects
    assert (block.shape, block.side, block.height, block.xy, block.yaw) == ('square', 0.04, 0.02, (0.70, 0.25), 0.4)
    assert block.color == (0.1, 0.7, 0.1)
    assert block.model.n == 4
    assert scene.start == 'down'
    np.testing.assert_array_equal(scene.camera_error.T_published_true, np.eye(4))


def test_optional_keys_take_defaults():
    scene = Scene.from_dict({'objects': [{'shape': 'triangle', 'side': 0.05, 'color': [0, 0, 1], 'xy': [0.7, 0.0]}]})
    assert scene.table.top_z == -0.15 and scene.start == 'down' and scene.camera_error.focal_scale == 1.0
    assert scene.objects[0].height == 0.02 and scene.objects[0].yaw == 0.0
    assert Scene.from_dict({}).objects == ()


def test_start_poses():
    poses = load_start_poses()
    assert set(poses) == {'down', 'angled', 'neutral'}
    assert list(poses['neutral'].values()) == [0.0, -0.55, 0.0, 0.75, 0.0, 1.26, 0.0]
    assert Scene.from_dict({'start': 'angled'}).start_positions() == poses['angled']
    assert Scene.from_dict({'start': JOINTS}).start_positions() == JOINTS


def test_camera_error_transform():
    error = Scene.from_dict({'camera_error': {'xyz': [0.01, 0.0, 0.0], 'rpy': [0.0, 0.0, np.pi / 2]}}).camera_error
    T = error.T_published_true
    np.testing.assert_allclose(T[:3, 3], [0.01, 0.0, 0.0])
    np.testing.assert_allclose(T[:3, 0], [0.0, 1.0, 0.0], atol=1e-12)


DELETE = object()


def _set(d, path, value):
    """Copy of ``d`` with the item at ``path`` (tuple of keys/indices) replaced, or deleted if value is DELETE."""
    d = copy.deepcopy(d)
    target = d
    for key in path[:-1]:
        target = target[key]
    if value is DELETE:
        del target[path[-1]]
    else:
        target[path[-1]] = value
    return d


INVALID = [
    (('tabel',), {}, 'tabel: unknown key'),
    (('table',), [0.75, 0.0], 'table: must be a mapping'),
    (('table', 'top_z'), 'low', 'table.top_z: must be a number'),
    (('table', 'height'), 0.7, 'table.height: unknown key'),
    (('table', 'center'), [0.75], 'table.center: must be a list of 2 numbers'),
    (('table', 'size'), [0.9, -1.5], 'table.size[1]: must be a positive number'),
    (('objects',), {'shape': 'square'}, 'objects: must be a list'),
    (('objects', 0), 'square', 'objects[0]: must be a mapping'),
    (('objects', 0, 'shape'), 'circle', 'objects[0].shape: must be one of'),
    (('objects', 1, 'side'), DELETE, 'objects[1].side: missing'),
    (('objects', 1, 'side'), -0.04, 'objects[1].side: must be a positive number'),
    (('objects', 0, 'side'), True, 'objects[0].side: must be a number'),
    (('objects', 0, 'height'), 0.0, 'objects[0].height: must be a positive number'),
    (('objects', 0, 'color'), [0.1, 1.7, 0.1], 'objects[0].color: RGB components must be in 0..1'),
    (('objects', 0, 'color'), [0.1, 0.7, 0.1, 1.0], 'objects[0].color: must be a list of 3 numbers'),
    (('objects', 0, 'color'), 'green', 'objects[0].color: must be a list of 3 numbers'),
    (('objects', 0, 'xy'), [1.5, 0.25], 'objects[0].xy: [1.5, 0.25] is not on the table'),
    (('objects', 0, 'xy'), [0.7, None], 'objects[0].xy[1]: must be a number'),
    (('objects', 0, 'yaw'), float('nan'), 'objects[0].yaw: must be a number'),
    (('objects', 0, 'colour'), [0, 1, 0], 'objects[0].colour: unknown key'),
    (('start',), 'up', "start: must be 'down', 'angled', 'neutral' or a map"),
    (('start',), 3, 'start: must be a mapping'),
    (('start',), {k: v for k, v in JOINTS.items() if k != 'left_w2'}, 'start.left_w2: missing'),
    (('start',), {**JOINTS, 'right_s0': 0.0}, 'start.right_s0: unknown key'),
    (('start',), {**JOINTS, 'left_s0': '0.1'}, 'start.left_s0: must be a number'),
    (('camera_error', 'xyz'), [0.0, 0.0], 'camera_error.xyz: must be a list of 3 numbers'),
    (('camera_error', 'rpy'), [0.0, 'x', 0.0], 'camera_error.rpy[1]: must be a number'),
    (('camera_error', 'focal_scale'), 0.0, 'camera_error.focal_scale: must be a positive number'),
    (('camera_error', 'scale'), 1.0, 'camera_error.scale: unknown key'),
]


@pytest.mark.parametrize('path, value, message', INVALID, ids=[m.split(':')[0] + ':' + str(v)[:12]
                                                              for _, v, m in INVALID])
def test_invalid_scene_names_the_key(path, value, message):
    with pytest.raises(SceneError) as error:
        Scene.from_dict(_set(VALID, path, value))
    assert str(error.value).startswith(message)


def test_scene_must_be_a_mapping():
    with pytest.raises(SceneError, match='^Scene: must be a mapping'):
        Scene.from_dict(['table'])


def test_load_scene_prefixes_the_path(tmp_path):
    path = tmp_path / 'bad.yaml'
    path.write_text(yaml.safe_dump(_set(VALID, ('objects', 0, 'side'), 0)))
    with pytest.raises(ValueError, match=rf'^{path}: objects\[0\].side: must be a positive number'):
        load_scene(str(path))
    assert load_scene(DEFAULT_SCENE_YAML).objects[0].shape == 'square'


# ------------------------------------------------------------------------------------------------ respawn
WITH_RESPAWN = {**VALID, 'respawn': {'poses': [[0.62, 0.30, 0.5], [0.80, -0.20, -1.0]], 'delay': 1.5, 'object': 0}}


def test_respawn_parses_with_defaults():
    respawn = Scene.from_dict(WITH_RESPAWN).respawn
    assert respawn == Respawn(((0.62, 0.30, 0.5), (0.80, -0.20, -1.0)), 1.5, 0)
    short = Scene.from_dict(_set(VALID, ('respawn',), {'poses': [[0.8, 0.0, 0.0]]})).respawn
    assert (short.delay, short.object) == (RESPAWN_DELAY, 0) == (2.0, 0)
    assert Scene.from_dict(VALID).respawn is None


RESPAWN_INVALID = [
    (('respawn',), [[0.6, 0.3, 0.0]], 'respawn: must be a mapping'),
    (('respawn', 'pose'), [], 'respawn.pose: unknown key'),
    (('respawn', 'poses'), DELETE, 'respawn.poses: missing'),
    (('respawn', 'poses'), [], 'respawn.poses: must be a non-empty list'),
    (('respawn', 'poses'), [0.6, 0.3, 0.0], 'respawn.poses[0]: must be a list of 3 numbers'),
    (('respawn', 'poses', 1), [0.8, -0.2], 'respawn.poses[1]: must be a list of 3 numbers'),
    (('respawn', 'poses', 1), [0.8, 'y', 0.0], 'respawn.poses[1][1]: must be a number'),
    (('respawn', 'poses', 1), [1.5, 0.0, 0.0], 'respawn.poses[1]: [1.5, 0.0] is not on the table'),
    (('respawn', 'poses', 1), [0.61, 0.11, 0.0], 'respawn.poses[1]: the block would overlap objects[1]'),
    (('respawn', 'delay'), -1.0, 'respawn.delay: must be a non-negative number'),
    (('respawn', 'object'), 2, 'respawn.object: 2 but the scene has 2 object(s)'),
    (('respawn', 'object'), 0.5, 'respawn.object: must be an integer'),
    (('respawn', 'object'), -1, 'respawn.object: must be a non-negative integer'),
]


@pytest.mark.parametrize('path, value, message', RESPAWN_INVALID,
                         ids=[m.split(':')[0] + ':' + str(v)[:12] for _, v, m in RESPAWN_INVALID])
def test_invalid_respawn_names_the_key(path, value, message):
    with pytest.raises(SceneError) as error:
        Scene.from_dict(_set(WITH_RESPAWN, path, value))
    assert str(error.value).startswith(message)


def test_respawn_of_the_second_block_may_not_overlap_the_first():
    respawn = {'poses': [[0.71, 0.26, 0.0]], 'object': 1}
    with pytest.raises(SceneError, match=r'^respawn.poses\[0\]: the block would overlap objects\[0\]'):
        Scene.from_dict({**VALID, 'respawn': respawn})
    assert Scene.from_dict({**VALID, 'respawn': {**respawn, 'poses': [[0.60, 0.10, 1.0]]}}).respawn.object == 1


# ------------------------------------------------------------------------------------------------ chessboards
BLOCK_A = {'shape': 'square', 'side': 0.04, 'color': [0.1, 0.7, 0.1], 'xy': [0.70, 0.25]}
BOARD = {'shape': 'chessboard', 'pattern': [9, 6], 'square': 0.025, 'xy': [0.53, 0.25], 'yaw': -1.5}
BLOCK_B = {'shape': 'hexagon', 'side': 0.03, 'color': [0.8, 0.1, 0.1], 'xy': [0.70, -0.10]}
WITH_BOARD = {'objects': [BLOCK_A, BOARD, BLOCK_B]}


def test_chessboards_are_split_from_the_blocks_which_keep_their_indices():
    scene = Scene.from_dict({**WITH_BOARD, 'respawn': {'poses': [[0.80, -0.30, 0.0]], 'object': 1},
                             'faults': {'nudge': {'object': 1, 'at': 1.0, 'offset': [0.01, 0.0]}}})
    assert [obj.shape for obj in scene.objects] == ['square', 'hexagon']     # the blocks, in their order
    (board,) = scene.boards
    assert board == Chessboard(pattern=(9, 6), square=0.025, xy=(0.53, 0.25), yaw=-1.5)
    assert (board.border, board.thickness, board.shape) == (0.025, BOARD_THICKNESS, 'chessboard') == \
        (0.025, 0.0005, 'chessboard')                                         # border: one square by default
    assert board.size == pytest.approx((0.300, 0.225))                       # 10 x 7 squares and the border
    assert scene.respawn.object == 1 and scene.faults.nudge.object == 1      # object 1 is the hexagon
    with pytest.raises(SceneError, match=r'^respawn.object: 2 but the scene has 2 object\(s\) \(blocks'):
        Scene.from_dict({**WITH_BOARD, 'respawn': {'poses': [[0.80, -0.30, 0.0]], 'object': 2}})
    with pytest.raises(SceneError, match=r'^respawn.poses\[0\]: the block would overlap objects\[0\]'):
        Scene.from_dict({**WITH_BOARD, 'respawn': {'poses': [[0.71, 0.26, 0.0]], 'object': 1}})


def test_blocks_may_stand_on_a_board_and_boards_may_not_overlap():
    on_board = {**BLOCK_A, 'xy': [0.53, 0.25]}
    assert len(Scene.from_dict({'objects': [BOARD, on_board]}).objects) == 1
    with pytest.raises(SceneError, match=r'^objects\[3\].xy: the board overlaps objects\[1\] on the table'):
        Scene.from_dict({'objects': [BLOCK_A, BOARD, BLOCK_B, {**BOARD, 'xy': [0.60, 0.20]}]})
    beside = {**BOARD, 'xy': [0.53, -0.08]}                                  # 0.300 m wide (along base y): apart
    assert len(Scene.from_dict({'objects': [BOARD, beside]}).boards) == 2


BOARD_INVALID = [
    (('objects', 1, 'pattern'), [1, 6], 'objects[1].pattern[0]: must be at least 2 inner corners (got 1)'),
    (('objects', 1, 'pattern'), [9, 0], 'objects[1].pattern[1]: must be at least 2 inner corners'),
    (('objects', 1, 'pattern'), [9], 'objects[1].pattern: must be a list of 2 integers'),
    (('objects', 1, 'pattern'), [9.5, 6], 'objects[1].pattern[0]: must be an integer'),
    (('objects', 1, 'pattern'), DELETE, 'objects[1].pattern: missing'),
    (('objects', 1, 'square'), 0.0, 'objects[1].square: must be a positive number'),
    (('objects', 1, 'border'), -0.01, 'objects[1].border: must be a non-negative number'),
    (('objects', 1, 'thickness'), 0.0, 'objects[1].thickness: must be a positive number'),
    (('objects', 1, 'xy'), [0.35, 0.25], 'objects[1].xy: the 0.300 x 0.225 m board (border included) does not '
                                         'lie wholly on the table'),
    (('objects', 1, 'color'), [0, 0, 0], 'objects[1].color: unknown key'),
    (('objects', 2, 'side'), -0.03, 'objects[2].side: must be a positive number'),       # the block after it
    (('objects', 2, 'xy'), [0.71, 0.26], 'objects[2].xy: the block overlaps objects[0] on the table'),
    (('objects', 2, 'shape'), 'chess', "objects[2].shape: must be one of ['triangle', 'square', 'pentagon', "
                                       "'hexagon'], 'chessboard', 'tape' or 'cup'"),
]


@pytest.mark.parametrize('path, value, message', BOARD_INVALID,
                         ids=[m.split(':')[0] + ':' + str(v)[:12] for _, v, m in BOARD_INVALID])
def test_invalid_board_names_its_place_in_the_objects_list(path, value, message):
    with pytest.raises(SceneError) as error:
        Scene.from_dict(_set(WITH_BOARD, path, value))
    assert str(error.value).startswith(message)


def test_boards_and_props_go_in_objects_only():
    for key in ('boards', 'props'):
        with pytest.raises(SceneError, match=f"^{key}: unknown key: chessboards, tape and cups go in 'objects'"):
            Scene.from_dict({key: [BOARD]})


def test_board_frame_is_opencvs_object_frame_on_the_printed_top():
    """``T_base_board`` maps ``calibration.board_object_points`` onto the board's inner corners: the grid centred
    on ``xy``, rows of corners along the yawed base x, on the printed top, z into the table."""
    board = Scene.from_dict({'objects': [BOARD]}).boards[0]
    top_z = -0.15
    T = board.T_base_board(top_z)
    assert np.linalg.det(T[:3, :3]) == pytest.approx(1.0)
    np.testing.assert_allclose(T[:3, :3].T @ T[:3, :3], np.eye(3), atol=1e-12)
    np.testing.assert_allclose(T[:3, 2], [0.0, 0.0, -1.0])                   # into the table
    np.testing.assert_allclose(T[:3, 0], [np.cos(-1.5), np.sin(-1.5), 0.0])  # along the rows: yaw from base x
    corners = transform_points(T, board_object_points((9, 6), 0.025))
    np.testing.assert_allclose(corners.mean(axis=0), [0.53, 0.25, top_z + 0.0005], atol=1e-12)
    np.testing.assert_allclose(corners[1] - corners[0], 0.025 * T[:3, 0], atol=1e-12)   # row by row
    np.testing.assert_allclose(corners[9] - corners[0], 0.025 * T[:3, 1], atol=1e-12)
    # the outline lies one square and the border beyond the outer corners, around the grid
    outline = transform_points(np.linalg.inv(T), np.column_stack([board.footprint(), np.full(4, top_z + 0.0005)]))
    np.testing.assert_allclose(np.sort(outline[:, 0]), [-0.05, -0.05, 0.25, 0.25], atol=1e-12)
    np.testing.assert_allclose(np.sort(outline[:, 1]), [-0.05, -0.05, 0.175, 0.175], atol=1e-12)
    # 35 of the 70 squares are black, the one before the first corner among them (OpenCV's printed pattern)
    squares = board.black_squares()
    assert squares.shape == (35, 4, 2)
    np.testing.assert_allclose(squares[0], [[-0.025, -0.025], [0.0, -0.025], [0.0, 0.0], [-0.025, 0.0]])
    centres = squares.mean(axis=1) / 0.025 + 0.5                             # square (a, b) -> (a - 1, b - 1)
    assert np.all(np.round(centres.sum(axis=1)) % 2 == 0)


def test_supersampling():
    assert Scene.from_dict({}).supersampling == 1
    assert Scene.from_dict({'supersampling': 3}).supersampling == 3
    for value, message in ((0, 'must be an integer from 1 to 4'), (5, 'must be an integer from 1 to 4'),
                           (1.5, 'must be an integer')):
        with pytest.raises(SceneError, match=f'^supersampling: {message}'):
            Scene.from_dict({'supersampling': value})


@pytest.mark.parametrize('name, focal_scale', [('hand_eye', 1.0), ('hand_eye_focal', 1.02)])
def test_hand_eye_scene_files(name, focal_scale):
    """config/scenes/hand_eye.yaml: a 9x6 board of 25 mm squares, one block beside it, a camera error of at most
    8 mm and 0.03 rad per axis, anti-aliased images (its views: tests/test_world.py); hand_eye_focal.yaml: the
    same, the true focal length 2 % longer."""
    scene = load_scene(os.path.join(PACKAGE_ROOT, 'config', 'scenes', f'{name}.yaml'))
    (board,) = scene.boards
    assert (board.pattern, board.square) == ((9, 6), 0.025)
    (block,) = scene.objects
    assert not _overlap(block, board) and scene.start == 'down' and scene.supersampling == 2
    error = scene.camera_error
    assert 0 < np.max(np.abs(error.xyz)) <= 0.008 and 0 < np.max(np.abs(error.rpy)) <= 0.03
    assert error.focal_scale == focal_scale
