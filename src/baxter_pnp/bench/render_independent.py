"""A second renderer of blocks, independent of ``synthetic.py`` (the perception benchmark's ``*_r2`` sets).

It shares no rasterising code with ``synthetic.py`` and is built differently, so that the vision pipeline is not
tuned to one renderer's habits:

- geometry: a prism (``models.PolygonModel``) whose vertical edges are rounded (radius ``corner_radius``) and whose
  top rim is rounded over (radius ``bevel``), tessellated into rings of cross-sections; every face is projected
  through the distorted camera (``CameraModel.project``), its edges cut into chords of at most ``CHORD_PX`` so
  that straight 3D edges come out curved as the lens bends them;
- rasterising: ``cv2.fillPoly`` (fixed point, ``shift``) on a canvas ``supersample`` x finer than the image (8 by
  default), then ``cv2.resize(INTER_AREA)``; a convex block needs only back-face culling, blocks are drawn far
  to near (painter's order). fillPoly fills every pixel an edge touches (about half a pixel too wide along each
  edge), so faces are shrunk by ``FILL_DILATION_SS_PX`` before filling;
- shading: Lambert + ambient + Blinn-Phong highlight under a random directional light fixed to the table; the
  top face is usually the brightest face, not always (a low light can light a side face within a few per cent
  of it); soft shadow and contact shadow on the table; a dim, grey, low-saturation textured table; vignetting;
- marks on the top face: dice pips (dark or white, 1-6; on the side faces too for dice), a printed letter, wood
  grain, a glare patch;
- camera: gaussian blur, sometimes slight motion blur, sensor noise with colour, JPEG at quality 70-95.

Ground truth per block (``render_scene``): ``vertices_px`` the top face's sharp corners, where its edge lines meet
(before any rounding or bevel: the model's vertices, which the pose estimator fits), ``centroid_px`` the projected
top-face centre, ``T_camera_block``, ``visible``. Block frame as in docs/ARCHITECTURE.md (origin at the top-face
centre, +z up); the table is the plane z = -height. Pixels (u, v) distorted, origin at the top-left pixel's centre.
"""
import functools
import math
from dataclasses import dataclass, field

import cv2
import numpy as np

from baxter_pnp import models
from baxter_pnp.camera import CameraModel

SUPERSAMPLE = 8                  # default canvas scale (supersampled pixels per image pixel)
MAX_CANVAS_PIXELS = 16e6         # the scale drops below ``supersample`` for a block so large that it would exceed this
FILL_DILATION_SS_PX = 0.5        # how far cv2.fillPoly's fill reaches beyond a polygon's edges (canvas pixels)
RADIANCE_SCALE = 64.0            # the canvas holds radiance x this in uint16 (steps of 1/64 grey level)
FIXED_POINT_SHIFT = 8            # fractional bits of the coordinates given to cv2.fillPoly
CHORD_PX = 3.0                   # longest projected chord of a 3D edge (px): the lens's curvature is followed
ARC_POINTS = 6                   # points per rounded vertical edge (per corner of a cross-section)
BEVEL_STEPS = 3                  # bands of the rounded-over top rim
CONTACT_SHADOW = 0.3             # darkening of the table right at a block's foot
CONTACT_SHADOW_BLUR_PX = 1.5     # and how far it reaches (sigma, px)
MIN_DEPTH = 1e-3                 # m; a block with a point closer to the camera plane is not drawn
PIP_OFFSETS = {                  # dice pips, in units of a quarter side from the face's centre
    1: [(0, 0)], 2: [(-1, -1), (1, 1)], 3: [(-1, -1), (0, 0), (1, 1)], 4: [(-1, -1), (1, -1), (-1, 1), (1, 1)],
    5: [(-1, -1), (1, -1), (0, 0), (-1, 1), (1, 1)], 6: [(-1, -1), (1, -1), (-1, 0), (1, 0), (-1, 1), (1, 1)]}
PIP_RADIUS_FRACTION = 0.09       # pip radius / side
LABEL_FRACTION = 0.55            # printed letter's box / the top face's inscribed diameter


@dataclass(frozen=True)
class Marks:
    """What is printed or seen on a block's faces (colours BGR 0-255 albedo, lengths as fractions of the side)."""
    pips: int = 0                     # dice pips on the top face (0 = none, 1-6)
    pip_bgr: tuple = (25, 25, 25)
    side_pips: bool = False           # a die: the side faces carry pips too
    label: str = ''                   # one printed character on the top face ('' = none)
    label_bgr: tuple = (20, 20, 20)
    grain: float = 0.0                # relative amplitude of a wood grain over the top face (0 = none)
    glare: float = 0.0                # grey levels of a specular glare patch on the top face (0 = none)


@dataclass(frozen=True)
class Block:
    """A regular prism block: ``shape`` (a key of ``models.SHAPES``), ``side``, ``height``, ``corner_radius`` of its
    vertical edges and ``bevel`` radius of its top rim (m), ``colour_bgr`` albedo (0-255), ``marks``."""
    shape: str
    side: float
    height: float = 0.02
    colour_bgr: tuple = (40, 170, 40)
    corner_radius: float = 0.0
    bevel: float = 0.0
    marks: Marks = field(default_factory=Marks)

    def __post_init__(self):
        model = self.model
        apothem = model.circumradius * math.cos(math.pi / model.n)
        if not 0.0 <= self.corner_radius < apothem:
            raise ValueError(f'corner_radius must be in [0, {apothem:.4f}) m for this block, got {self.corner_radius}')
        if not 0.0 <= self.bevel < min(self.height, apothem):
            raise ValueError(f'bevel must be in [0, {min(self.height, apothem):.4f}) m for this block, '
                             f'got {self.bevel}')
        if self.marks.pips not in PIP_OFFSETS and self.marks.pips != 0:
            raise ValueError(f'pips must be 0-6, got {self.marks.pips}')

    @property
    def model(self):
        """The block's ``models.PolygonModel`` (its sharp top-face corners are the ground truth)."""
        return models.model_for(self.shape, self.side, self.height)


@dataclass(frozen=True)
class Look:
    """Light, table and camera of one picture (angles rad, lengths px, grey levels 0-255)."""
    light_azimuth: float = 0.8        # direction towards the light in the table frame (about +z)
    light_elevation: float = 1.2      # above the table plane
    ambient: float = 0.35             # fraction of the albedo lit whatever the face's direction
    diffuse: float = 0.65
    specular: float = 0.15            # Blinn-Phong highlight strength (fraction of white)
    shininess: float = 20.0
    exposure: float = 0.8             # scales every radiance
    table_grey: float = 140.0         # table albedo
    table_tint: tuple = (1.0, 1.0, 1.0)   # BGR gains of the table's colour
    table_texture: float = 4.0        # grey levels (standard deviation) of the table's mottling
    shadow_strength: float = 0.4      # darkening at the heart of the block's shadow
    shadow_blur_px: float = 3.0       # penumbra (sigma)
    vignetting: float = 0.35          # brightness lost at the image's corners
    blur_sigma: float = 0.7
    motion_blur_px: float = 0.0       # length of a straight motion blur (0 = none)
    motion_angle: float = 0.0
    noise_sigma: float = 2.0          # per channel (colour noise), plus half as much shared by the channels
    jpeg_quality: int = 85            # 0: no JPEG round trip


def random_look(rng):
    """A random ``Look``: dim grey tables, lights 42-85 deg above the table (a side face is rarely a little brighter
    than the top), blur, noise and JPEG 70-95."""
    return Look(
        light_azimuth=float(rng.uniform(0.0, 2.0 * np.pi)),
        light_elevation=float(np.radians(rng.uniform(42.0, 85.0))),
        ambient=float(rng.uniform(0.25, 0.5)), diffuse=float(rng.uniform(0.5, 0.75)),
        specular=float(rng.uniform(0.0, 0.25)), shininess=float(rng.uniform(8.0, 60.0)),
        exposure=float(rng.uniform(0.5, 0.95)),
        table_grey=float(rng.uniform(70.0, 180.0)), table_tint=tuple(rng.uniform(0.94, 1.06, size=3)),
        table_texture=float(rng.uniform(1.5, 6.0)),
        shadow_strength=float(rng.uniform(0.15, 0.55)), shadow_blur_px=float(rng.uniform(1.5, 5.0)),
        vignetting=float(rng.uniform(0.2, 0.55)),
        blur_sigma=float(rng.uniform(0.45, 1.1)),
        motion_blur_px=float(rng.uniform(1.0, 2.5)) if rng.random() < 0.2 else 0.0,
        motion_angle=float(rng.uniform(0.0, np.pi)),
        noise_sigma=float(rng.uniform(0.8, 2.5)), jpeg_quality=int(rng.integers(70, 96)))


def plain_look(**changes):
    """A ``Look`` without any camera effect, table texture, shadow or vignetting (for exact checks)."""
    settings = dict(table_texture=0.0, shadow_strength=0.0, vignetting=0.0, blur_sigma=0.0, motion_blur_px=0.0,
                    noise_sigma=0.0, jpeg_quality=0, specular=0.0)
    settings.update(changes)
    return Look(**settings)


def render_scene(camera, blocks, rng, look=None, supersample=SUPERSAMPLE):
    """Image of ``blocks`` = ``[(Block, T_camera_block)]`` on a table, and their ground truth.

    The table is the first block's bottom plane (all blocks should stand on it). ``look`` defaults to
    ``random_look(rng)``. Returns ``(image_bgr uint8 (H, W, 3), truths)``, ``truths[i]`` a dict: ``vertices_px``
    (n, 2) the top face's sharp corners in model order, ``centroid_px`` (2,) the projected top-face centre,
    ``T_camera_block`` (4x4), ``visible`` (top face towards the camera, corners inside the image, not hidden).
    """
    look = random_look(rng) if look is None else look
    light_cam = _light_in_camera(blocks, look)
    image = _table(camera, look, rng)
    image *= _shadow_factor(camera, blocks, light_cam, look)[..., None]
    coverage = _draw_blocks(image, camera, _far_first(blocks), light_cam, look, supersample, rng)
    image = _camera_effects(image * _vignetting(camera.width, camera.height, look.vignetting)[..., None], look, rng)
    return image, _truths(camera, blocks, coverage)


def render_layers(camera, blocks, rng, look=None, supersample=SUPERSAMPLE):
    """The ``blocks`` of ``render_scene`` as layers to put into a picture of a real table (``bench.composite``):
    ``(colour, alpha, shadow, table_bgr, truths)``. ``colour`` (H, W, 3) float32: the blocks' radiance, premultiplied by
    their coverage ``alpha`` (H, W, 0-1); ``shadow`` (H, W): the table's gains in their shadows; ``table_bgr`` (3,):
    the radiance of the table ``look`` describes (its mottling left out), the scale the colours are on. No camera
    effect (blur, noise, JPEG: the composite's own)."""
    look = random_look(rng) if look is None else look
    light_cam = _light_in_camera(blocks, look)
    h, w = camera.height, camera.width
    colour, alpha = np.zeros((h, w, 3), np.float32), np.zeros((h, w), np.float32)
    coverage = _draw_blocks(colour, camera, _far_first(blocks), light_cam, look, supersample, rng, alpha)
    table_bgr = _table_radiance(look)
    return colour, alpha, _shadow_factor(camera, blocks, light_cam, look), table_bgr, _truths(camera, blocks, coverage)


def _light_in_camera(blocks, look):
    """The direction towards ``look``'s light in the camera frame; ValueError without blocks (the table is the first
    block's bottom plane)."""
    if not blocks:
        raise ValueError('render_independent: no blocks to draw')
    return np.asarray(blocks[0][1], dtype=float)[:3, :3] @ _light_direction(look)


def _far_first(blocks):
    """``[(index, Block, T_camera_block)]`` of ``blocks``, the farthest first (painter's order)."""
    order = sorted(range(len(blocks)), key=lambda i: -np.linalg.norm(blocks[i][1][:3, 3]))
    return [(i, *blocks[i]) for i in order]


def _truths(camera, blocks, coverage):
    """``render_scene``'s ground truth of ``blocks`` (``coverage``: ``_draw_blocks``'s)."""
    truths = []
    for i, (block, T_camera_block) in enumerate(blocks):
        vertices_px = camera.project(_transform(T_camera_block, block.model.vertices))
        inside = np.all((vertices_px >= 0) & (vertices_px <= [camera.width - 1, camera.height - 1]))
        top_facing, drawn, seen = coverage.get(i, (False, 0, 0))
        truths.append({'vertices_px': vertices_px, 'centroid_px': camera.project(T_camera_block[:3, 3])[0],
                       'T_camera_block': np.array(T_camera_block, dtype=float),
                       'visible': bool(top_facing and inside and drawn > 0 and seen >= 0.995 * drawn)})
    return truths


# ------------------------------------------------------------------------------------------------ geometry

def _transform(T, points):
    return np.asarray(points, dtype=float) @ T[:3, :3].T + T[:3, 3]


def _cross_section(model, corner_radius, inset, z):
    """(n * ARC_POINTS, 3) outline (block frame, m) of the block at height ``z``, ``inset`` inside the sharp prism's
    sides, its corners rounded to radius ``max(corner_radius - inset, 0)``; counter-clockwise about +z."""
    n, half = model.n, math.pi / model.n
    rho = max(corner_radius - inset, 0.0)
    corner_angles = half + 2.0 * math.pi * np.arange(n) / n
    centre_distance = model.circumradius - (inset + rho) / math.cos(half)
    angles = corner_angles[:, None] + np.linspace(-half, half, ARC_POINTS)[None, :]
    x = centre_distance * np.cos(corner_angles)[:, None] + rho * np.cos(angles)
    y = centre_distance * np.sin(corner_angles)[:, None] + rho * np.sin(angles)
    return np.column_stack([x.ravel(), y.ravel(), np.full(x.size, z)])


def _block_faces(block):
    """``(top, quads)`` of a block in its frame: the flat top face (k, 3) and the quads (Q, 4, 3) of its rounded
    rim and sides, each counter-clockwise seen from outside."""
    steps = BEVEL_STEPS if block.bevel > 0 else 0
    theta = np.linspace(0.0, math.pi / 2.0, steps + 1)
    rings = [_cross_section(block.model, block.corner_radius, block.bevel * (1.0 - math.sin(t)),
                            -block.bevel * (1.0 - math.cos(t))) for t in theta]
    rings.append(_cross_section(block.model, block.corner_radius, 0.0, -block.height))
    quads = [np.stack([upper, lower, np.roll(lower, -1, axis=0), np.roll(upper, -1, axis=0)], axis=1)
             for upper, lower in zip(rings[:-1], rings[1:])]
    return rings[0], np.concatenate(quads)


def _quad_normals(quads):
    """(Q, 3) outward unit normals of quads (Q, 4, 3) (zero for a degenerate quad), from their diagonals."""
    normals = np.cross(quads[:, 2] - quads[:, 0], quads[:, 3] - quads[:, 1])
    lengths = np.linalg.norm(normals, axis=1, keepdims=True)
    return np.where(lengths > 1e-14, normals / np.maximum(lengths, 1e-300), 0.0)


def _circle(centre, axis_u, axis_v, radius, points=24):
    """(points, 3) polygon of a circle in the plane spanned by the unit vectors ``axis_u``, ``axis_v``."""
    angles = np.linspace(0.0, 2.0 * math.pi, points, endpoint=False)
    return centre + radius * (np.cos(angles)[:, None] * axis_u + np.sin(angles)[:, None] * axis_v)


def _pips(count, centre, axis_u, axis_v, side):
    """Circles of ``count`` dice pips on a face of centre ``centre`` and in-plane axes ``axis_u``, ``axis_v``."""
    return [_circle(centre + 0.25 * side * (a * axis_u + b * axis_v), axis_u, axis_v, PIP_RADIUS_FRACTION * side)
            for a, b in PIP_OFFSETS[count]]


@functools.lru_cache(maxsize=64)
def _glyph_outlines(character):
    """Outlines (outer and holes, even-odd) of a printed ``character`` in a unit box centred at 0, y up."""
    texture = np.zeros((96, 96), np.uint8)
    (width, height), _ = cv2.getTextSize(character, cv2.FONT_HERSHEY_SIMPLEX, 2.5, 8)
    cv2.putText(texture, character, ((96 - width) // 2, (96 + height) // 2), cv2.FONT_HERSHEY_SIMPLEX, 2.5, 255, 8,
                cv2.LINE_8)
    contours, _ = cv2.findContours(texture, cv2.RETR_CCOMP, cv2.CHAIN_APPROX_SIMPLE)
    return [np.column_stack([(c[:, 0, 0] - 47.5) / 96.0, (47.5 - c[:, 0, 1]) / 96.0]) for c in contours if len(c) >= 3]


def _mark_polygons(block):
    """[(polygon (k, 3) in the block frame, BGR albedo, face normal (3,))] of the block's pips and letter."""
    marks, side = block.marks, block.side
    z_axis, x_axis, y_axis = np.eye(3)[2], np.eye(3)[0], np.eye(3)[1]
    polygons = []
    if marks.pips:
        polygons += [(p, marks.pip_bgr, z_axis) for p in _pips(marks.pips, np.zeros(3), x_axis, y_axis, side)]
    if marks.label:
        box = LABEL_FRACTION * 2.0 * block.model.circumradius * math.cos(math.pi / block.model.n)
        polygons += [(np.column_stack([box * o, np.zeros(len(o))]), marks.label_bgr, z_axis)
                     for o in _glyph_outlines(marks.label)]
    if marks.side_pips:
        apothem = block.model.circumradius * math.cos(math.pi / block.model.n)
        for k in range(block.model.n):
            angle = 2.0 * math.pi * (k + 1) / block.model.n     # outward normal of side k (between vertices k, k+1)
            normal = np.array([math.cos(angle), math.sin(angle), 0.0])
            tangent = np.array([-math.sin(angle), math.cos(angle), 0.0])
            centre = apothem * normal - [0.0, 0.0, block.height / 2.0]
            count = 1 + (marks.pips + k) % 6
            polygons += [(p, marks.pip_bgr, normal) for p in _pips(count, centre, tangent, z_axis, side)]
    return polygons


# ------------------------------------------------------------------------------------------------ shading

def _light_direction(look):
    """Unit vector towards the light in the table frame (+z up)."""
    c = math.cos(look.light_elevation)
    return np.array([c * math.cos(look.light_azimuth), c * math.sin(look.light_azimuth),
                     math.sin(look.light_elevation)])


def _shade(albedo_bgr, normals_cam, points_cam, light_cam, look):
    """(N, 3) radiance (BGR, grey levels) of surface points (N, 3) with unit normals (N, 3), camera frame:
    Lambert + ambient + Blinn-Phong, times the exposure."""
    normals_cam, points_cam = np.atleast_2d(normals_cam), np.atleast_2d(points_cam)
    half = light_cam - points_cam / np.linalg.norm(points_cam, axis=1, keepdims=True)
    half /= np.linalg.norm(half, axis=1, keepdims=True)
    diffuse = look.ambient + look.diffuse * np.maximum(0.0, normals_cam @ light_cam)
    highlight = look.specular * 255.0 * np.maximum(0.0, np.sum(normals_cam * half, axis=1)) ** look.shininess
    return look.exposure * (diffuse[:, None] * np.asarray(albedo_bgr, dtype=float) + highlight[:, None])


# ------------------------------------------------------------------------------------------------ drawing

def _project_polygons(camera, polygons_cam):
    """Distorted pixel outlines of 3D polygons (camera frame): every edge cut into chords of at most CHORD_PX."""
    sizes = np.array([len(p) for p in polygons_cam])
    corners = np.vstack(polygons_cam)
    starts = np.repeat(np.cumsum(sizes) - sizes, sizes)
    following = starts + (np.arange(len(corners)) - starts + 1) % np.repeat(sizes, sizes)
    corners_px = camera.project(corners)
    pieces = np.maximum(1, np.ceil(np.linalg.norm(corners_px[following] - corners_px, axis=1) / CHORD_PX)).astype(int)
    edge = np.repeat(np.arange(len(corners)), pieces)
    fraction = (np.arange(len(edge)) - np.repeat(np.cumsum(pieces) - pieces, pieces)) / pieces[edge]
    dense = corners[edge] + fraction[:, None] * (corners[following[edge]] - corners[edge])
    polygon_pieces = np.add.reduceat(pieces, np.cumsum(sizes) - sizes)
    return np.split(camera.project(dense), np.cumsum(polygon_pieces)[:-1])


def _shrunk(points, distance):
    """A convex polygon (k, 2) moved ``distance`` inwards (mitred corners); None when it vanishes or flips."""
    edges = points[np.r_[1:len(points), 0]] - points
    lengths = np.linalg.norm(edges, axis=1)
    keep = lengths > 1e-9
    points, edges = points[keep], edges[keep] / lengths[keep, None]
    if len(points) < 3:
        return None
    area2 = _twice_area(points)
    if abs(area2) < 1e-12:
        return None
    inward = np.sign(area2) * np.column_stack([-edges[:, 1], edges[:, 0]])   # left normal for a CCW polygon
    before = inward[np.r_[len(points) - 1, 0:len(points) - 1]]
    moved = points + distance * (before + inward) / np.maximum(1.0 + np.sum(before * inward, axis=1), 0.2)[:, None]
    return moved if _twice_area(moved) * area2 > 0 else None


def _twice_area(points):
    """Twice the signed area of a polygon (k, 2) (positive counter-clockwise in a y-up frame)."""
    x, y = points[:, 0], points[:, 1]
    return float(np.dot(x[:-1], y[1:]) - np.dot(x[1:], y[:-1]) + x[-1] * y[0] - x[0] * y[-1])


def _draw_blocks(image, camera, blocks, light_cam, look, supersample, rng, alpha_image=None):
    """Composite ``blocks`` = ``[(index, Block, T_camera_block)]`` (far first) over ``image`` (float32, in place);
    their coverage (0-1) also into ``alpha_image`` (H, W float32, in place) when given.

    Returns ``{index: (top face towards the camera, canvas pixels of its top face drawn, still showing at the end)}``.
    """
    plans, coverage = [], {}
    for index, block, T in blocks:
        top, quads = _block_faces(block)
        if np.any(_transform(T, np.vstack([top, quads[:, 1]]))[:, 2] <= MIN_DEPTH):
            continue
        R = T[:3, :3]
        top_cam, top_normal_cam = _transform(T, top), R[:, 2]
        top_facing = float(top_normal_cam @ top_cam[0]) < 0.0
        coverage[index] = (top_facing, 0, 0)
        quads_cam = _transform(T, quads.reshape(-1, 3)).reshape(quads.shape)
        normals_cam, centres_cam = _quad_normals(quads) @ R.T, quads_cam.mean(axis=1)
        front = np.sum(normals_cam * centres_cam, axis=1) < 0.0            # zero normals (degenerate) are dropped
        colours = _shade(block.colour_bgr, normals_cam[front], centres_cam[front], light_cam, look)
        polygons = [(q, c, 'face') for q, c in zip(quads_cam[front], colours)]   # kinds: face, top, top-mark, mark
        if top_facing:
            polygons.append((top_cam, _shade(block.colour_bgr, top_normal_cam, T[:3, 3], light_cam, look)[0], 'top'))
        for polygon, albedo, normal in _mark_polygons(block):
            polygon_cam, normal_cam = _transform(T, polygon), R @ normal
            if float(normal_cam @ polygon_cam[0]) < 0.0:
                polygons.append((polygon_cam, _shade(albedo, normal_cam, polygon_cam.mean(axis=0), light_cam, look)[0],
                                 'top-mark' if normal[2] > 0.5 else 'mark'))
        plans.append((index, block, T, polygons))
    drawable = [(index, block, T, polygons, outline) for index, block, T, polygons in plans if polygons
                for outline in [_project_polygons(camera, [p for p, _, _ in polygons])]]
    if not drawable:
        return coverage
    everything = np.vstack([np.vstack(outline) for *_, outline in drawable])
    x0, y0 = np.maximum(np.floor(everything.min(axis=0)).astype(int) - 2, 0)
    x1, y1 = np.minimum(np.ceil(everything.max(axis=0)).astype(int) + 3, [camera.width, camera.height])
    if x1 <= x0 or y1 <= y0:
        return coverage
    s = max(1, min(int(supersample), int(math.sqrt(MAX_CANVAS_PIXELS / ((x1 - x0) * (y1 - y0))))))
    radiance = np.zeros(((y1 - y0) * s, (x1 - x0) * s, 3), np.uint16)       # grey levels x RADIANCE_SCALE
    labels = np.zeros(radiance.shape[:2], np.uint8)                          # 0 none, 2 i + 1 top of i, 2 i + 2 rest
    drawn = {}
    for index, block, T, polygons, outlines in drawable:
        top_label, other_label = 2 * index + 1, 2 * index + 2
        for (_, colour, kind), outline in zip(polygons, outlines):
            canvas_px = (outline - [x0, y0] + 0.5) * s - 0.5
            if kind in ('face', 'top'):
                canvas_px = _shrunk(canvas_px, FILL_DILATION_SS_PX)
                if canvas_px is None:
                    continue
            points = [np.round(canvas_px * (1 << FIXED_POINT_SHIFT)).astype(np.int32)]
            value = tuple(float(c) for c in np.clip(np.asarray(colour) * RADIANCE_SCALE, 0, 65535))
            cv2.fillPoly(radiance, points, value, cv2.LINE_8, FIXED_POINT_SHIFT)
            label = top_label if kind in ('top', 'top-mark') else other_label
            if kind != 'top-mark':
                cv2.fillPoly(labels, points, label, cv2.LINE_8, FIXED_POINT_SHIFT)
            if kind == 'top':
                drawn[index] = int(np.count_nonzero(labels == label))
    for index, count in drawn.items():
        coverage[index] = (coverage[index][0], count, int(np.count_nonzero(labels == 2 * index + 1)))
    size = (x1 - x0, y1 - y0)
    colour = cv2.resize(radiance, size, interpolation=cv2.INTER_AREA).astype(np.float32) / RADIANCE_SCALE
    alpha = cv2.resize((labels != 0).astype(np.float32), size, interpolation=cv2.INTER_AREA)
    region = image[y0:y1, x0:x1]
    region *= 1.0 - alpha[..., None]
    region += colour
    if alpha_image is not None:
        alpha_image[y0:y1, x0:x1] = 1.0 - (1.0 - alpha_image[y0:y1, x0:x1]) * (1.0 - alpha)
    for index, block, T, polygons, _ in drawable:
        if index in drawn and (block.marks.grain or block.marks.glare):
            top_alpha = cv2.resize((labels == 2 * index + 1).astype(np.float32), size, interpolation=cv2.INTER_AREA)
            top_colour = next(colour for _, colour, kind in polygons if kind == 'top')
            _top_face_texture(region, top_alpha, camera, (x0, y0), block, T, top_colour, rng)
    return coverage


def _top_face_texture(region, top_alpha, camera, origin, block, T_camera_block, top_colour, rng):
    """Wood grain (relative change of the top face's colour) and a glare patch (added grey levels), in the block
    frame, over the pixels the top face covers (``top_alpha``), in place."""
    rows, cols = np.nonzero(top_alpha > 0)
    if len(rows) == 0:
        return
    x0, y0 = origin
    rays = np.column_stack([_normalised_rays(camera)[rows + y0, cols + x0], np.ones(len(rows))])
    normal, centre = T_camera_block[:3, 2], T_camera_block[:3, 3]
    depth = (normal @ centre) / (rays @ normal)
    xy = ((rays * depth[:, None] - centre) @ T_camera_block[:3, :3])[:, :2] / block.side   # in sides
    marks = block.marks
    added = np.zeros((len(rows), 3), np.float32)
    if marks.grain:
        angle, period, phase = rng.uniform(0.0, np.pi), rng.uniform(0.08, 0.2), rng.uniform(0.0, 2.0 * np.pi)
        along = xy @ [math.cos(angle), math.sin(angle)]
        across = xy @ [-math.sin(angle), math.cos(angle)]
        wobble = 0.3 * np.sin(2.0 * np.pi * across / (3.0 * period) + phase)
        grain = marks.grain * np.sin(2.0 * np.pi * (along / period + wobble))
        added += (grain[:, None] * np.asarray(top_colour)[None, :]).astype(np.float32)
    if marks.glare:
        spot, radius = rng.uniform(-0.3, 0.3, size=2), rng.uniform(0.1, 0.25)
        added += (marks.glare * np.exp(-np.sum((xy - spot) ** 2, axis=1) / (2.0 * radius ** 2)))[:, None]
    region[rows, cols] += top_alpha[rows, cols, None] * added


@functools.lru_cache(maxsize=4)
def _cached_rays(width, height, K, D):
    camera = CameraModel(width, height, np.reshape(K, (3, 3)), D)
    map_x, map_y = camera.rendering_maps(CameraModel(width, height, camera.K, np.zeros(5)))
    rays = np.dstack([(map_x - camera.cx) / camera.fx, (map_y - camera.cy) / camera.fy])
    rays.flags.writeable = False
    return rays


def _normalised_rays(camera):
    """(H, W, 2) normalised coordinates (X/Z, Y/Z) of every pixel's ray (cached)."""
    return _cached_rays(camera.width, camera.height, tuple(camera.K.ravel()), tuple(camera.D))


# ------------------------------------------------------------------------------------------------ table, camera

def _table(camera, look, rng):
    """Float32 BGR table: a dim grey, slightly tinted, mottled at two scales, lit like a face towards +z."""
    h, w = camera.height, camera.width
    image = np.empty((h, w, 3), np.float32)
    image[:] = _table_radiance(look)
    if look.table_texture:
        # mottling (standard deviation ``table_texture``): broad grey patches with a faint tint, a fine grain
        coarse = rng.normal(size=(6, 8, 1)) + 0.25 * rng.normal(size=(6, 8, 3))
        coarse = cv2.resize(coarse.astype(np.float32), (w, h), interpolation=cv2.INTER_CUBIC)
        fine = cv2.resize(cv2.GaussianBlur(_gaussian_noise(rng, (h // 2, w // 2)), (0, 0), 0.8), (w, h),
                          interpolation=cv2.INTER_LINEAR)
        image += look.table_texture * (coarse + 2.8 * fine[..., None]) / math.sqrt(2.0)
    return image


def _table_radiance(look):
    """(3,) float32 BGR radiance of ``look``'s table, unmottled, lit like a face towards +z."""
    lit = look.exposure * look.table_grey * (look.ambient + look.diffuse * math.sin(look.light_elevation))
    return (lit * np.asarray(look.table_tint, dtype=np.float32)).astype(np.float32)


def _shadow_factor(camera, blocks, light_cam, look):
    """(H, W) float32 gains of the table: 1 in the light, lower in each block's soft shadow and at its foot."""
    h, w = camera.height, camera.width
    factor = np.ones((h, w), np.float32)
    if not look.shadow_strength:
        return factor
    for block, T in blocks:
        light_block = T[:3, :3].T @ light_cam
        top, _ = _block_faces(block)
        foot = _cross_section(block.model, block.corner_radius, 0.0, -block.height)
        cast = top - np.outer((top[:, 2] + block.height) / max(light_block[2], 0.2), light_block)
        outline = np.vstack([foot, cast])
        hull = _transform(T, outline[cv2.convexHull(outline[:, :2].astype(np.float32), returnPoints=False).ravel()])
        if np.any(hull[:, 2] <= MIN_DEPTH):
            continue
        shadow_px, foot_px = _project_polygons(camera, [hull, _transform(T, foot)])
        reach = int(math.ceil(4.0 * max(look.shadow_blur_px, CONTACT_SHADOW_BLUR_PX))) + 1
        x0, y0 = np.maximum(np.floor(shadow_px.min(axis=0)).astype(int) - reach, 0)
        x1, y1 = np.minimum(np.ceil(shadow_px.max(axis=0)).astype(int) + reach + 1, [w, h])
        if x1 <= x0 or y1 <= y0:
            continue
        shadow = np.zeros((y1 - y0, x1 - x0), np.float32)
        for polygon, strength, sigma in ((shadow_px, look.shadow_strength, look.shadow_blur_px),
                                         (foot_px, CONTACT_SHADOW, CONTACT_SHADOW_BLUR_PX)):
            mask = np.zeros_like(shadow)
            cv2.fillPoly(mask, [np.round((polygon - [x0, y0]) * 16).astype(np.int32)], 1.0, cv2.LINE_8, 4)
            shadow = np.maximum(shadow, strength * cv2.GaussianBlur(mask, (0, 0), sigma))
        factor[y0:y1, x0:x1] *= 1.0 - shadow
    return factor


@functools.lru_cache(maxsize=8)
def _radial_squared(width, height):
    """(H, W) squared distance of each pixel to the image centre, 1 at the corners."""
    u, v = np.meshgrid(np.arange(width, dtype=np.float32) - (width - 1) / 2.0,
                       np.arange(height, dtype=np.float32) - (height - 1) / 2.0)
    r2 = (u ** 2 + v ** 2) / (((width - 1) / 2.0) ** 2 + ((height - 1) / 2.0) ** 2)
    r2.flags.writeable = False
    return r2


def _vignetting(width, height, strength):
    """(H, W) gains: 1 at the centre, ``1 - strength`` at the corners (quadratic in the radius)."""
    return 1.0 - strength * _radial_squared(width, height)


def _gaussian_noise(rng, shape):
    """Float32 standard normal noise of ``shape`` from OpenCV's generator (fast), seeded from ``rng``."""
    noise = np.empty(shape, np.float32)
    cv2.setRNGSeed(int(rng.integers(2 ** 31)))
    cv2.randn(noise.reshape(shape[0], -1), 0.0, 1.0)
    return noise


def _camera_effects(image, look, rng):
    """Blur (gaussian, then an optional straight motion blur), colour noise, uint8, JPEG round trip."""
    if look.blur_sigma:
        image = cv2.GaussianBlur(image, (0, 0), look.blur_sigma)
    if look.motion_blur_px:
        size = 2 * int(math.ceil(look.motion_blur_px / 2.0)) + 1
        kernel = np.zeros((size * 8, size * 8), np.float32)
        centre, reach = size * 4 - 0.5, look.motion_blur_px * 4
        direction = np.array([math.cos(look.motion_angle), math.sin(look.motion_angle)])
        a, b = centre - reach * direction, centre + reach * direction
        cv2.line(kernel, tuple(np.round(a * 16).astype(int)), tuple(np.round(b * 16).astype(int)), 1.0, 8,
                 cv2.LINE_AA, 4)
        kernel = cv2.resize(kernel, (size, size), interpolation=cv2.INTER_AREA)
        image = cv2.filter2D(image, -1, kernel / kernel.sum())
    if look.noise_sigma:
        h, w = image.shape[:2]
        noise = _gaussian_noise(rng, (h, w, 3))
        shared = cv2.cvtColor(noise, cv2.COLOR_BGR2GRAY)[..., None]
        image = image + look.noise_sigma * (noise + shared)   # partly shared by B, G, R
    image = cv2.convertScaleAbs(np.maximum(image, 0.0))
    if look.jpeg_quality:
        ok, buffer = cv2.imencode('.jpg', image, [cv2.IMWRITE_JPEG_QUALITY, int(look.jpeg_quality)])
        image = cv2.imdecode(buffer, cv2.IMREAD_COLOR)
    return image
