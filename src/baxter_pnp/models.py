"""Object models: regular polygonal prisms (the blocks) and planes (the table top).

Block frame (``block``, see docs/ARCHITECTURE.md): origin at the centre of the top face, +z the top
face's normal pointing up (away from the table); top-face vertex k (k = 0..n-1) lies at angle
``pi/n + 2*pi*k/n`` about +z at the circumradius ``R = s / (2 sin(pi/n))``, z = 0, so the vertices go
counter-clockwise about +z and, for a square, the edges are parallel to x and y. Lengths in metres,
angles in radians.
"""
import math
from dataclasses import dataclass
from functools import cached_property, lru_cache

import numpy as np

from baxter_pnp.transforms import invert

SHAPES = {'triangle': 3, 'square': 4, 'pentagon': 5, 'hexagon': 6}


@dataclass(frozen=True)
class PolygonModel:
    """A regular n-gon prism: ``shape`` (a key of ``SHAPES``), side ``side`` (m), height ``height`` (m)."""
    shape: str
    side: float
    height: float = 0.02

    def __post_init__(self):
        if self.shape not in SHAPES:
            raise ValueError(f'unknown shape {self.shape!r}; expected one of {sorted(SHAPES)}')
        if not (math.isfinite(self.side) and self.side > 0):
            raise ValueError(f'side must be a positive number of metres, got {self.side!r}')
        if not (math.isfinite(self.height) and self.height >= 0):
            raise ValueError(f'height must be a non-negative number of metres, got {self.height!r}')

    @property
    def n(self):
        """Number of vertices (and of sides) of the top face."""
        return SHAPES[self.shape]

    @property
    def circumradius(self):
        """Distance (m) from the top-face centre to each vertex: ``s / (2 sin(pi/n))``."""
        return self.side / (2.0 * math.sin(math.pi / self.n))

    @property
    def symmetry_angle(self):
        """Rotation (rad) about +z that maps the block onto itself: ``2 pi / n``."""
        return 2.0 * math.pi / self.n

    @cached_property
    def vertices(self):
        """(n, 3) read-only array: the top-face vertices in the block frame (m), counter-clockwise about +z."""
        angles = math.pi / self.n + self.symmetry_angle * np.arange(self.n)
        vertices = np.column_stack([self.circumradius * np.cos(angles),
                                    self.circumradius * np.sin(angles),
                                    np.zeros(self.n)])
        vertices.flags.writeable = False
        return vertices


@lru_cache(maxsize=64)
def model_for(shape, side, height=0.02):
    """The ``PolygonModel`` of a ``shape`` block with side ``side`` (m) and height ``height`` (m) (one instance per
    arguments: a model is immutable, and its vertices are computed once)."""
    return PolygonModel(shape, float(side), float(height))


# seen_model: the top face's edges are seen this fraction of the radius of a rounded-over top rim inside the sharp
# edges (docs/perception.md, "Rounded top edges"): a Lambertian rim under a light 45-90 deg above the table, averaged
# over the light's azimuth, as the sub-pixel stage's thin-strip model measures it (0.18-0.22).
EDGE_INSET_FRACTION = 0.2


def check_edge_radius(side, height, edge_radius, shapes=tuple(SHAPES)):
    """ValueError (saying what the radius must be) unless ``edge_radius`` (m) is a rim radius a block of ``side``
    and ``height`` (m) can have for every one of ``shapes``: non-negative, less than the top face's apothem and than
    the height."""
    if not (math.isfinite(edge_radius) and edge_radius >= 0.0):
        raise ValueError(f'must be a non-negative number of metres, got {edge_radius!r}')
    for shape in shapes:
        apothem = side / (2.0 * math.tan(math.pi / SHAPES[shape]))
        if edge_radius > 0.0 and edge_radius >= (min(apothem, height) if height > 0 else apothem):
            raise ValueError(f'must be less than the block\'s apothem and height, got {edge_radius} m for a {side} m '
                             f'{shape} {height} m tall')


def seen_model(shape, side, height=0.02, edge_radius=0.0):
    """The model the image shows of a ``shape`` block of ``side`` and ``height`` (m) whose top rim is rounded over
    with radius ``edge_radius`` (m; 0: sharp, the block's own model): its top face inset by ``EDGE_INSET_FRACTION``
    of the radius, the same centre and height. What the pose estimator fits to the detected vertices: a die's
    rounded edges make its top face look smaller, and a model of the sharp cube puts it farther away than it is."""
    try:
        check_edge_radius(side, height, edge_radius, (shape,))
    except ValueError as exc:
        raise ValueError(f'edge_radius {exc}') from None
    sharp = model_for(shape, side, height)
    if edge_radius == 0.0:
        return sharp
    return model_for(shape, side - 2.0 * EDGE_INSET_FRACTION * edge_radius * math.tan(math.pi / sharp.n), height)


@dataclass(frozen=True)
class Plane:
    """The points X with ``normal . X = offset`` (``normal`` unit, metres); the normal points up (camera side)."""
    normal: np.ndarray
    offset: float

    def __post_init__(self):
        normal = np.asarray(self.normal, dtype=float).reshape(3)
        length = np.linalg.norm(normal)
        if not (np.all(np.isfinite(normal)) and length > 0 and math.isfinite(self.offset)):
            raise ValueError(f'Plane needs a finite non-zero normal and offset, got {self.normal!r}, {self.offset!r}')
        normal = normal / length
        normal.flags.writeable = False
        object.__setattr__(self, 'normal', normal)
        object.__setattr__(self, 'offset', float(self.offset))

    def transformed(self, T_b_a):
        """This plane (expressed in frame a) expressed in frame b; ``T_b_a`` is the 4x4 pose of a in b."""
        normal_b = T_b_a[:3, :3] @ self.normal
        return Plane(normal_b, self.offset + normal_b @ T_b_a[:3, 3])

    @classmethod
    def level(cls, z):
        """The horizontal plane at height ``z`` (m), normal +z."""
        return cls(np.array([0.0, 0.0, 1.0]), float(z))

    def raised(self, distance):
        """This plane moved ``distance`` (m) along its normal (up: towards the camera side)."""
        return Plane(self.normal, self.offset + distance)

    def z_at(self, xy):
        """Height (m) of the plane above the point ``xy`` (x, y); the normal must not be horizontal."""
        return float((self.offset - self.normal[0] * xy[0] - self.normal[1] * xy[1]) / self.normal[2])

    def tilt(self):
        """Angle (rad) between the normal and +z."""
        return float(np.arccos(np.clip(abs(self.normal[2]), 0.0, 1.0)))

    def axes(self):
        """``(e1, e2)``: unit axes in the plane, e1 the frame's x (its y if x is within 26 deg of the normal) less its
        part along the normal, ``e2 = normal x e1`` (so e1, e2, normal are right-handed)."""
        axis = np.array([1.0, 0.0, 0.0]) if abs(self.normal[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
        e1 = axis - (axis @ self.normal) * self.normal
        e1 /= np.linalg.norm(e1)
        return e1, np.cross(self.normal, e1)

    def signed_distance(self, points):
        """Signed distance (m) of a point (3,) or points (N, 3) to the plane, positive on the normal's side."""
        return np.asarray(points, dtype=float) @ self.normal - self.offset


def table_plane_in_camera(T_base_camera, table):
    """The table top ``table`` (a ``Plane`` in base, e.g. ``Plane.level(z)``) as a ``Plane`` in the camera frame."""
    return table.transformed(invert(T_base_camera))
