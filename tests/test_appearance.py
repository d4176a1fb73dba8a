"""The fake camera's look (``sim.appearance``): presets and overrides as a scene key, the image formation
(exposure, white balance, vignetting, noise), a textured table, and the vision still finding the block."""
import dataclasses

import numpy as np
import pytest
import yaml

from baxter_pnp.sim import appearance
from baxter_pnp.sim.appearance import (PRESETS, AppearanceConfig, NoiseBank, describe, expand, form_image, pixel_gain,
                                       random_appearance, table_texture)
from baxter_pnp.sim.cameras import sensor_model, sensor_window
from baxter_pnp.sim.scene import Scene, SceneError, load_scene
from baxter_pnp.sim.world import SimWorld
from baxter_pnp.vision import detect
from baxter_pnp.vision.config import VisionConfig

CAMERA = sensor_model('left_hand_camera').windowed(sensor_window(640, 400))


def test_presets_overrides_and_errors_as_a_scene_key():
    baxter = AppearanceConfig.from_dict(expand('baxter'))
    assert baxter.preset == 'baxter' and baxter.vignetting < 1.0 and baxter.table_texture > 0
    assert load_scene().appearance == baxter == Scene().appearance              # the real hand camera's look
    assert AppearanceConfig.from_dict(expand('clean')) == AppearanceConfig()     # the fields' neutral values
    tuned = AppearanceConfig.from_dict(expand({'preset': 'baxter', 'exposure': 0.4}))
    assert tuned.exposure == 0.4 and tuned.vignetting == baxter.vignetting
    assert AppearanceConfig.from_dict(expand({'exposure': 0.4})) == tuned        # no preset: the default's keys
    assert AppearanceConfig.from_dict(expand({'preset': 'clean', 'exposure': 0.4})).vignetting == 1.0
    objects = [{'shape': 'square', 'side': 0.04, 'color': [0.1, 0.7, 0.1], 'xy': [0.7, 0.25]}]
    assert Scene.from_dict({'objects': objects, 'appearance': 'baxter'}).appearance == baxter
    for value, key in (('sunny', 'appearance.preset'), ({'exposure': -1.0}, 'appearance.exposure'),
                       ({'vignetting': 1.5}, 'appearance.vignetting'), (3, 'appearance')):
        with pytest.raises(SceneError, match=key):
            Scene.from_dict({'objects': objects, 'appearance': value})


def test_random_looks_are_valid_scenes_reproducible_per_seed_and_span_clean_to_baxter_and_beyond():
    looks = [random_appearance(np.random.default_rng(seed)) for seed in range(300)]
    assert random_appearance(np.random.default_rng(7)) == looks[7] != looks[8]
    objects = [{'shape': 'square', 'side': 0.04, 'color': [0.1, 0.7, 0.1], 'xy': [0.7, 0.25]}]
    for look in looks:
        assert yaml.safe_load(yaml.safe_dump(look)) == look                    # plain types: a scene file holds it
        config = Scene.from_dict({'objects': objects, 'appearance': look}).appearance    # validated
        assert config.table_color == tuple(look['table_color']) and config.white_balance[1] == 1.0
    assert 'exposure=' in describe(looks[0]) and describe('baxter') == 'baxter'
    clean, baxter = AppearanceConfig(), AppearanceConfig.from_dict(expand('baxter'))
    grey = [np.mean(look['table_color']) for look in looks]
    tint = [np.ptp(look['table_color']) for look in looks]
    assert max(tint) <= 2 * appearance.TABLE_TINT + 0.002
    drawn = {'table grey': (grey, appearance.TABLE_GREY_RANGE, clean.table_color[0], baxter.table_color[0]),
             'white balance R': ([look['white_balance'][0] for look in looks], appearance.WHITE_BALANCE_R_RANGE,
                                 clean.white_balance[0], baxter.white_balance[0]),
             'white balance B': ([look['white_balance'][2] for look in looks], appearance.WHITE_BALANCE_B_RANGE,
                                 clean.white_balance[2], baxter.white_balance[2])}     # both 1: a cast either way
    for key, bounds in (('table_texture', appearance.TABLE_TEXTURE_RANGE), ('exposure', appearance.EXPOSURE_RANGE),
                        ('vignetting', appearance.VIGNETTING_RANGE), ('noise_std', appearance.NOISE_STD_RANGE),
                        ('colour_noise_std', appearance.COLOUR_NOISE_STD_RANGE)):
        drawn[key] = ([look[key] for look in looks], bounds, getattr(clean, key), getattr(baxter, key))
    for key, (values, (low, high), *presets) in drawn.items():
        width = high - low
        assert low - 0.02 <= min(values) < low + 0.05 * width and high - 0.05 * width < max(values) <= high + 0.02, key
        assert low <= min(presets) and max(presets) <= high, key                  # spans clean..baxter
        assert min(values) < min(presets) or max(values) > max(presets), key     # and a bit beyond
    assert PRESETS['baxter']['table_color'][0] > appearance.TABLE_GREY_RANGE[0]   # darker tables than baxter's too


def test_image_formation_exposure_white_balance_vignetting_and_noise():
    flat = np.full((CAMERA.height, CAMERA.width, 3), 200, np.uint8)
    clean = AppearanceConfig()
    assert not clean.scales_intensity()
    np.testing.assert_array_equal(form_image(flat, clean, CAMERA), flat)
    dim = AppearanceConfig(exposure=0.5, white_balance=(1.0, 1.0, 0.8))      # (R, G, B) gains
    b, g, r = form_image(flat, dim, CAMERA)[0, 0]
    assert (b, g, r) == (80, 100, 100)
    vignetted = AppearanceConfig(vignetting=0.5)
    image = form_image(flat, vignetted, CAMERA, gains=pixel_gain(CAMERA, vignetted)).astype(float)
    centre = image[int(round(CAMERA.cy)), int(round(CAMERA.cx)), 1]
    corners = image[[0, 0, -1, -1], [0, -1, 0, -1], 1]
    assert centre == 200 and corners.min() == pytest.approx(100, abs=1) and corners.max() < 200 * 0.8
    noisy = form_image(np.full((400, 640, 3), 100, np.uint8), AppearanceConfig(noise_std=1.5, colour_noise_std=2.0),
                       CAMERA, rng=np.random.default_rng(0)).astype(float) - 100
    assert noisy.std(axis=(0, 1)) == pytest.approx([2.5] * 3, rel=0.05)      # sqrt(1.5^2 + 2^2) per channel
    covariance = np.cov(noisy[..., 0].ravel(), noisy[..., 1].ravel())[0, 1]
    assert covariance == pytest.approx(1.5 ** 2, rel=0.1)                  # the common part is shared


def test_a_noise_draw_is_a_stored_frame_circularly_shifted():
    bank = NoiseBank((40, 64, 3), 1.0, 2.0)
    frames = bank.tiles[:, :40, :64]
    for seed in range(20):
        rng, twin = np.random.default_rng(seed), np.random.default_rng(seed)
        index, dy, dx = twin.integers(bank.FRAMES), twin.integers(40), twin.integers(64)
        np.testing.assert_array_equal(bank.draw(rng), np.roll(frames[index], (dy, dx), axis=(0, 1)))


def test_table_texture_has_the_colour_and_contrast_asked():
    texture = table_texture(AppearanceConfig(table_color=(0.4, 0.4, 0.4), table_texture=0.1), size=256)
    assert texture.shape == (256, 256, 3)
    assert texture.mean() == pytest.approx(0.4 * 255, abs=1.0)
    assert texture.std() / texture.mean() == pytest.approx(0.1, rel=0.1)


@pytest.mark.parametrize('start', ['down', 'angled'])
def test_the_baxter_look_is_dim_textured_and_the_block_is_still_found_where_it_lies(start):
    """The default scene under ``baxter`` and ``clean``: the baxter frame is darker (the real frames' median
    L* is 25-36, the clean one's 85), its table textured, its corners darker; the vision finds the one green
    square at the same place in both (0.5 px)."""
    frames = {}
    for look in ('clean', 'baxter'):
        scene = dataclasses.replace(load_scene(), start=start, appearance=AppearanceConfig.from_dict(expand(look)))
        world = SimWorld(scene)
        try:
            frames[look] = world.render_camera('left_hand_camera', CAMERA, np.random.default_rng(1))
        finally:
            world.close()
    grey = {look: frame.astype(float).mean(axis=2) for look, frame in frames.items()}
    table = (slice(250, 390), slice(40, 600))           # below the block and the fingers
    assert grey['baxter'][table].mean() < 0.5 * grey['clean'][table].mean()
    assert grey['baxter'][table].std() > 2 * grey['clean'][table].std()       # texture beyond the noise
    assert grey['baxter'][-20:, :20].mean() < 0.75 * grey['baxter'][table].mean()   # vignetting
    config = VisionConfig.from_yaml()
    found = {look: detect(frame, config) for look, frame in frames.items()}
    assert [(d.shape, d.colour) for d in found['baxter']] == [('square', 'green')]
    assert len(found['clean']) == 1
    np.testing.assert_allclose(found['baxter'][0].centroid_px, found['clean'][0].centroid_px, atol=0.5)
