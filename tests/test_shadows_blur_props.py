"""The fake camera's light, shadows and motion blur (``appearance: light_direction, shadows, exposure_time``) and the
table clutter (``shape: tape | cup`` entries, black and white blocks): each as asked, and none of the clutter a
block to the vision."""
import dataclasses

import cv2
import numpy as np
import pybullet as p
import pytest

from baxter_pnp import perception
from baxter_pnp.camera import CameraModel
from baxter_pnp.models import Plane, table_plane_in_camera
from baxter_pnp.sim import appearance
from baxter_pnp.sim.appearance import AppearanceConfig, expand
from baxter_pnp.sim.cameras import sensor_model, sensor_window
from baxter_pnp.sim.render import LIGHT, RendererUnavailable, egl
from baxter_pnp.sim.scene import Scene, SceneError
from baxter_pnp.sim.world import SimWorld
from baxter_pnp.transforms import from_xyz_rpy, invert, make_transform
from baxter_pnp.vision import detect
from baxter_pnp.vision.config import VisionConfig

CAMERA = sensor_model('left_hand_camera').windowed(sensor_window(640, 400))
LINK = 'left_hand_camera'
BLOCK_XY = (0.70, 0.25)          # in the down pose's view, below the fingers
QUIET = {'noise_std': 0.0, 'colour_noise_std': 0.0}


def _egl_problem():
    try:
        egl.shared_context()
    except RendererUnavailable as error:
        return str(error)
    return ''


needs_egl = pytest.mark.skipif(bool(_egl_problem()), reason=f'EGL unavailable here: {_egl_problem()}')


def render(scene_dict, rng=None):
    """(the hand camera's image of the scene in the down pose, T_base_camera)."""
    world = SimWorld(Scene.from_dict({'start': 'down', **scene_dict}))
    try:
        return world.render_camera(LINK, CAMERA, rng), world.link_pose(LINK)
    finally:
        world.close()


def pixel_of(T_base_camera, point_base):
    """(u, v) int pixel of a base point."""
    point = invert(T_base_camera) @ [*point_base, 1.0]
    return np.rint(CAMERA.project(point[:3])[0]).astype(int)


def patch_mean(image, pixel, half=3):
    u, v = pixel
    return float(image[v - half:v + half + 1, u - half:u + half + 1].astype(float).mean())


@needs_egl
@pytest.mark.parametrize('strength', [0.5, 1.0])
def test_a_block_casts_its_shadow_away_from_the_light_as_dark_as_asked(strength):
    """A 40 mm cube lit from +x at 45 deg shades the table for 40 mm on its -x side: there the direct light's
    share ``strength`` is gone (TinyRenderer's model: ambient 0.55 + diffuse 0.45 n.l), the +x side is as lit as
    without shadows."""
    block = {'shape': 'square', 'side': 0.04, 'height': 0.04, 'color': [0.1, 0.7, 0.1], 'xy': list(BLOCK_XY)}
    images = {}
    for shadows in (0.0, strength):
        look = {'light_direction': [1.0, 0.0, 1.0], 'shadows': shadows, **QUIET}
        images[shadows], T_base_camera = render({'objects': [block], 'appearance': look})
    table_z = Scene().table.top_z
    in_shadow = pixel_of(T_base_camera, (BLOCK_XY[0] - 0.02 - 0.02, BLOCK_XY[1], table_z))   # 20 mm beyond its edge
    lit_side = pixel_of(T_base_camera, (BLOCK_XY[0] + 0.02 + 0.02, BLOCK_XY[1], table_z))
    direct = LIGHT['lightDiffuseCoeff'] * np.cos(np.pi / 4)
    expected = (LIGHT['lightAmbientCoeff'] + (1 - strength) * direct) / (LIGHT['lightAmbientCoeff'] + direct)
    assert patch_mean(images[strength], in_shadow) / patch_mean(images[0.0], in_shadow) == \
        pytest.approx(expected, abs=0.02)
    assert patch_mean(images[strength], lit_side) == pytest.approx(patch_mean(images[0.0], lit_side), abs=0.5)


def test_the_light_direction_shades_the_faces():
    """The same scene lit from straight above and from low at the side: the table (facing up) is darker in the
    second, by the cosine of the light's angle."""
    means = []
    for direction in ([0.0, 0.0, 1.0], [1.0, 0.0, 0.5]):
        image, _ = render({'appearance': {'light_direction': direction, **QUIET}})
        means.append(image[300:390, 40:600].astype(float).mean())
    cosine = 0.5 / np.hypot(1.0, 0.5)
    expected = (LIGHT['lightAmbientCoeff'] + LIGHT['lightDiffuseCoeff'] * cosine) / \
        (LIGHT['lightAmbientCoeff'] + LIGHT['lightDiffuseCoeff'])
    assert means[1] / means[0] == pytest.approx(expected, abs=0.02)


def _camera_over_table(height):
    """T_base_camera looking straight down from ``height`` m above z = 0 (x along base x, y along -base y)."""
    return make_transform(np.diag([1.0, -1.0, -1.0]), [0.7, 0.0, height])


def test_motion_blur_smears_along_the_motion_by_its_length_and_spares_what_rides_along():
    """A bright column on a dark table, the camera moved 4 mm along its x during the exposure at 0.4 m: the column
    smears over f * 4 mm / 0.4 m px toward -u, its light kept; the pixels marked as riding with the camera
    (``scene_alpha`` 0) stay as they are; no motion, no change."""
    image = np.full((CAMERA.height, CAMERA.width, 3), 20, np.uint8)
    image[:, 300] = 220
    image[:40, :80] = 5                                               # a finger
    alpha = np.full(image.shape[:2], 255, np.uint8)
    alpha[:40, :80] = 0
    T_now = _camera_over_table(0.4)
    assert appearance.motion_blur(image, CAMERA, T_now, T_now, 0.0, alpha) is image
    T_before = T_now @ from_xyz_rpy([0.004, 0.0, 0.0], [0.0, 0.0, 0.0])
    blurred = appearance.motion_blur(image, CAMERA, T_now, T_before, 0.0, alpha)
    smear = CAMERA.K[0, 0] * 0.004 / 0.4                                  # px
    row = blurred[200, 250:320, 1].astype(float) - 20
    columns = np.arange(250, 320)
    assert row.sum() == pytest.approx(200, rel=0.05)                     # the light is kept
    assert np.sum(row * columns) / row.sum() == pytest.approx(300 - smear / 2, abs=0.5)
    assert np.count_nonzero(row > 5) == pytest.approx(smear + 1, abs=1.5)
    np.testing.assert_array_equal(blurred[:40, :80], image[:40, :80])


@needs_egl
def test_the_fake_blurs_a_moving_hand_camera_but_not_its_fingers():
    """Two frames 20 ms apart with the wrist bent 0.02 rad between them: under ``exposure_time: 0.02`` the table
    texture of the second frame is smeared (less contrast between neighbours) and the fingers, which move with the
    camera, are the same pixels as without blur."""
    scene = Scene.from_dict({'start': 'down', 'appearance': {'preset': 'baxter', 'shadows': 0.0, 'vignetting': 1.0,
                                                             **QUIET}})     # only the fingers dark
    frames = {}
    for exposure_time in (0.0, 0.02):
        world = SimWorld(dataclasses.replace(scene, appearance=dataclasses.replace(scene.appearance,
                                                                                  exposure_time=exposure_time)))
        try:
            world.render_camera(LINK, CAMERA)
            positions = dict(scene.start_positions())
            positions['left_w1'] += 0.02
            world.set_arm_positions('left', positions)
            world.time += 0.02
            frames[exposure_time] = world.render_camera(LINK, CAMERA)
            riding = world._riding_parts(LINK)
        finally:
            world.close()
    assert riding
    sharp, blurred = (frames[t][250:390, 40:600, 1].astype(float) for t in (0.0, 0.02))
    def contrast(image):         # mean step between neighbours, both ways (the smear runs mostly along v)
        return np.abs(np.diff(image, axis=0)).mean() + np.abs(np.diff(image, axis=1)).mean()
    assert contrast(blurred) < 0.8 * contrast(sharp)
    fingers = frames[0.0][:60].max(axis=2) < 40                       # the dark fingers at the top,
    fingers = cv2.erode(fingers.astype(np.uint8), np.ones((5, 5), np.uint8)) > 0     # their silhouette's pixels aside
    assert fingers.sum() > 2000
    np.testing.assert_array_equal(frames[0.02][:60][fingers], frames[0.0][:60][fingers])


def test_random_looks_draw_light_shadows_and_blur():
    looks = [appearance.random_appearance(np.random.default_rng(seed)) for seed in range(200)]
    elevations = [np.degrees(np.arcsin(look['light_direction'][2] / np.linalg.norm(look['light_direction'])))
                  for look in looks]
    assert 44.5 < min(elevations) < 50 and 83 < max(elevations) < 88.5
    for key, (low, high) in (('shadows', appearance.SHADOWS_RANGE), ('exposure_time', appearance.EXPOSURE_TIME_RANGE)):
        values = [look[key] for look in looks]
        assert low <= min(values) < low + 0.05 * (high - low) and high - 0.05 * (high - low) < max(values) <= high
    baxter = AppearanceConfig.from_dict(expand('baxter'))
    assert baxter.shadows > 0 and baxter.exposure_time > 0


# ------------------------------------------------------------------------------------------------ clutter
TAPE = {'shape': 'tape', 'xy': [0.66, 0.30], 'length': 0.10, 'width': 0.019, 'color': [0.1, 0.7, 0.1], 'yaw': 0.3}
CUP = {'shape': 'cup', 'xy': [0.80, 0.33], 'radius': 0.04, 'height': 0.095, 'color': [0.1, 0.2, 0.8]}
GREEN_SQUARE = {'shape': 'square', 'side': 0.04, 'color': [0.1, 0.7, 0.1], 'xy': list(BLOCK_XY)}


def test_props_are_objects_entries_kept_apart_from_the_blocks():
    scene = Scene.from_dict({'objects': [TAPE, GREEN_SQUARE, CUP]})
    assert [obj.shape for obj in scene.objects] == ['square']
    assert [prop.shape for prop in scene.props] == ['tape', 'cup']
    Scene.from_dict({'objects': [GREEN_SQUARE, {**TAPE, 'xy': list(BLOCK_XY)}]})     # a block may stand on tape
    for entry, message in (({**CUP, 'xy': [0.72, 0.26]}, 'objects[1].xy: the cup overlaps objects[0]'),
                           ({**TAPE, 'xy': [1.19, 0.0]}, 'objects[1].xy: the tape does not lie wholly on the table'),
                           ({**CUP, 'radius': 0.0}, 'objects[1].radius: must be a positive number'),
                           ({**TAPE, 'color': [2, 0, 0]}, 'objects[1].color'),
                           ({**CUP, 'mug': 1}, 'objects[1].mug: unknown key')):
        with pytest.raises(SceneError, match=message.replace('[', r'\[').replace(']', r'\]')):
            Scene.from_dict({'objects': [GREEN_SQUARE, entry]})


def test_a_cup_is_solid_and_tape_is_not():
    world = SimWorld(Scene.from_dict({'objects': [TAPE, CUP]}))
    try:
        top = Scene().table.top_z
        hit = p.rayTest([*CUP['xy'], top + 0.15], [*CUP['xy'], top - 0.01], physicsClientId=world._client)[0]
        assert hit[0] >= 0 and hit[3][2] == pytest.approx(top + CUP['height'], abs=0.002)
        hit = p.rayTest([*TAPE['xy'], top + 0.15], [*TAPE['xy'], top - 0.01], physicsClientId=world._client)[0]
        assert hit[3][2] == pytest.approx(top, abs=0.001)                # the table: the tape has no collision
    finally:
        world.close()


@pytest.mark.parametrize('look', ['clean', 'baxter'])
def test_clutter_in_view_is_drawn_and_no_block_to_the_vision(look):
    """A green tape strip, a blue cup, black and white cubes and a chessboard around one green square, all in
    view: the tape is drawn in its colour where it lies; the vision sees nothing blue, black or white, and of the
    green things only the square gets a pose on the table (the strip, a 5:1 quadrilateral, is refused: a square
    would have to stand 56-61 deg off the table to look like it)."""
    clutter = [{**TAPE, 'xy': [0.58, 0.36]}, {**CUP, 'xy': [0.56, 0.17]},
               {'shape': 'chessboard', 'pattern': [5, 4], 'square': 0.025, 'xy': [0.72, 0.06]},
               {'shape': 'square', 'side': 0.04, 'height': 0.04, 'color': [0.05, 0.05, 0.05], 'xy': [0.64, 0.14]},
               {'shape': 'square', 'side': 0.03, 'height': 0.03, 'color': [0.92, 0.92, 0.9], 'xy': [0.62, 0.29]}]
    image, T_base_camera = render({'objects': [GREEN_SQUARE, *clutter], 'appearance': look},
                                  np.random.default_rng(0))
    table_z = Scene().table.top_z
    u, v = pixel_of(T_base_camera, (0.58, 0.36, table_z))
    b, g, r = image[v, u].astype(int)
    assert g > r + 15 and g > b + 15                                   # the tape, green, in view
    u, v = pixel_of(T_base_camera, (0.56, 0.17 + 0.8 * CUP['radius'], table_z + CUP['height']))
    b, g, r = image[v, u].astype(int)
    assert b > r + 15 and b > g + 15                                   # the cup's rim, blue, in view
    config = VisionConfig.from_yaml()
    assert {d.colour for d in detect(image, config)} == {'green'}
    observations = perception.observe_blocks(image, CAMERA, config, 0.04, 0.02, shape='square', colour='green',
                                             table_plane=table_plane_in_camera(T_base_camera, Plane.level(table_z)))
    posed = [T_base_camera @ o.pose.T_camera_object for o in observations if o.pose is not None]
    assert len(observations) == 2 and len(posed) == 1
    assert np.hypot(*(posed[0][:2, 3] - BLOCK_XY)) < 0.003


SHADE_BLOCK = {'shape': 'square', 'side': 0.04, 'color': [0.1, 0.7, 0.1], 'xy': [0.66, 0.25], 'yaw': 0.3}
SHADE_CUP = {'shape': 'cup', 'xy': [0.66, 0.35], 'radius': 0.03, 'height': 0.095, 'color': [0.9, 0.9, 0.9]}


@needs_egl
@pytest.mark.parametrize('strength', [0.3, 0.5, 1.0])
def test_a_block_half_in_a_cup_shadow_is_posed_where_it_lies(strength):
    """A cup between the light and the block shades part of the block's top face: the block is still posed within
    3 mm of where it lies. From 0.5 on, top-face isolation takes the shadow's edge for a side face's and the lit
    part gets no pose; the whole blob (``vision.blob_detection``) does."""
    look = {'preset': 'baxter', 'light_direction': [0.35, 1.0, 1.0], 'shadows': strength}
    image, T_base_camera = render({'objects': [SHADE_BLOCK, SHADE_CUP], 'appearance': look}, np.random.default_rng(0))
    table_z = Scene().table.top_z
    observations = perception.observe_blocks(image, CAMERA, VisionConfig.from_yaml(), 0.04, 0.02, shape='square',
                                             colour='green',
                                             table_plane=table_plane_in_camera(T_base_camera, Plane.level(table_z)))
    posed = [T_base_camera @ o.pose.T_camera_object for o in observations if o.pose is not None]
    assert len(posed) == 1 and np.hypot(*(posed[0][:2, 3] - SHADE_BLOCK['xy'])) < 0.003


def test_a_square_whose_corner_half_lies_in_shadow_is_still_a_posed_square():
    """A green square seen straight down, with a soft-edged shadow over the half beyond its diagonal: the top-face
    stage keeps the lit triangle (what ``detect`` reports), yet ``observe_blocks`` asked for a square poses the
    whole blob as a square, where the same image without the shadow puts it (0.5 mm, 0.5 deg)."""
    camera = CameraModel(640, 400, [[400.0, 0.0, 320.0], [0.0, 400.0, 200.0], [0.0, 0.0, 1.0]])
    plane = Plane(np.array([0.0, 0.0, -1.0]), -0.32)               # the table, 2 cm below a top face 0.3 m away
    config = VisionConfig.from_yaml()
    u, v = np.meshgrid(np.arange(640), np.arange(400))
    poses = {}
    for strength in (0.0, 0.45):
        image = np.full((400, 640, 3), 90, np.uint8)
        corners = np.array([[292.8, 172.8], [346.2, 172.8], [346.2, 226.2], [292.8, 226.2]])  # 40 mm at 0.3 m
        cv2.fillPoly(image, [np.round(corners * 16).astype(np.int32)], (40, 170, 40), cv2.LINE_AA, shift=4)
        shade = 1.0 - strength * np.clip(((u - 320) + (v - 200)) / 6.0 + 0.5, 0.0, 1.0)   # a 6 px penumbra
        noise = np.random.default_rng(0).normal(0, 1.0, image.shape)
        image = np.clip(image * shade[:, :, None] + noise, 0, 255).astype(np.uint8)
        expected = 'square' if strength == 0 else 'triangle'
        assert [(d.shape, d.colour) for d in detect(image, config)] == [(expected, 'green')]
        observations = perception.observe_blocks(image, camera, config, 0.04, 0.02, shape='square', colour='green',
                                                 table_plane=plane)
        assert len(observations) == 1 and observations[0].pose is not None
        poses[strength] = observations[0].pose.T_camera_object
    np.testing.assert_allclose(poses[0.45][:3, 3], poses[0.0][:3, 3], atol=0.0005)
    angle = np.arccos(np.clip((np.trace(poses[0.45][:3, :3].T @ poses[0.0][:3, :3]) - 1) / 2, -1, 1))
    assert np.degrees(angle) < 0.5
