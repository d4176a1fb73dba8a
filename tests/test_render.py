"""Camera renderers (sim.render): OpenGL through EGL draws what PyBullet's TinyRenderer draws, follows the scene,
costs a fraction of it (also for the ``baxter`` look's textured table), and gives way to TinyRenderer where EGL
cannot run or a shape is one it cannot draw.

Images are compared pixel by pixel (mean absolute difference in grey levels, BGR) and by the centroid of the
green block's top face (px). The EGL parts skip, with the reason, on a machine where EGL cannot start.
"""
import dataclasses
import os
import subprocess
import sys

import cv2
import numpy as np
import pybullet as p
import pytest

from baxter_pnp.runtime import PACKAGE_ROOT
from baxter_pnp.sim import render
from baxter_pnp.sim.appearance import AppearanceConfig, expand, preset_look, table_texture
from baxter_pnp.sim.cameras import sensor_model, sensor_window
from baxter_pnp.sim.launcher import FakeBaxterProcess
from baxter_pnp.sim.scene import load_scene
from baxter_pnp.sim.world import SimWorld
from baxter_pnp.transforms import make_transform

CLEAN = preset_look('clean')     # TinyRenderer's look: no soft shadows, no motion blur

NO_EGL_ENV = {'__EGL_VENDOR_LIBRARY_FILENAMES': '/nonexistent/egl_vendor.json'}   # glvnd finds no EGL driver
FALLBACK_LOG = 'camera renderer: EGL not used'


def egl_problem():
    """Why EGL cannot run here, or '' if it can."""
    try:
        render.egl.shared_context()
    except render.RendererUnavailable as error:
        return str(error)
    return ''


needs_egl = pytest.mark.skipif(bool(egl_problem()), reason=f'EGL unavailable here: {egl_problem()}')


@pytest.fixture(scope='module')
def camera():
    """The fake's left hand camera at 640x400 (a centred window of the 1280x800 sensor, with distortion)."""
    return sensor_model('left_hand_camera').windowed(sensor_window(640, 400))


def green_top(image):
    """Boolean mask of the lit green top face of a block (BGR image)."""
    hsv = cv2.cvtColor(image, cv2.COLOR_BGR2HSV)
    return (hsv[:, :, 0] > 45) & (hsv[:, :, 0] < 75) & (hsv[:, :, 1] > 100) & (hsv[:, :, 2] > 150)


def centroid(mask):
    """(u, v) px centroid of a boolean mask."""
    rows, columns = np.nonzero(mask)
    return np.array([columns.mean(), rows.mean()])


def mean_abs_difference(a, b):
    return float(np.abs(a.astype(np.int16) - b.astype(np.int16)).mean())


def process_cpu_seconds():
    """CPU seconds used by this process so far, all its threads (the rasteriser's too)."""
    with open('/proc/self/stat') as f:
        fields = f.read().rsplit(')', 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf('SC_CLK_TCK')


def cpu_per_frame(world, camera, frames=5, repeats=3):
    """CPU seconds of this process per ``world.render_camera`` of ``camera`` (noise-free): the least of
    ``repeats`` runs of ``frames`` frames (another process's load makes the rasteriser's threads wait and spin)."""
    world.render_camera('left_hand_camera', camera)
    runs = []
    for _ in range(repeats):
        started = process_cpu_seconds()
        for _ in range(frames):
            world.render_camera('left_hand_camera', camera)
        runs.append((process_cpu_seconds() - started) / frames)
    return min(runs)


@needs_egl
@pytest.mark.parametrize('start', ['down', 'angled'])
def test_egl_draws_the_hand_camera_as_tinyrenderer_does_for_a_tenth_of_the_cpu(camera, start):
    """Two worlds of the default scene under the ``clean`` look, one per renderer: same image (incl. lens
    distortion), same block."""
    scene = dataclasses.replace(load_scene(), start=start, appearance=CLEAN)
    worlds = {kind: SimWorld(scene, renderer=kind) for kind in ('tiny', 'egl')}
    try:
        assert {kind: world.renderer_name for kind, world in worlds.items()} == {'tiny': 'tiny', 'egl': 'egl'}
        images = {kind: world.render_camera('left_hand_camera', camera) for kind, world in worlds.items()}
        # measured 0.000 (down) and 0.001 (angled): a handful of silhouette pixels where the two rasterisers
        # break ties differently; the margin allows a few hundred such pixels, not a shading or colour change
        assert mean_abs_difference(images['tiny'], images['egl']) < 0.05
        # the same 8-bit arithmetic: measured 0 and 1e-5 of the pixels differ at all (off by one grey level where
        # the shading is computed a hair differently would touch most of the image)
        assert np.mean(np.any(images['tiny'] != images['egl'], axis=2)) < 0.001
        masks = {kind: green_top(image) for kind, image in images.items()}
        assert masks['tiny'].sum() > 500
        # measured equal masks: the same pixels; a half-pixel convention error would move the centroid 0.5 px
        assert masks['egl'].sum() == pytest.approx(masks['tiny'].sum(), rel=0.005)
        assert np.hypot(*(centroid(masks['egl']) - centroid(masks['tiny']))) < 0.05
        # measured 7-9 ms against 75-80 ms a frame (with remap) alone; under the suite's other worker once 26
        # against 56 ms (one run of 5 frames each). Half leaves room for that contention and still fails if the
        # frames came from TinyRenderer (a ratio of 1)
        assert cpu_per_frame(worlds['egl'], camera) < 0.5 * cpu_per_frame(worlds['tiny'], camera)
    finally:
        for world in worlds.values():
            world.close()


@needs_egl
@pytest.mark.parametrize('start', ['down', 'angled'])
def test_egl_draws_the_baxter_look_textured_table_as_tinyrenderer_does(camera, start, monkeypatch):
    """``appearance: baxter`` (the table a speckle texture): 'auto' picks EGL, which samples the texture as
    TinyRenderer does (PyBullet's box texture coordinates, the image flipped, nearest texel), for a fraction of
    its CPU. Whole noise-free camera images (the look's exposure, white balance and vignetting)."""
    monkeypatch.delenv(render.RENDERER_ENV, raising=False)
    # shadows and motion blur aside (TinyRenderer draws shadows its own way; tests/test_shadows_blur_props.py)
    look = dataclasses.replace(AppearanceConfig.from_dict(expand('baxter')), shadows=0.0, exposure_time=0.0)
    scene = dataclasses.replace(load_scene(), start=start, appearance=look)
    worlds = {kind: SimWorld(scene, renderer=kind) for kind in ('tiny', 'auto')}
    try:
        assert worlds['auto'].renderer_name == 'egl'
        images = {kind: world.render_camera('left_hand_camera', camera) for kind, world in worlds.items()}
        table = images['tiny'][250:, :, 1].astype(float)          # below the block: table only
        # the speckle shows: mean step between neighbouring pixels measured 0.69 (0.09 for a flat table, vignetting)
        assert np.abs(np.diff(table, axis=1)).mean() > 0.3
        # measured 0.0002 (down) and 0.0007 (angled), 0.01-0.02 % of the pixels: texels split differently where a
        # pixel centre falls on a texel edge, and silhouettes. The margin allows a few hundred such pixels; a flat
        # table, or the texture flipped, shifted or sampled at another scale, costs 8-13 grey levels.
        assert mean_abs_difference(images['tiny'], images['auto']) < 0.05
        assert np.mean(np.any(images['tiny'] != images['auto'], axis=2)) < 0.001
        # measured 18-24 ms against 92-100 ms a frame (load average 3-8 on 2 cores; the look's image formation,
        # ~10 ms, in both): half leaves room for contention and still fails if TinyRenderer drew the frames
        assert cpu_per_frame(worlds['auto'], camera) < 0.5 * cpu_per_frame(worlds['tiny'], camera)
    finally:
        for world in worlds.values():
            world.close()


@needs_egl
def test_egl_draws_the_chessboard_as_tinyrenderer_does(camera):
    """config/scenes/hand_eye.yaml (a chessboard: a white box and a mesh of black quads on it; 2 x 2 samples a
    pixel): the same image of the board from both renderers.

    Only below the fingers (rows 150 on), where the board lies: the scene's camera error turns the camera so
    that the top rows show a part of the hand next to the lens, which TinyRenderer draws as a dark band across
    the image and EGL does not (3.8 grey levels over the whole image; not the board's doing)."""
    scene = dataclasses.replace(load_scene(os.path.join(PACKAGE_ROOT, 'config', 'scenes', 'hand_eye.yaml')),
                                appearance=CLEAN)
    worlds = {kind: SimWorld(scene, renderer=kind) for kind in ('tiny', 'egl')}
    try:
        images = {kind: world.render_camera('left_hand_camera', camera)[150:] for kind, world in worlds.items()}
        assert np.sum(images['tiny'].max(axis=2) < 40) > 15000          # the 35 black squares
        # measured 0.002 grey levels and 0.02 % of the pixels: a few edge pixels where the rasterisers differ
        assert mean_abs_difference(images['tiny'], images['egl']) < 0.05
        assert np.mean(np.any(images['tiny'] != images['egl'], axis=2)) < 0.002
    finally:
        for world in worlds.values():
            world.close()


@needs_egl
def test_egl_follows_the_scene_and_draws_the_arm_as_tinyrenderer_does():
    """A view of the robot (cylinders, boxes, the block); then a moved block, a recoloured link, a moved arm and
    a body added after the renderer was made: each drawn by both renderers alike."""
    world = SimWorld(dataclasses.replace(load_scene(), start='angled', appearance=CLEAN), renderer='egl')
    meshes = world._renderer._meshes
    tiny, egl = render.TinyRenderer(world._client), render.EglRenderer(world._client, meshes)
    ideal = sensor_model('front').windowed(sensor_window(640, 400)).scaled(320, 200)
    # optical frame 1.8 m in front of the robot, looking back at it (z toward -x base, y down)
    T_base_camera = make_transform(np.column_stack([[0, 1, 0], [0, 0, -1], [-1, 0, 0]]).astype(float),
                                   [1.8, 0.2, 0.3])
    try:
        def difference():
            return mean_abs_difference(tiny.render(T_base_camera, ideal), egl.render(T_base_camera, ideal))
        before = egl.render(T_base_camera, ideal)
        # measured 0.15: the cylinders' silhouettes (the two tessellate their rims alike, but the hulls' triangles
        # differ); a missing link or a wrong colour costs several grey levels
        assert difference() < 0.5
        world.place_object(0, (0.75, 0.35), 0.3)
        p.changeVisualShape(world._robot, world._links['left_upper_elbow'], rgbaColor=[0.1, 0.2, 0.9, 1.0],
                            physicsClientId=world._client)
        world.command_arm_positions('left', {'left_s0': 0.4, 'left_e1': 1.2}, speed_ratio=1.0)
        world.step(240)
        box = p.createVisualShape(p.GEOM_BOX, halfExtents=[0.05, 0.05, 0.05], rgbaColor=[0.9, 0.6, 0.1, 1.0],
                                  physicsClientId=world._client)
        p.createMultiBody(0.0, -1, box, [0.6, -0.2, 0.1], physicsClientId=world._client)
        after = egl.render(T_base_camera, ideal)
        assert mean_abs_difference(before, after) > 2.0       # the changes show
        assert difference() < 0.5
    finally:
        egl.close()
        world.close()


@needs_egl
def test_shapes_egl_does_not_draw_go_to_tinyrenderer(camera, caplog, monkeypatch):
    """A texture on a body that is not a box (the robot): 'auto' picks TinyRenderer, 'egl' refuses; on the table
    'auto' picks EGL. A sphere added to the scene later: TinyRenderer draws the frames from then on, said once
    in the log."""
    monkeypatch.delenv(render.RENDERER_ENV, raising=False)
    world = SimWorld(load_scene(), renderer='egl')
    try:
        meshes, image = world._renderer._meshes, table_texture(AppearanceConfig.from_dict(expand('baxter')), 64)
        with pytest.raises(render.RendererUnavailable, match='textures on boxes only'):
            render.make_renderer('egl', world._client, meshes, textures={world._robot: image})
        for body, expected in ((world._robot, 'tiny'), (world._table, 'egl')):
            renderer = render.make_renderer('auto', world._client, meshes, textures={body: image})
            assert renderer.name == expected
            renderer.close()
        sphere = p.createVisualShape(p.GEOM_SPHERE, radius=0.02, rgbaColor=[0.9, 0.1, 0.1, 1.0],
                                     physicsClientId=world._client)
        T_camera = world.link_pose('left_hand_camera')
        p.createMultiBody(0.0, -1, sphere, (T_camera @ [0.0, 0.0, 0.2, 1.0])[:3], physicsClientId=world._client)
        with caplog.at_level('WARNING', logger=render.__name__):
            images = [world.render_camera('left_hand_camera', camera) for _ in range(2)]
        assert len([r for r in caplog.records if 'switching from EGL to TinyRenderer' in r.message]) == 1
        assert world.renderer_description == 'PyBullet TinyRenderer'
        red = (images[1][:, :, 2] > 150) & (images[1][:, :, 1] < 60)
        assert red.sum() > 1000                 # the sphere, 20 cm in front of the lens
    finally:
        world.close()


def test_without_egl_auto_uses_tinyrenderer_with_one_log_line_and_egl_is_refused():
    """A machine without an EGL driver (glvnd pointed at none): 'auto' gives TinyRenderer, logged once per
    process; 'egl' raises; BAXTER_PNP_RENDERER=tiny makes 'auto' TinyRenderer without trying EGL."""
    code = ('from baxter_pnp.sim.scene import load_scene\n'
            'from baxter_pnp.sim.world import SimWorld\n'
            'from baxter_pnp.sim.render import RendererUnavailable\n'
            'print("renderers", SimWorld(load_scene()).renderer_name, SimWorld(load_scene()).renderer_name)\n'
            'try:\n'
            '    SimWorld(load_scene(), renderer="egl")\n'
            'except RendererUnavailable as error:\n'
            '    print("refused", error)\n')
    done = subprocess.run([sys.executable, '-c', code], env={**os.environ, **NO_EGL_ENV}, capture_output=True,
                          text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    assert 'renderers tiny tiny' in done.stdout and 'refused no EGL display' in done.stdout
    assert done.stderr.count(FALLBACK_LOG) == 1
    forced = subprocess.run([sys.executable, '-c', code.replace('    SimWorld(load_scene(), renderer="egl")',
                                                                '    pass')],
                            env={**os.environ, render.RENDERER_ENV: 'tiny'}, capture_output=True, text=True,
                            timeout=120)
    assert 'renderers tiny tiny' in forced.stdout and FALLBACK_LOG not in forced.stderr


def test_the_fake_refuses_renderer_egl_where_egl_cannot_run(tmp_path, monkeypatch):
    """``fake_baxter.py --renderer egl`` on a machine without EGL exits 2 before touching ROS, saying why."""
    for key, value in NO_EGL_ENV.items():
        monkeypatch.setenv(key, value)
    process = FakeBaxterProcess(None, ['--renderer', 'egl'], log_path=tmp_path / 'fake.log')
    assert process.run_to_exit() == 2
    assert 'fake_baxter: error: --renderer egl: no EGL display' in process.log()
