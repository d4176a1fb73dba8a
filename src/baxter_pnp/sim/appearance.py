"""How the fake's camera images look: the scene key ``appearance`` and the image formation applied to each render.

``appearance: baxter``, the default (``DEFAULT_PRESET``), is measured on real Baxter hand-camera frames
(``../shared/real/baxter_hand_a``, ``baxter_hand_b``; ``bench/appearance_stats.py`` prints real and rendered
statistics side by side): a grey table in dim light, vignetting, a slight colour cast, noise in every channel, soft
shadows and motion blur; ``appearance: clean`` is the look the fake first had (a light table, full light, noise of
2 grey levels per channel). A mapping overrides a preset's keys: ``appearance: {preset: clean, exposure: 0.4}``
(without ``preset``: the default's). ``random_appearance`` draws a look for domain randomisation
(``run_trials.py --appearance random``). Pure (numpy, OpenCV): the world renders, then ``form_image`` turns the
render into the camera's image.
"""
import functools
import math
from dataclasses import dataclass
from typing import Tuple

import cv2
import numpy as np

from baxter_pnp.params import Parameters

MAX_EXPOSURE_TIME = 0.1        # s: the longest frame integration (a 10 fps camera's whole frame time)
DEFAULT_PRESET = 'baxter'      # the look of a scene without ``appearance``; a mapping without ``preset`` overrides it
PRESETS = {
    'clean': {},
    # Medians over the 35 real frames (bench/appearance_stats.py): table L* 25-36 at the image median, corners
    # at 0.45-0.65 of the centre, a blue-green cast (B/G 0.94-1.06, R/G 0.90-0.98 on grey), noise 1.1-1.3 grey
    # levels per channel after the camera's own processing.
    # Light, shadows and motion blur are estimates, not measurements: the frames show weak, soft shadows under the
    # laptop and the e-stop box from several ceiling lights, and smears of several pixels in frames taken while
    # the hand moved (baxter_image_130.jpg).
    'baxter': {'table_color': (0.42, 0.42, 0.42), 'table_texture': 0.12, 'exposure': 0.85,
               'white_balance': (0.94, 1.0, 1.0), 'vignetting': 0.5, 'noise_std': 0.9, 'colour_noise_std': 0.7,
               'light_direction': (0.2, -0.1, 1.0), 'shadows': 0.3, 'exposure_time': 0.02},
}


@dataclass(frozen=True)
class AppearanceConfig(Parameters):
    """``table_color`` RGB 0..1; ``table_texture``: relative contrast of the table's speckle (0 flat);
    ``exposure``: scales every intensity (light level x exposure x gain); ``white_balance``: gains on
    (R, G, B); ``vignetting``: brightness in the image corners relative to the optical centre (1 none, a
    cos^4-like fall-off); ``noise_std``: grey-level noise common to the three channels; ``colour_noise_std``:
    independent noise per channel (grey levels); ``light_direction``: toward the one directional light (base
    frame, any length; it shades every face); ``shadows``: the share of that light's direct part a shadowed
    surface loses (0 none; shadows are soft, cast by the arms, the blocks and the clutter; TinyRenderer draws
    its own hard ones of fixed strength); ``exposure_time``: s, how long a frame integrates light: the image
    is blurred along the hand's motion over that time (0 none)."""
    preset: str = 'clean'
    table_color: Tuple[float, float, float] = (0.86, 0.86, 0.84)
    table_texture: float = 0.0
    exposure: float = 1.0
    white_balance: Tuple[float, float, float] = (1.0, 1.0, 1.0)
    vignetting: float = 1.0
    noise_std: float = 0.0
    colour_noise_std: float = 2.0          # Gazebo's camera noise: 0.007 x 255
    light_direction: Tuple[float, float, float] = (0.4, -0.3, 1.0)      # sim.render.LIGHT
    shadows: float = 0.0
    exposure_time: float = 0.0

    def validate(self):
        self.require(self.preset in PRESETS, 'preset', 'must be one of %s' % ', '.join(PRESETS))
        self.require(all(0.0 <= c <= 1.0 for c in self.table_color), 'table_color', 'must be RGB in 0..1')
        self.require(0.0 <= self.table_texture <= 1.0, 'table_texture', 'must be in 0..1')
        self.require(self.exposure > 0.0, 'exposure', 'must be > 0')
        self.require(all(g > 0.0 for g in self.white_balance), 'white_balance', 'gains must be > 0')
        self.require(0.0 < self.vignetting <= 1.0, 'vignetting', 'must be in (0, 1]')
        self.require(self.noise_std >= 0.0 and self.colour_noise_std >= 0.0, 'noise_std', 'must be >= 0')
        self.require(len(self.light_direction) == 3 and self.light_direction[2] > 0, 'light_direction',
                     'must be [x, y, z] toward a light above the table (z > 0)')
        self.require(0.0 <= self.shadows <= 1.0, 'shadows', 'must be in 0..1')
        self.require(0.0 <= self.exposure_time <= MAX_EXPOSURE_TIME, 'exposure_time',
                     f'must be in 0..{MAX_EXPOSURE_TIME} s')

    def scales_intensity(self):
        """True if ``form_image`` changes a noise-free render (exposure, white balance or vignetting)."""
        return self.exposure != 1.0 or tuple(self.white_balance) != (1.0, 1.0, 1.0) or self.vignetting < 1.0



def expand(value):
    """The mapping of a scene's ``appearance`` value (a preset name, or a mapping of ``preset``, default
    ``DEFAULT_PRESET``, plus overrides): the preset's keys, overridden by the mapping's; other values are returned
    as they are (the parameter check names them)."""
    if isinstance(value, str):
        value = {'preset': value}
    if not isinstance(value, dict):
        return value
    preset = value.get('preset', DEFAULT_PRESET)
    return {'preset': preset, **PRESETS.get(preset, {}), **value}


def preset_look(name):
    """The ``AppearanceConfig`` of preset ``name`` ('clean', 'baxter')."""
    return AppearanceConfig.from_dict(expand(name))


def default_appearance():
    """The ``AppearanceConfig`` of a scene without an ``appearance`` key: the ``DEFAULT_PRESET`` look."""
    return preset_look(DEFAULT_PRESET)


# Ranges of random_appearance (uniform draws), each spanning clean..baxter and a bit beyond. The baxter values
# were measured on the 35 real hand-camera frames (docs/fake_baxter.md "Appearance"): table L* 25-36 at the image
# median, corners at 0.27-0.75 of the centre (medians 0.45, 0.65), grey's R/G 0.83-0.99 and B/G 0.93-1.10,
# noise 0.9-1.6 grey levels per channel.
TABLE_GREY_RANGE = (0.35, 0.90)          # table_color level, RGB 0..1: clean 0.86, baxter 0.42
TABLE_TINT = 0.02                        # +- per channel around the grey level (clean's blue is 0.02 low)
TABLE_TEXTURE_RANGE = (0.0, 0.15)        # relative speckle contrast: clean 0, baxter 0.12
EXPOSURE_RANGE = (0.6, 1.1)              # clean 1, baxter 0.85
WHITE_BALANCE_R_RANGE = (0.86, 1.04)     # red gain (green fixed at 1): clean 1, baxter 0.94, real R/G 0.83-0.99
WHITE_BALANCE_B_RANGE = (0.92, 1.10)     # blue gain: clean and baxter 1, real B/G 0.93-1.10
VIGNETTING_RANGE = (0.4, 1.0)            # corner / centre brightness: clean 1, baxter 0.5, real 0.27-0.75
NOISE_STD_RANGE = (0.0, 1.5)             # grey levels common to the channels: clean 0, baxter 0.9
COLOUR_NOISE_STD_RANGE = (0.5, 2.5)      # grey levels per channel: clean 2, baxter 0.7
LIGHT_ELEVATION_RANGE = (45.0, 88.0)     # deg above the table (any azimuth): clean 63, baxter 77
SHADOWS_RANGE = (0.0, 0.5)               # clean 0, baxter 0.3
EXPOSURE_TIME_RANGE = (0.0, 0.03)        # s: clean 0, baxter 0.02


def random_appearance(rng):
    """A random look: an ``appearance:`` mapping (every key but ``preset``; plain floats and lists, rounded to
    0.001, so it survives YAML) drawn uniformly from the ``*_RANGE`` constants with ``rng`` (a
    ``numpy.random.Generator``); the same generator state gives the same look."""
    def draw(bounds):
        return round(float(rng.uniform(*bounds)), 3)
    grey = draw(TABLE_GREY_RANGE)
    table = [round(min(1.0, max(0.0, grey + float(rng.uniform(-TABLE_TINT, TABLE_TINT)))), 3) for _ in range(3)]
    look = {'table_color': table, 'table_texture': draw(TABLE_TEXTURE_RANGE), 'exposure': draw(EXPOSURE_RANGE),
            'white_balance': [draw(WHITE_BALANCE_R_RANGE), 1.0, draw(WHITE_BALANCE_B_RANGE)],
            'vignetting': draw(VIGNETTING_RANGE), 'noise_std': draw(NOISE_STD_RANGE),
            'colour_noise_std': draw(COLOUR_NOISE_STD_RANGE)}
    # drawn after the keys above, so that a seed gives the looks of before plus light, shadows and blur
    elevation, azimuth = math.radians(draw(LIGHT_ELEVATION_RANGE)), float(rng.uniform(-math.pi, math.pi))
    look['light_direction'] = [round(math.cos(elevation) * math.cos(azimuth), 3),
                               round(math.cos(elevation) * math.sin(azimuth), 3), round(math.sin(elevation), 3)]
    look['shadows'], look['exposure_time'] = draw(SHADOWS_RANGE), draw(EXPOSURE_TIME_RANGE)
    return look


def describe(value):
    """One-line label of a scene's ``appearance`` value: a preset name as it is, a mapping as ``key=value``
    pairs (sequences joined by '/', 3 significant digits), e.g. ``exposure=0.7 vignetting=0.55``."""
    if not isinstance(value, dict):
        return str(value)

    def text(v):
        if isinstance(v, (list, tuple)):
            return '/'.join(text(x) for x in v)
        return '%.3g' % v if isinstance(v, float) else str(v)
    return ' '.join(f'{key}={text(v)}' for key, v in value.items())


def table_texture(config, size=1024, seed=0):
    """(size, size, 3) uint8 RGB texture of the table: ``table_color`` with a speckle of relative contrast
    ``table_texture`` (grains of about 2 texels, 1-1.5 mm on the default table)."""
    rng = np.random.default_rng(seed)
    speckle = cv2.GaussianBlur(rng.standard_normal((size, size)).astype(np.float32), (0, 0), 1.2)
    speckle /= speckle.std()
    shade = 1.0 + config.table_texture * speckle
    rgb = np.asarray(config.table_color, np.float32)[None, None, :] * shade[:, :, None]
    return np.clip(rgb * 255.0 + 0.5, 0, 255).astype(np.uint8)


def vignetting_gain(camera, corner_brightness):
    """(H, W) float32 brightness factor of ``camera``'s pixels: 1 at the principal point, ``corner_brightness``
    at the farthest image corner, following cos^4 of the ray angle rescaled to that corner value."""
    if corner_brightness >= 1.0:
        return None
    u = (np.arange(camera.width, dtype=np.float32) - camera.cx) / camera.fx
    v = (np.arange(camera.height, dtype=np.float32) - camera.cy) / camera.fy
    r2 = u[None, :] ** 2 + v[:, None] ** 2
    cos4 = 1.0 / (1.0 + r2) ** 2
    corner = float(cos4.min())
    return (1.0 - (1.0 - cos4) / (1.0 - corner) * (1.0 - corner_brightness)).astype(np.float32)


def pixel_gain(camera, config):
    """(H, W, 3) float32 factor of each pixel and channel (B, G, R) of ``camera`` under ``config``: exposure x white
    balance x vignetting (``vignetting_gain``); None for a look that scales nothing (the clean one)."""
    if not config.scales_intensity():
        return None
    channels = np.float32(config.exposure) * np.asarray(config.white_balance[::-1], np.float32)
    vignette = vignetting_gain(camera, config.vignetting)
    if vignette is None:
        return np.tile(channels, (camera.height, camera.width, 1))
    return vignette[:, :, None] * channels


def form_image(render_bgr, config, camera, rng=None, gain=1.0, gains=None):
    """The camera's uint8 BGR image of a noise-free render: intensities x ``gains`` (``pixel_gain(camera, config)``,
    computed when None: callers cache it) x ``gain`` (a lighting fault), then noise from ``rng`` (none if None),
    rounded and clipped. Two passes over the image (OpenCV's saturating arithmetic): 1 ms at 640x400."""
    if gains is None:
        gains = pixel_gain(camera, config)
    if gains is None:
        value = render_bgr.astype(np.float32)
        if gain != 1:
            value *= np.float32(gain)
    else:
        value = cv2.multiply(render_bgr, gains, scale=float(gain), dtype=cv2.CV_32F)
    if rng is not None and (config.noise_std > 0 or config.colour_noise_std > 0):
        noise = _noise_bank(render_bgr.shape, config.noise_std, config.colour_noise_std).draw(rng)
        return cv2.add(value, noise, dtype=cv2.CV_8U)
    return cv2.add(value, 0.0, dtype=cv2.CV_8U)


class NoiseBank:
    """Sensor noise at a frame rate the fake can afford: ``FRAMES`` noise images (a part common to the channels,
    std ``common_std``, plus an independent part per channel, std ``colour_std``; grey levels), drawn once; each
    frame takes one of them, circularly shifted by a random offset (a view, no copy, instead of 13-18 ms for fresh
    normal draws at 640x400; neighbouring pixels stay independent). Each is stored tiled 2 x 2 (less a row and a
    column), so that every circular shift is a window of it."""
    FRAMES = 2

    def __init__(self, shape, common_std, colour_std, seed=0):
        rng = np.random.default_rng(seed)
        height, width, channels = shape
        frames = rng.standard_normal((self.FRAMES, height, width, channels), dtype=np.float32) * np.float32(colour_std)
        frames += rng.standard_normal((self.FRAMES, height, width, 1), dtype=np.float32) * np.float32(common_std)
        self.shape = (height, width, channels)
        self.tiles = np.tile(frames, (1, 2, 2, 1))[:, :2 * height - 1, :2 * width - 1]

    def draw(self, rng):
        """(H, W, C) float32 noise for one frame (a read-only view), chosen and shifted with ``rng``: frame
        ``index`` rolled by (dy, dx) rows and columns, as ``np.roll``."""
        height, width, _ = self.shape
        index, dy, dx = int(rng.integers(self.FRAMES)), int(rng.integers(height)), int(rng.integers(width))
        top, left = (height - dy) % height, (width - dx) % width
        return self.tiles[index, top:top + height, left:left + width]


_noise_bank = functools.lru_cache(maxsize=8)(NoiseBank)


MAX_BLUR_LEVELS = 4            # the smear is the mean of up to 2 ** 4 = 16 copies (one a pixel of the longest smear)


def motion_blur(image, camera, T_base_camera, T_base_camera_before, table_z, scene_alpha=None):
    """``image`` (uint8 (H, W, 3) of ``camera`` at ``T_base_camera``) smeared as if the shutter had opened with the
    camera at ``T_base_camera_before`` (the optical frame in ``base`` at the exposure's start and end, m): the mean
    of ``2 ** k`` copies of the image moved to camera poses evenly spaced along that motion (at most a pixel apart
    on the longest smear; ``k`` at most ``MAX_BLUR_LEVELS``), each by the homography of the table plane (``z =
    table_z`` in base; the blocks' few cm of parallax ignored). The mean is built by doubling: k times, the running
    mean and itself moved by the motion it spans (so ``k`` warps for ``2 ** k`` copies). ``scene_alpha`` ((H, W)
    uint8, 0 on the parts that ride with the camera, e.g. the fingers, 255 elsewhere) keeps those sharp and out of
    the smear of the rest. Unchanged when nothing in view moved 0.5 px. About 1 ms a level at 640x400, plus 1 ms."""
    height, width = image.shape[:2]
    corners = np.array([[0, 0], [width - 1, 0], [0, height - 1], [width - 1, height - 1], [width / 2, height / 2]],
                       np.float64)
    T_now_before = np.linalg.inv(T_base_camera) @ T_base_camera_before
    moved = cv2.perspectiveTransform(corners[None], _table_homography(camera, T_base_camera, T_base_camera_before,
                                                                      table_z))[0] - corners
    smear = float(np.max(np.linalg.norm(moved, axis=1)))
    if not math.isfinite(smear) or smear < 0.5:
        return image
    if scene_alpha is None:
        scene_alpha = np.full((height, width), 255, np.uint8)
    riding = cv2.compare(scene_alpha, 128, cv2.CMP_LT)                       # 255 where a riding part is
    levels = min(MAX_BLUR_LEVELS, max(1, math.ceil(math.log2(smear + 1.0))))
    spacing = 1.0 / (2 ** levels - 1)                                       # of the motion, between two copies
    mean = cv2.cvtColor(image, cv2.COLOR_BGR2BGRA)           # colour times the scene's share, the share in alpha
    cv2.subtract(mean, mean, dst=mean, mask=riding)
    for level in range(levels):          # mean of copies 0 .. 2^level - 1 and of the next 2^level of them
        T_base_then = T_base_camera @ scaled_motion(T_now_before, spacing * 2 ** level)
        H = _table_homography(camera, T_base_camera, T_base_then, table_z)      # now pixel -> pixel then
        mean = cv2.addWeighted(mean, 0.5, _warped(mean, H, corners), 0.5, 0.0)
    coverage = cv2.extractChannel(mean, 3)                                      # 255: every copy is of the scene
    smeared = cv2.cvtColor(mean, cv2.COLOR_BGRA2BGR)                            # all scene: the mean
    x, y, w, h = cv2.boundingRect(riding)           # a part riding shares the pixels it smears over, near it
    reach = math.ceil(smear) + 2
    x0, y0, x1, y1 = max(0, x - reach), max(0, y - reach), min(width, x + w + reach), min(height, y + h + reach)
    rows, columns = np.nonzero(cv2.inRange(coverage[y0:y1, x0:x1], 128, 254))    # there: the scene's share
    rows, columns = rows + y0, columns + x0
    weighted = mean[rows, columns, :3] * (255.0 / coverage[rows, columns])[:, None] + 0.5
    smeared[rows, columns] = np.minimum(weighted, 255.0).astype(np.uint8)
    keep = cv2.bitwise_or(riding, cv2.compare(coverage, 128, cv2.CMP_LT))      # riding parts stay sharp on top
    cv2.copyTo(image, keep, smeared)
    return smeared


def _warped(image, H, corners, tolerance_px=0.01):
    """``image`` warped by the homography ``H`` (its pixel -> the result's, ``H[2, 2]`` = 1; bilinear,
    border replicated): by its affine part where that moves none of ``corners`` ((N, 2) px: the image's) more than
    ``tolerance_px`` from where ``H`` does (a blur sample's small motion; a third cheaper), else by ``H``."""
    height, width = image.shape[:2]
    exact = cv2.perspectiveTransform(corners[None], H)[0]
    affine = corners @ H[:2, :2].T + H[:2, 2]
    if np.max(np.abs(exact - affine)) <= tolerance_px:
        return cv2.warpAffine(image, H[:2], (width, height), flags=cv2.INTER_LINEAR,
                              borderMode=cv2.BORDER_REPLICATE)
    return cv2.warpPerspective(image, H, (width, height), flags=cv2.INTER_LINEAR,
                               borderMode=cv2.BORDER_REPLICATE)


def _table_homography(camera, T_base_camera, T_base_camera_before, table_z):
    """3x3 homography from ``camera``'s pixels at ``T_base_camera`` to its pixels at ``T_base_camera_before`` of the
    points of the table plane ``z = table_z`` (base, m)."""
    T_before_now = np.linalg.inv(T_base_camera_before) @ T_base_camera
    normal = T_base_camera[:3, :3].T @ [0.0, 0.0, 1.0]             # the table's normal in the camera frame now
    distance = table_z - T_base_camera[2, 3]                         # its offset: normal . X = distance on it
    H = camera.K @ (T_before_now[:3, :3] + np.outer(T_before_now[:3, 3], normal) / distance) @ np.linalg.inv(camera.K)
    return H / H[2, 2]


def scaled_motion(T, fraction):
    """The rigid motion ``T`` (4x4) scaled to ``fraction``: its rotation's angle about the same axis and its
    translation, each times ``fraction`` (1: ``T``, 0: none)."""
    angle_axis, _ = cv2.Rodrigues(np.asarray(T[:3, :3], np.float64))
    scaled = np.eye(4)
    scaled[:3, :3], _ = cv2.Rodrigues(angle_axis * fraction)
    scaled[:3, 3] = fraction * np.asarray(T[:3, 3], float)
    return scaled
