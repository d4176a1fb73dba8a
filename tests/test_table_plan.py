"""The multi-block planner (table_plan.py, pure): bin rows, free slots, stacks, the user's errors."""
import dataclasses

import numpy as np
import pytest

from baxter_pnp import table_plan
from baxter_pnp.table_map import MapBlock
from baxter_pnp.table_plan import PlanError


def block(block_id, colour, xy, shape='square', z=-0.13):
    return MapBlock(block_id, shape, colour, np.array([xy[0], xy[1], z]), np.eye(3) * 1e-6, 0.0, 1, 0.0, [],
                    np.zeros(2))


SCENE = [block(1, 'green', (0.70, 0.25)), block(2, 'red', (0.62, 0.10)), block(3, 'green', (0.55, 0.30)),
         block(4, 'red', (0.75, 0.05)), block(5, 'blue', (0.60, 0.40), shape='triangle')]      # 5: the distractor


def test_slots_run_in_rows_spaced_apart():
    row = [s for s, _ in zip(table_plan.slots((0.5, 0.2), (0, -1), 0.08), range(3))]
    np.testing.assert_allclose(row, [(0.5, 0.2), (0.5, 0.12), (0.5, 0.04)])
    grid = [s for s, _ in zip(table_plan.slots((0.5, 0.2), (0, -1), 0.08, per_row=2), range(3))]
    np.testing.assert_allclose(grid, [(0.5, 0.2), (0.5, 0.12), (0.58, 0.2)])     # next row: +90 deg from -y is +x


def test_sort_puts_every_named_block_in_its_bin_row_and_leaves_the_rest():
    bins = {'green': (0.50, 0.10), 'red': (0.80, 0.30)}
    moves = table_plan.plan_sort(SCENE, bins)
    assert sorted(m.block_id for m in moves) == [1, 2, 3, 4]            # not the blue distractor
    for m in moves:
        slot_row = [s for s, _ in zip(table_plan.slots(bins[m.colour]), range(2))]
        assert any(np.allclose(m.to_xy, s) for s in slot_row), m
    destinations = np.array([m.to_xy for m in moves])
    gaps = np.linalg.norm(destinations[:, None] - destinations[None], axis=2) + np.eye(len(moves))
    assert gaps.min() >= table_plan.SLOT_SPACING - 1e-9                 # they do not touch
    for m in moves:                                                      # never where another block stands
        others = [b for b in SCENE if b.id != m.block_id]
        assert table_plan.is_free(m.to_xy, others), m


def test_sort_skips_a_slot_where_a_block_stands_and_keeps_one_already_in_its_bin():
    blocks = [block(1, 'green', (0.50, 0.10)), block(2, 'green', (0.70, 0.30)), block(3, 'red', (0.50, 0.02))]
    moves = table_plan.plan_sort(blocks, {'green': (0.50, 0.10)})
    assert [m.block_id for m in moves] == [2]                            # block 1 is in the bin's first slot
    np.testing.assert_allclose(moves[0].to_xy, (0.50, -0.06))            # slot 2 is taken by the red block


def test_sort_by_shape_and_the_errors_a_user_sees():
    moves = table_plan.plan_sort(SCENE, {'blue': (0.5, 0.1)}, shape='square')
    assert moves == []                                                   # the blue block is a triangle
    with pytest.raises(PlanError, match='out of reach'):
        table_plan.plan_sort(SCENE, {'green': (0.5, 0.1)}, placeable=lambda xy: False)
    with pytest.raises(PlanError, match='COLOUR:X,Y'):
        table_plan.parse_bin('green')
    with pytest.raises(PlanError, match='X,Y in metres'):
        table_plan.parse_bin('green:0.5')
    assert table_plan.parse_bin(' red :0.5,-0.1') == ('red', (0.5, -0.1))
    with pytest.raises(PlanError, match='at least two colours'):
        table_plan.parse_order('red')


def test_clear_moves_every_block_into_one_area_in_rows():
    moves = table_plan.plan_clear(SCENE, (0.45, 0.0), per_row=3)
    assert sorted(m.block_id for m in moves) == [1, 2, 3, 4, 5]
    area = [s for s, _ in zip(table_plan.slots((0.45, 0.0), per_row=3), range(6))]
    assert all(any(np.allclose(m.to_xy, s) for s in area) for m in moves)
    assert len({m.to_xy for m in moves}) == 5


def test_stack_order_levels_and_a_taken_spot():
    moves = table_plan.plan_stack(SCENE, (0.45, -0.1), ['red', 'green', 'blue'])
    assert [(m.colour, m.level) for m in moves] == [('red', 1), ('green', 2), ('blue', 3)]
    assert moves[0].block_id == 2 and moves[1].block_id == 3                # the nearest of each colour
    assert all(m.to_xy == (0.45, -0.1) for m in moves)
    in_place = table_plan.plan_stack(SCENE, (0.62, 0.10), ['red', 'green'])    # the red block is there already
    assert [(m.colour, m.level) for m in in_place] == [('green', 2)]
    with pytest.raises(PlanError, match='taken by the green square'):
        table_plan.plan_stack(SCENE, (0.70, 0.26), ['red', 'green'])
    with pytest.raises(PlanError, match='no yellow left'):
        table_plan.plan_stack(SCENE, (0.45, -0.1), ['red', 'yellow'])
    with pytest.raises(PlanError, match='no green square left on the table for level 3'):
        table_plan.plan_stack(SCENE, (0.45, -0.1), ['green', 'green', 'green'], shape='square')


def test_levels_displaced_blocks_and_the_survey_line():
    assert table_plan.level_of(-0.13, -0.15, 0.02, 0.005) == 1
    assert table_plan.level_of(-0.089, -0.15, 0.02, 0.005) == 3
    assert table_plan.level_of(-0.12, -0.15, 0.02, 0.005) is None       # half a block up: knocked over
    after = [block(9, 'green', (0.70, 0.25)), block(8, 'red', (0.66, 0.10))]
    moved = table_plan.displaced(SCENE[:2], after, moved_ids=())
    assert [b.id for b in moved] == [2]                                  # the red block was pushed 4 cm
    assert table_plan.displaced(SCENE[:2], after, moved_ids=(2,)) == []
    line = table_plan.block_line(SCENE[0])
    assert line.startswith('block 1: green square at x 700.0 y 250.0 z -130.0 mm'), line


def test_an_estimate_put_on_its_known_height_along_the_viewing_ray():
    camera = np.array([0.5, 0.1, 0.3])
    truth = np.array([0.6, 0.15, -0.11])
    T = np.eye(4)
    T[:3, 3] = camera + 0.96 * (truth - camera)        # 4 % short in depth: 11 mm high, 4 mm off laterally
    np.testing.assert_allclose(table_plan.on_height(T, camera, -0.11)[:3, 3], truth, atol=1e-12)


# ---------------------------------------------------------------------------- a block checked on its level
TABLE_Z = -0.15
SIDE, HEIGHT = 0.04, 0.02


def camera_looking_at(eye, target):
    """T_base_camera at ``eye`` (m, base) with its optical axis through ``target``, its x axis level."""
    z = np.subtract(target, eye) / np.linalg.norm(np.subtract(target, eye))
    x = np.cross(z, [0.0, 0.0, 1.0])
    x /= np.linalg.norm(x)
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = np.column_stack([x, np.cross(z, x), z]), eye
    return T


@pytest.mark.parametrize('level', [1, 2, 3])
@pytest.mark.parametrize('scale', [0.94, 1.0, 1.06])
def test_a_block_on_its_level_is_posed_there_by_its_top_face(level, scale):
    """A block's top face seen a few per cent off its size (a rim, a side face's pixel: the polygon pose's depth
    10-15 mm off from 0.35 m) is posed on the level it is checked on, within 1 mm of where it stands, face up."""
    camera, table, T_base_camera = level_scene()
    detection, T_true = square_on_level(camera, T_base_camera, level, scale)
    estimate = table_plan.pose_on_level(detection, camera, T_base_camera, table, level, SIDE, HEIGHT)
    assert estimate is not None and estimate.method == 'on_table'
    assert np.linalg.norm(estimate.T_camera_object[:3, 3] - T_true[:3, 3]) < 0.001
    assert estimate.T_camera_object[:3, 2] @ T_true[:3, 2] > np.cos(1e-6)


def test_a_face_not_a_blocks_on_the_level_is_not_posed_there():
    """A face 0.75 of the size (another block, a fragment) or checked on level 0: None, ValueError."""
    camera, table, T_base_camera = level_scene()
    detection, _ = square_on_level(camera, T_base_camera, 2, 0.75)
    assert table_plan.pose_on_level(detection, camera, T_base_camera, table, 2, SIDE, HEIGHT) is None
    with pytest.raises(ValueError, match='levels start at 1'):
        table_plan.pose_on_level(detection, camera, T_base_camera, table, 0, SIDE, HEIGHT)


def level_scene():
    """(camera model, table plane in base, T_base_camera 0.3 m above the table looking at (0.47, 0.10) m)."""
    from baxter_pnp import models
    from baxter_pnp.camera import load_default_camera
    return (load_default_camera(), models.Plane.level(TABLE_Z),
            camera_looking_at((0.40, 0.25, TABLE_Z + 0.30), (0.47, 0.10, TABLE_Z)))


def square_on_level(camera, T_base_camera, level, scale):
    """(a red square ``vision.Detection`` of the top face of a block on ``level`` at (0.47, 0.10) m, yaw 0.4 rad,
    ``scale`` times its size; the block's T_camera_block)."""
    from baxter_pnp import models, vision
    from baxter_pnp.transforms import invert, make_transform
    model = models.model_for('square', SIDE, HEIGHT)
    T = invert(T_base_camera) @ make_transform(None, (0.47, 0.10, TABLE_Z + level * HEIGHT))
    c, s = np.cos(0.4), np.sin(0.4)
    T[:3, :3] = T[:3, :3] @ np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    vertices = camera.project(scale * model.vertices @ T[:3, :3].T + T[:3, 3])
    return vision.Detection('square', 'red', vertices, vertices.mean(axis=0), 900.0, 1.0, False,
                            vertices.reshape(-1, 1, 2).astype(np.int32)), T


@pytest.mark.parametrize('level', [1, 2])
def test_a_look_checking_a_level_believes_a_block_there_and_not_two_levels_off(level):
    """``on_level``: a polygon whose own pose is on the level checked gives that pose; one 5 % too small (its pose
    15 mm too far: on no level, or on the level below) is posed on the level checked by its top face, within 1 mm;
    a block two levels up, seen as it is, is not taken for one on the level checked; a pose with a residual over
    ``max_residual_px`` is on no level."""
    from baxter_pnp import pose, models, perception
    camera, table, T_base_camera = level_scene()
    config = table_plan.TableTaskConfig()
    model = models.model_for('square', SIDE, HEIGHT)

    def observation(on, scale):
        detection, T = square_on_level(camera, T_base_camera, on, scale)
        estimate = pose.estimate_pose(detection.vertices_px, camera, model)
        return perception.BlockObservation(detection, estimate), T

    exact, T_true = observation(level, 1.0)
    assert table_plan.level_of_pose(exact.pose, T_base_camera, table, config) == level
    assert table_plan.on_level(exact, camera, T_base_camera, table, level, config) == (exact.pose, False)
    small, T_true = observation(level, 0.95)
    assert table_plan.level_of_pose(small.pose, T_base_camera, table, config) == (None if level == 1 else level - 1)
    estimate, refitted = table_plan.on_level(small, camera, T_base_camera, table, level, config)
    assert refitted and np.linalg.norm(estimate.T_camera_object[:3, 3] - T_true[:3, 3]) < 0.001
    two_up, _ = observation(level + 2, 1.0)
    assert table_plan.level_of_pose(two_up.pose, T_base_camera, table, config) == level + 2
    assert table_plan.on_level(two_up, camera, T_base_camera, table, level, config) == (None, False)
    noisy = perception.BlockObservation(exact.detection, dataclasses.replace(exact.pose, residual_px=2.5))
    assert table_plan.level_of_pose(noisy.pose, T_base_camera, table, config) is None


def test_a_block_whose_polygon_keeps_a_side_face_is_posed_on_its_level_by_its_silhouette():
    """A block on level 2 whose polygon is its blob's (top face and the side faces seen: no square) is no top face
    on the level, but its silhouette is the block's standing there: posed within 1.5 mm."""
    import cv2
    from baxter_pnp import models, perception, vision
    camera, table, T_base_camera = level_scene()
    model = models.model_for('square', SIDE, HEIGHT)
    _, T = square_on_level(camera, T_base_camera, 2, 1.0)
    top = model.vertices @ T[:3, :3].T + T[:3, 3]
    outline = cv2.convexHull(camera.project(np.vstack([top, top - HEIGHT * T[:3, 2]])).astype(np.float32))
    polygon = cv2.approxPolyDP(outline, 3.0, True).reshape(-1, 2).astype(float)[:4]     # four of its corners
    detection = vision.Detection('square', 'red', polygon, polygon.mean(axis=0), 900.0, 1.0, False,
                                 np.round(outline).astype(np.int32))
    level_2 = models.table_plane_in_camera(T_base_camera, table.raised(HEIGHT))
    assert perception.top_face_on_plane(detection, camera, SIDE, HEIGHT, level_2) is None
    estimate = table_plan.pose_on_level(detection, camera, T_base_camera, table, 2, SIDE, HEIGHT)
    assert estimate is not None and estimate.method == 'silhouette'
    assert np.linalg.norm(estimate.T_camera_object[:3, 3] - T[:3, 3]) < 0.0015
