"""Ground-truth images of polygonal blocks and chessboards seen by a known (distorted) camera.

Used by the tests and the perception benchmark. Geometry is exact; the picture is made realistic:

1. convex faces (camera optical frame, metres) are rasterised by pixel-centre sampling into a
   supersampled ideal pinhole camera (same focal length, a margin so that every ray of the real
   camera is covered), with back-face culling and painter's order (far blocks first);
2. area downsampling (antialiasing) to the ideal camera's resolution, composited over the
   background (table colour, or the table plane ``T_camera_table`` with a darker area beyond its horizon);
3. ``cv2.remap`` with ``CameraModel.rendering_maps`` into the distorted camera image;
4. a linear lighting gradient across the image, gaussian blur, gaussian noise, JPEG encode/decode.

Faces are Lambertian-shaded by a directional light fixed to the table (a ceiling light): it keeps
its direction relative to the surface the objects lie on, however the camera looks at it. So the
top of a block is always the brightest face and its side faces have its hue but are darker.
The block frame is the one of docs/ARCHITECTURE.md (origin at the top-face centre, +z up,
vertex k at angle ``pi/n + 2 pi k / n``). Pixels are (u, v), distorted, origin at the top-left pixel centre.
"""
import functools
from dataclasses import dataclass

import cv2
import numpy as np
from scipy.spatial.transform import Rotation

from baxter_pnp import models
from baxter_pnp.camera import CameraModel, load_default_camera
from baxter_pnp.transforms import make_transform, transform_points

AMBIENT = 0.3                 # fraction of a face's colour lit by ambient light
WALL_SHADE = 0.5              # brightness of what lies beyond the table's horizon, relative to the table
MIN_DEPTH = 1e-3              # m; faces with a vertex closer to the camera plane are not drawn


@dataclass
class BlockSpec:
    """A regular prism block: ``shape`` (a key of ``models.SHAPES``), ``side`` and ``height`` in metres, BGR albedo."""
    shape: str
    side: float
    height: float = 0.02
    colour_bgr: tuple = (40, 170, 40)

    def __post_init__(self):
        models.model_for(self.shape, self.side, self.height)     # ValueError on a bad shape or size

    @property
    def model(self):
        """The block's ``models.PolygonModel``."""
        return models.model_for(self.shape, self.side, self.height)

    def top_vertices(self):
        """(n, 3) top-face vertices in the block frame (metres), counter-clockwise about +z."""
        return self.model.vertices

    def faces(self):
        """[(vertices (m, 3), outward normal (3,))] of the prism in the block frame; the top face first."""
        top = self.top_vertices()
        bottom = top - [0.0, 0.0, self.height]
        faces = [(top, np.array([0.0, 0.0, 1.0])), (bottom[::-1], np.array([0.0, 0.0, -1.0]))]
        n = len(top)
        for k in range(n):
            j = (k + 1) % n
            mid = (top[k] + top[j]) / 2.0
            faces.append((np.array([top[k], bottom[k], bottom[j], top[j]]), mid / np.linalg.norm(mid)))
        return faces

    def corners(self):
        """(2n, 3) all prism vertices in the block frame."""
        top = self.top_vertices()
        return np.vstack([top, top - [0.0, 0.0, self.height]])


@dataclass(frozen=True)
class ImageEffects:
    """Appearance settings shared by the renderers (colours BGR 0-255, sigmas in pixels)."""
    table_bgr: tuple = (225, 225, 220)
    lighting_gradient: float = 0.25          # peak-to-peak relative brightness change across the image
    light_dir_camera: tuple = (0.3, -0.4, -1.0)  # towards the light (camera frame) when the table faces the camera
    noise_sigma: float = 2.0                 # grey levels
    blur_sigma: float = 0.6
    jpeg_quality: int = 90                   # None or 0: no JPEG round trip
    supersample: int = 4
    T_camera_table: np.ndarray = None        # table plane (its +z up); None: uniform background


@dataclass
class _Face:
    """A convex polygon to draw: vertices in the camera frame (m), colour (BGR float), label (< 0: untracked)."""
    points_cam: np.ndarray
    colour: np.ndarray
    label: int = -1


def render_block_scene(camera, blocks, rng, **effects):
    """Image of blocks on a table, and their ground truth.

    ``blocks``: list of ``(BlockSpec, T_camera_block)``. ``effects``: fields of ``ImageEffects``.
    Returns ``(image_bgr uint8 (H, W, 3), truths)``; ``truths[i]`` (same order as ``blocks``) is a dict:
    ``vertices_px`` (n, 2) distorted pixels of the top-face vertices in model order, ``centroid_px``
    (2,) the projection of the top-face centre, ``T_camera_block`` (4x4), ``visible`` (the top face
    faces the camera, all its vertices are inside the image and no other block hides it).
    """
    settings = ImageEffects(**effects)
    order = sorted(range(len(blocks)), key=lambda i: -np.linalg.norm(blocks[i][1][:3, 3]))
    faces, top_facing = [], {}
    for i in order:
        spec, T_camera_block = blocks[i]
        albedo = np.asarray(spec.colour_bgr, dtype=float)
        surface = settings.T_camera_table if settings.T_camera_table is not None else T_camera_block
        light = _light_in_camera(surface, settings.light_dir_camera)
        for k, (vertices, normal) in enumerate(spec.faces()):
            points = transform_points(T_camera_block, vertices)
            normal_cam = T_camera_block[:3, :3] @ normal
            facing = float(normal_cam @ points[0]) < 0.0
            if k == 0:
                top_facing[i] = facing
            if facing:
                faces.append(_Face(points, albedo * _brightness(normal_cam, light), i + 1 if k == 0 else -1))
    image, coverage = _render(camera, faces, rng, settings)
    truths = []
    for i, (spec, T_camera_block) in enumerate(blocks):
        vertices_px = camera.project(transform_points(T_camera_block, spec.top_vertices()))
        drawn, seen = coverage.get(i + 1, (0, 0))
        inside = np.all((vertices_px >= 0) & (vertices_px <= [camera.width - 1, camera.height - 1]))
        truths.append({
            'vertices_px': vertices_px,
            'centroid_px': camera.project(T_camera_block[:3, 3])[0],
            'T_camera_block': np.array(T_camera_block, dtype=float),
            'visible': bool(top_facing[i] and inside and drawn > 0 and seen >= 0.995 * drawn),
        })
    return image, truths


def render_chessboard(camera, T_camera_board, rng, pattern=(9, 6), square=0.030, **effects):
    """Image of a chessboard with ``pattern`` = (columns, rows) inner corners and ``square`` (m) squares.

    Board frame: origin at the first inner corner, x along the columns, y along the rows, z = 0 on
    the board (OpenCV's calibration object points ``(i * square, j * square, 0)``); one square of
    white margin surrounds the squares. The board's +z is its printed side's normal for shading (the
    light is fixed to the board as to a table). Returns ``(image_bgr, corners_px)`` with
    ``corners_px`` (columns * rows, 2) distorted pixels, row by row.
    """
    settings = ImageEffects(**effects)
    cols, rows = pattern
    shade = _brightness(T_camera_board[:3, 2], _light_in_camera(T_camera_board, settings.light_dir_camera))

    def quad(x0, y0, x1, y1):
        return transform_points(T_camera_board, [[x0, y0, 0], [x1, y0, 0], [x1, y1, 0], [x0, y1, 0]])

    faces = [_Face(quad(-2 * square, -2 * square, (cols + 1) * square, (rows + 1) * square),
                   np.full(3, 245.0 * shade))]
    for a in range(cols + 1):
        for b in range(rows + 1):
            if (a + b) % 2 == 0:
                x0, y0 = (a - 1) * square, (b - 1) * square
                faces.append(_Face(quad(x0, y0, x0 + square, y0 + square), np.full(3, 25.0 * shade)))
    image, _ = _render(camera, faces, rng, settings)
    grid = np.array([[i * square, j * square, 0.0] for j in range(rows) for i in range(cols)])
    return image, camera.project(transform_points(T_camera_board, grid))


def random_block_pose(rng, distance_range=(0.10, 0.40), max_tilt_deg=35.0, camera=None, margin_px=20,
                      block=None, max_tries=1000):
    """Random ``T_camera_block``: top-face centre at a random distance (m) along the ray of a random pixel.

    The pixel is at least ``margin_px`` from the border; when ``block`` (a BlockSpec) is given, every
    prism vertex is kept that far inside the image too. Tilt (angle between the block's +z and the
    camera's -z, i.e. away from fronto-parallel) is uniform on the spherical cap up to
    ``max_tilt_deg``; yaw about the block's +z is uniform. ``camera`` defaults to the thesis camera.
    """
    camera = camera if camera is not None else load_default_camera()
    low = np.array([margin_px, margin_px])
    high = np.array([camera.width - 1 - margin_px, camera.height - 1 - margin_px])
    facing_camera = Rotation.from_rotvec([np.pi, 0.0, 0.0])        # block +z = camera -z
    cos_max = np.cos(np.radians(max_tilt_deg))
    for _ in range(max_tries):
        ray = np.append(camera.undistort_points(rng.uniform(low, high))[0], 1.0)
        position = _unit(ray) * rng.uniform(*distance_range)
        azimuth, yaw = rng.uniform(0.0, 2.0 * np.pi, size=2)
        tilt = np.arccos(rng.uniform(cos_max, 1.0))
        tilt_rotation = Rotation.from_rotvec(tilt * np.array([np.cos(azimuth), np.sin(azimuth), 0.0]))
        rotation = tilt_rotation * facing_camera * Rotation.from_rotvec([0.0, 0.0, yaw])
        T_camera_block = make_transform(rotation, position)
        if block is None:
            return T_camera_block
        corners = transform_points(T_camera_block, block.corners())
        if np.all(corners[:, 2] > MIN_DEPTH):
            pixels = camera.project(corners)
            if np.all((pixels >= low) & (pixels <= high)):
                return T_camera_block
    raise ValueError(f'random_block_pose: no pose keeps the block {margin_px} px inside the image '
                     f'after {max_tries} tries (distance_range={distance_range})')


# --------------------------------------------------------------------------------------- renderer core

def _render(camera, faces, rng, settings):
    """Draw ``faces`` (painter's order) into ``camera``'s image with the effects; returns (image, coverage).

    ``coverage[label] = (supersampled pixels drawn, pixels still showing at the end)`` for labels > 0;
    label 0 marks "no face" in the label buffer, so faces need a non-zero label.
    """
    s = int(settings.supersample)
    ideal = _ideal_camera(camera)
    ideal_ss = ideal.scaled(ideal.width * s, ideal.height * s)
    canvas = _background(ideal, settings)
    polygons = [(ideal_ss.normalised_to_pixels(f.points_cam[:, :2] / f.points_cam[:, 2:]), f)
                for f in faces if np.all(f.points_cam[:, 2] > MIN_DEPTH)]
    coverage = {}
    if polygons:
        everything = np.vstack([p for p, _ in polygons])
        # the supersampled patch holding every face, aligned to whole ideal pixels
        x0, y0 = np.maximum(np.floor(everything.min(axis=0) / s).astype(int), 0)
        x1, y1 = np.minimum(np.ceil((everything.max(axis=0) + 1) / s).astype(int), [ideal.width, ideal.height])
        if x1 > x0 and y1 > y0:
            colour = np.zeros(((y1 - y0) * s, (x1 - x0) * s, 3), np.float32)
            labels = np.zeros(colour.shape[:2], np.int16)
            drawn = {}
            for pixels, face in polygons:
                count = _fill_convex(colour, labels, pixels - [x0 * s, y0 * s], face.colour, face.label)
                if face.label > 0:
                    drawn[face.label] = count
            coverage = {label: (count, int(np.count_nonzero(labels == label))) for label, count in drawn.items()}
            size = (x1 - x0, y1 - y0)
            premultiplied = cv2.resize(colour, size, interpolation=cv2.INTER_AREA)
            alpha = cv2.resize((labels != 0).astype(np.float32), size, interpolation=cv2.INTER_AREA)[..., None]
            region = canvas[y0:y1, x0:x1]
            region *= 1.0 - alpha
            region += premultiplied
    map_x, map_y = camera.rendering_maps(ideal)
    image = cv2.remap(canvas, map_x, map_y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    return _camera_effects(image, rng, settings), coverage


def _fill_convex(colour, labels, pixels, bgr, label):
    """Paint the convex polygon ``pixels`` (m, 2) into ``colour``/``labels``; returns the pixel count.

    A pixel is inside when its centre is strictly inside every edge's half-plane (centres are
    nudged by 1e-7 px so that a centre exactly on an edge shared by two polygons goes to one of
    them), so coverage is unbiased. Each edge bounds u from below or above on every row, or (if
    horizontal) keeps or drops whole rows.
    """
    area2 = np.cross(pixels - pixels[0], np.roll(pixels, -1, axis=0) - pixels[0]).sum()
    if abs(area2) < 1e-9:
        return 0
    h, w = labels.shape
    x0, y0 = np.maximum(np.floor(pixels.min(axis=0)).astype(int), 0)
    x1, y1 = np.minimum(np.ceil(pixels.max(axis=0)).astype(int) + 1, [w, h])
    if x1 <= x0 or y1 <= y0:
        return 0
    v = np.arange(y0, y1) + 1e-7
    low, high = np.full(len(v), -np.inf), np.full(len(v), np.inf)
    orientation = np.sign(area2)
    for (ax, ay), (bx, by) in zip(pixels, np.roll(pixels, -1, axis=0)):
        # inside: orientation * ((bx - ax) (v - ay) - (by - ay) (u - ax)) > 0
        dy = orientation * (by - ay)
        if dy == 0.0:                     # horizontal edge: rows on its outer side are empty
            high[orientation * (bx - ax) * (v - ay) <= 0] = -np.inf
            continue
        crossing = ax + (bx - ax) * (v - ay) / (by - ay)
        if dy > 0:
            np.minimum(high, crossing, out=high)
        else:
            np.maximum(low, crossing, out=low)
    # first and one-past-last pixel column of each row: low < u + 1e-7 < high
    first = np.clip(np.floor(low - 1e-7) + 1, x0, x1).astype(int)
    stop = np.clip(np.ceil(high - 1e-7), x0, x1).astype(int)
    count = 0
    for row, a, b in zip(range(y0, y1), first, stop):
        if b > a:
            colour[row, a:b] = bgr
            labels[row, a:b] = label
            count += b - a
    return count


def _background(ideal, settings):
    """Float32 background in the ideal camera: the table colour, darker beyond the table's horizon."""
    canvas = _uniform_image(ideal.width, ideal.height, tuple(settings.table_bgr)).copy()
    if settings.T_camera_table is not None:
        normal = np.asarray(settings.T_camera_table, float)[:3, 2]
        offset = normal @ np.asarray(settings.T_camera_table, float)[:3, 3]
        # a ray d = K^-1 (u, v, 1) meets the plane in front of the camera iff (normal . d) * offset > 0;
        # normal . d is affine in (u, v): a u + b v + c. Coverage from the signed distance to that line.
        a, b = normal[0] / ideal.fx, normal[1] / ideal.fy
        c = normal[2] - a * ideal.cx - b * ideal.cy
        u, v = np.meshgrid(np.arange(ideal.width, dtype=np.float32), np.arange(ideal.height, dtype=np.float32))
        if abs(a) + abs(b) > 1e-12:
            distance = np.sign(offset) * (a * u + b * v + c) / np.hypot(a, b)
            on_table = np.clip(0.5 + distance, 0.0, 1.0)
        else:                             # the table is parallel to the image plane
            on_table = np.full(u.shape, float(np.sign(offset) * c > 0), np.float32)
        canvas *= (WALL_SHADE + (1.0 - WALL_SHADE) * on_table)[..., None]
    return canvas


def _camera_effects(image, rng, settings):
    """Lighting gradient, blur, noise and JPEG of a float32 BGR image -> uint8 BGR."""
    h, w = image.shape[:2]
    if settings.lighting_gradient:
        # gain = 1 + g (t - 1/2), t going 0 -> 1 across the image along a random direction
        direction = _unit(rng.normal(size=2))
        du, dv = settings.lighting_gradient * direction / np.abs(direction).sum()
        u, v = _unit_grid(w, h)
        gain = cv2.addWeighted(u, du, v, dv, 1.0 - min(du, 0.0) - min(dv, 0.0) - 0.5 * settings.lighting_gradient)
        image = cv2.multiply(image, cv2.merge((gain, gain, gain)))
    if settings.blur_sigma:
        image = cv2.GaussianBlur(image, (0, 0), settings.blur_sigma)
    if settings.noise_sigma:
        noise = np.empty((h, w * 3), np.float32)
        cv2.setRNGSeed(int(rng.integers(2 ** 31)))
        cv2.randn(noise, 0.0, float(settings.noise_sigma))
        image += noise.reshape(h, w, 3)
    np.maximum(image, 0.0, out=image)
    image = cv2.convertScaleAbs(image)           # rounds and saturates to uint8
    if settings.jpeg_quality:
        ok, buffer = cv2.imencode('.jpg', image, [cv2.IMWRITE_JPEG_QUALITY, int(settings.jpeg_quality)])
        image = cv2.imdecode(buffer, cv2.IMREAD_COLOR)
    return image


def _light_in_camera(T_camera_surface, light_dir_camera):
    """Unit direction (camera frame) towards a light fixed to a surface whose +z is its up normal.

    ``light_dir_camera`` is the direction when the surface squarely faces the camera (up = camera
    -z, i.e. the surface frame is the camera frame turned by pi about x).
    """
    return np.asarray(T_camera_surface, dtype=float)[:3, :3] @ (np.diag([1.0, -1.0, -1.0]) @ _unit(light_dir_camera))


def _brightness(normal_cam, light):
    """Lambertian brightness (ambient .. 1) of a face with outward unit normal ``normal_cam``."""
    return AMBIENT + (1.0 - AMBIENT) * max(0.0, float(normal_cam @ light))


def _unit(vector):
    vector = np.asarray(vector, dtype=float)
    return vector / np.linalg.norm(vector)


@functools.lru_cache(maxsize=4)
def _uniform_image(width, height, bgr):
    """Float32 (height, width, 3) image of one colour (cached: copy before writing)."""
    image = np.empty((height, width, 3), np.float32)
    image[:] = bgr
    return image


@functools.lru_cache(maxsize=4)
def _unit_grid(width, height):
    """Pixel coordinates (u, v) as float32 grids scaled to 0..1."""
    u, v = np.meshgrid(np.linspace(0, 1, width, dtype=np.float32), np.linspace(0, 1, height, dtype=np.float32))
    return u, v


def _ideal_camera(camera):
    """Pinhole camera with ``camera``'s focal lengths whose image covers every ray of ``camera`` (+2 px margin)."""
    return _ideal_camera_cached(camera.width, camera.height, tuple(camera.K.ravel()), tuple(camera.D))


@functools.lru_cache(maxsize=8)
def _ideal_camera_cached(width, height, K, D):
    camera = CameraModel(width, height, np.reshape(K, (3, 3)), D)
    u, v = np.arange(width, dtype=float), np.arange(height, dtype=float)
    border = np.vstack([np.column_stack([u, np.zeros_like(u)]), np.column_stack([u, np.full_like(u, height - 1)]),
                        np.column_stack([np.zeros_like(v), v]), np.column_stack([np.full_like(v, width - 1), v])])
    ideal_px = camera.normalised_to_pixels(camera.undistort_points(border))
    margin = 2
    low = np.floor(ideal_px.min(axis=0)) - margin
    high = np.ceil(ideal_px.max(axis=0)) + margin
    K_ideal = camera.K.copy()
    K_ideal[:2, 2] -= low
    size = (high - low + 1).astype(int)
    return CameraModel(int(size[0]), int(size[1]), K_ideal, np.zeros(5), camera.name, camera.frame_id)
