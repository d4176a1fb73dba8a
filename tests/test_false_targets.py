"""No false target in a cluttered first look: the start views of random-look trial scenes (random light, shadows,
blur and table; clutter: a chessboard, tape of any block colour, cups, black and white cubes; two distractors, one
of the target's colour) hold no green square the application believes (``task.target.believable``, the table plane
from the view) anywhere but on the target, and the target is believed in most of them (docs/perception.md, "The
believable 'false' squares are the target")."""
import numpy as np
import pytest

from baxter_pnp import models, perception
from baxter_pnp.bench.trial_scenes import random_scene, trial_appearance, trial_clutter_rng
from baxter_pnp.sim.cameras import image_model
from baxter_pnp.sim.scene import Scene
from baxter_pnp.sim.world import SimWorld
from baxter_pnp.task.target import TargetRules, believable
from baxter_pnp.vision.config import VisionConfig

SEEDS = range(12)
CAMERA = image_model('left_hand_camera', 640, 400)
SAME_BLOCK_M = 0.08        # a believed estimate this close to the target is the target (two sides: a far one is
#                            posed a few per cent too far along its ray, docs/perception.md)


def _first_look(seed, start_pose):
    """(scene, T_base_camera, believed observations) of the first look at a random-look trial scene."""
    scene = random_scene(np.random.default_rng(seed), start_pose, distractors=2, same_colour_distractor=True,
                         appearance=trial_appearance('random', seed), clutter_rng=trial_clutter_rng('random', seed))
    world = SimWorld(Scene.from_dict(scene))
    try:
        world.command_gripper('left', 100.0, velocity_percent=100.0)
        world.step(240)
        image = world.render_camera('left_hand_camera', CAMERA, np.random.default_rng(seed))
        T_base_camera = world.link_pose('left_hand_camera')
    finally:
        world.close()
    side = scene['objects'][0]['side']
    table = models.Plane(np.array([0.0, 0.0, 1.0]), scene['table']['top_z'])
    rules = TargetRules('square', 'green', side, 0.02, table, max_residual_px=2.0, max_height_error=0.02)
    observations = perception.observe_blocks(image, CAMERA, VisionConfig.from_yaml(), side, 0.02, shape='square',
                                             colour='green',
                                             table_plane=models.table_plane_in_camera(T_base_camera, table))
    return scene, T_base_camera, [o for o in observations if believable(o, T_base_camera, rules)]


@pytest.mark.parametrize('start_pose', ['down', 'angled'])
def test_the_only_believed_green_square_in_a_cluttered_first_look_is_the_target(start_pose):
    found, false = 0, []
    for seed in SEEDS:
        scene, T_base_camera, believed = _first_look(seed, start_pose)
        target_xy = np.asarray(scene['objects'][0]['xy'])
        distances = [float(np.linalg.norm((T_base_camera @ o.pose.T_camera_object)[:2, 3] - target_xy))
                     for o in believed]
        found += any(d <= SAME_BLOCK_M for d in distances)
        false += [(seed, round(d, 3), round(o.detection.area_px)) for o, d in zip(believed, distances)
                  if d > SAME_BLOCK_M]
    assert not false, f'{start_pose}: believed green squares off the target (seed, m from it, px^2): {false}'
    assert found >= 0.75 * len(SEEDS), f'{start_pose}: the target believed in {found} of {len(SEEDS)} first looks'
