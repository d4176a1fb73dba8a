"""Scene YAML of the fake Baxter: defaults, start poses and every validation error."""
import copy

import numpy as np
import pytest
import yaml

from baxter_pnp.kinematics import load_start_poses
from baxter_pnp.sim.scene import DEFAULT_SCENE_YAML, RESPAWN_DELAY, Respawn, Scene, SceneError, load_scene

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
