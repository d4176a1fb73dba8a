"""The table map, pure: every block seen during a survey, in ``base``, fused across looks (issue 14).

A *sighting* is one block in one look: shape, colour, ``T_base_block`` (4x4, m; docs/ARCHITECTURE.md's block
frame: top-face centre, z up) and the position's covariance (3x3, m^2, in base). Uncertainty model
(``sightings_from_look``): the pose estimator's Gauss-Newton covariance of the position (``pose.PoseEstimate``),
rotated into base: along the viewing ray it grows with the square of the depth (a 33 mm square 0.55 m away, seen
at 45 deg: 11 mm, against 0.7 mm across the ray), which the earlier isotropic model missed; every direction at
least the lateral error ``sighting_std``: the reprojection error back-projected at the block's depth,
``depth * sqrt(residual_px^2 + pixel_std^2) / f`` (f the mean focal length, px; ``pixel_std`` the corner
detector's noise floor, 1 px). A sighting without a covariance is isotropic, ``std`` in every direction; ``std``
is always the square root of the largest eigenvalue (m), the uncertainty along the least certain direction.

Association (``TableMap.add_look``): the sightings of one look are matched, per (shape, colour), to the map's
blocks of that shape and colour by ``scipy.optimize.linear_sum_assignment`` on their xy distance, gated at
``radius`` (default ``task.target.TRACK_RADIUS``): a matched sighting is the same block, an unmatched one a new
block; two sightings of one look are never merged. Fusion: information-weighted position (covariance
``inv(sum(inv(C_i)))``, so that two views from different sides cancel each other's depth error) and, for the yaw
about base +z, the circular mean of ``n * yaw`` weighted by ``1 / std^2`` (n-fold
symmetry: a square's yaw is defined modulo 90 deg), divided by n; ``views`` counts the looks, ``last_seen`` is
the newest stamp (s). ``remove`` forgets a picked block, ``moved`` resets one placed elsewhere.
"""
import json
from dataclasses import dataclass, field
from typing import List, NamedTuple, Optional

import numpy as np
from scipy.optimize import linear_sum_assignment

from baxter_pnp.models import SHAPES
from baxter_pnp.pose import largest_std

TRACK_RADIUS = 0.05     # m: task.target.TRACK_RADIUS (kept here so the map imports nothing but models)
PIXEL_STD = 1.0         # px: the corner detector's noise floor


class Sighting(NamedTuple):
    """One block in one look: ``shape`` and ``colour`` (names), ``T_base_block`` (4x4, m), position ``std`` (m) and
    ``covariance`` (3x3 in base, m^2; None: ``std`` in every direction)."""
    shape: str
    colour: str
    T_base_block: np.ndarray
    std: float
    covariance: Optional[np.ndarray] = None

    def position_covariance(self):
        """(3, 3) covariance of the position in base (m^2)."""
        return np.eye(3) * self.std ** 2 if self.covariance is None else self.covariance


def sighting_std(depth, residual_px, focal_px, pixel_std=PIXEL_STD):
    """Position standard deviation (m) of a block ``depth`` m from the camera whose pose fits its vertices to
    ``residual_px`` (RMS px) in an image of focal length ``focal_px`` (px): the module docstring's model."""
    return float(depth * np.hypot(residual_px, pixel_std) / focal_px)


def floored_covariance(covariance, std):
    """``covariance`` (3x3, m^2) with every eigenvalue raised to at least ``std ** 2``."""
    eigenvalues, vectors = np.linalg.eigh(covariance)
    return (vectors * np.maximum(eigenvalues, std ** 2)) @ vectors.T


def lateral_std(pose, camera, pixel_std=PIXEL_STD):
    """``sighting_std`` of a ``pose.PoseEstimate`` seen by ``camera`` (``CameraModel``: its mean focal length), m."""
    return sighting_std(np.linalg.norm(pose.T_camera_object[:3, 3]), pose.residual_px,
                        0.5 * (camera.K[0, 0] + camera.K[1, 1]), pixel_std)


def sightings_from_look(observations, T_base_camera, camera, pixel_std=PIXEL_STD):
    """The ``Sighting`` s of a look's ``perception.BlockObservation`` s (those with a pose), through
    ``T_base_camera`` (camera pose in base, 4x4 m) and ``camera`` (``CameraModel``); the module docstring's
    uncertainty model."""
    R_base_camera = T_base_camera[:3, :3]
    sightings = []
    for observation in observations:
        pose = observation.pose
        if pose is None:
            continue
        T_camera_block = pose.T_camera_object
        lateral = lateral_std(pose, camera, pixel_std)
        estimated = np.zeros((3, 3)) if pose.covariance is None else pose.covariance[:3, :3]
        covariance = floored_covariance(R_base_camera @ estimated @ R_base_camera.T, lateral)
        sightings.append(Sighting(observation.detection.shape, observation.detection.colour,
                                  T_base_camera @ T_camera_block, largest_std(covariance), covariance))
    return sightings


def symmetry_order(shape):
    """n of an n-fold symmetric block (its top face a regular n-gon): yaw is defined modulo 2 pi / n."""
    return SHAPES[shape]


def yaw_of(T_base_block):
    """Yaw (rad) of a block frame about base +z (the block lying on a level table)."""
    return float(np.arctan2(T_base_block[1, 0], T_base_block[0, 0]))


def wrap_yaw(yaw, shape):
    """``yaw`` (rad) wrapped into [-pi/n, pi/n), n the shape's symmetry order."""
    period = 2.0 * np.pi / symmetry_order(shape)
    return float((yaw + 0.5 * period) % period - 0.5 * period)


@dataclass
class MapBlock:
    """A block of the map: ``id``, ``shape``, ``colour``, fused ``position`` (3,) m in base and its ``covariance``
    (3x3, m^2, base; ``std``: along the least certain direction, m), ``yaw`` (rad, in [-pi/n, pi/n)), ``views``
    (looks that saw it), ``last_seen`` (s), ``view_ids`` (the looks' ids). ``_yaw_sum`` is the weighted sum of unit
    vectors at ``n * yaw`` (the circular mean's state)."""
    id: int
    shape: str
    colour: str
    position: np.ndarray
    covariance: np.ndarray
    yaw: float
    views: int
    last_seen: float
    view_ids: List = field(default_factory=list)
    _yaw_sum: np.ndarray = field(default=None, repr=False)

    @property
    def std(self):
        """Standard deviation of the position along its least certain direction (m)."""
        return largest_std(self.covariance)

    @property
    def T_base_block(self):
        """4x4 pose in base (m): the fused position, rotated ``yaw`` about +z."""
        c, s = np.cos(self.yaw), np.sin(self.yaw)
        T = np.eye(4)
        T[:2, :2] = [[c, -s], [s, c]]
        T[:3, 3] = self.position
        return T

    def to_json(self):
        """JSON-ready dict (m, rad, s)."""
        return {'id': self.id, 'shape': self.shape, 'colour': self.colour,
                'position_m': [float(v) for v in self.position], 'std_m': self.std,
                'covariance_m2': np.asarray(self.covariance, dtype=float).tolist(),
                'yaw_rad': float(self.yaw), 'views': int(self.views), 'last_seen': float(self.last_seen),
                'view_ids': list(self.view_ids), 'yaw_sum': [float(v) for v in self._yaw_sum]}

    @classmethod
    def from_json(cls, d):
        """Inverse of ``to_json`` (a map written before the covariance: isotropic ``std_m``)."""
        covariance = (np.array(d['covariance_m2'], dtype=float) if 'covariance_m2' in d
                      else np.eye(3) * float(d['std_m']) ** 2)
        return cls(int(d['id']), d['shape'], d['colour'], np.array(d['position_m'], dtype=float),
                   covariance, float(d['yaw_rad']), int(d['views']), float(d['last_seen']),
                   list(d['view_ids']), np.array(d['yaw_sum'], dtype=float))


class TableMap:
    """The blocks seen on the table, fused across looks (module docstring); ``radius`` (m) the association gate."""

    def __init__(self, radius=TRACK_RADIUS):
        self.radius = float(radius)
        self._blocks = {}
        self._next_id = 1

    def blocks(self):
        """The ``MapBlock`` s, by id."""
        return [self._blocks[k] for k in sorted(self._blocks)]

    def block(self, block_id):
        """The ``MapBlock`` of ``block_id`` (KeyError if none)."""
        return self._blocks[block_id]

    def __len__(self):
        return len(self._blocks)

    def add_look(self, sightings, stamp, view_id=None):
        """Fuse one look's ``Sighting`` s (stamp ``stamp`` s, id ``view_id``) into the map; returns the block id
        of each sighting, in order."""
        ids = [None] * len(sightings)
        groups = {}
        for k, s in enumerate(sightings):
            groups.setdefault((s.shape, s.colour), []).append(k)
        for (shape, colour), members in groups.items():
            known = [b for b in self.blocks() if b.shape == shape and b.colour == colour]
            matched = {}
            if known:
                xy = np.array([sightings[k].T_base_block[:2, 3] for k in members])
                cost = np.linalg.norm(xy[:, None, :] - np.array([b.position[:2] for b in known])[None], axis=2)
                gated = np.where(cost <= self.radius, cost, 1e6)
                for row, col in zip(*linear_sum_assignment(gated)):
                    if cost[row, col] <= self.radius:
                        matched[members[row]] = known[col]
            for k in members:
                block = matched.get(k)
                if block is None:
                    block = self._new(sightings[k], stamp, view_id)
                else:
                    self._fuse(block, sightings[k], stamp, view_id)
                ids[k] = block.id
        return ids

    def _new(self, sighting, stamp, view_id):
        n = symmetry_order(sighting.shape)
        weight = 1.0 / sighting.std ** 2
        yaw = wrap_yaw(yaw_of(sighting.T_base_block), sighting.shape)
        block = MapBlock(self._next_id, sighting.shape, sighting.colour,
                         np.array(sighting.T_base_block[:3, 3], dtype=float), sighting.position_covariance(), yaw, 1,
                         float(stamp), [view_id], weight * np.array([np.cos(n * yaw), np.sin(n * yaw)]))
        self._blocks[block.id] = block
        self._next_id += 1
        return block

    @staticmethod
    def _fuse(block, sighting, stamp, view_id):
        n = symmetry_order(block.shape)
        W_old, W_new = np.linalg.inv(block.covariance), np.linalg.inv(sighting.position_covariance())
        block.covariance = np.linalg.inv(W_old + W_new)
        block.position = block.covariance @ (W_old @ block.position + W_new @ sighting.T_base_block[:3, 3])
        w_new = 1.0 / sighting.std ** 2
        yaw = yaw_of(sighting.T_base_block)
        block._yaw_sum = block._yaw_sum + w_new * np.array([np.cos(n * yaw), np.sin(n * yaw)])
        block.yaw = wrap_yaw(np.arctan2(block._yaw_sum[1], block._yaw_sum[0]) / n, block.shape)
        block.views += 1
        block.last_seen = max(block.last_seen, float(stamp))
        block.view_ids.append(view_id)

    def remove(self, block_id):
        """Forget a block (picked up); returns its ``MapBlock``."""
        return self._blocks.pop(block_id)

    def moved(self, block_id, sighting, stamp):
        """A block put where ``sighting`` (a ``Sighting``) saw it at ``stamp`` (s): its fused history is replaced by
        this one pose (one view). Returns the ``MapBlock``."""
        old = self._blocks[block_id]
        n = symmetry_order(old.shape)
        yaw = wrap_yaw(yaw_of(sighting.T_base_block), old.shape)
        block = MapBlock(block_id, old.shape, old.colour, np.array(sighting.T_base_block[:3, 3], dtype=float),
                         sighting.position_covariance(), yaw, 1, float(stamp), [None],
                         np.array([np.cos(n * yaw), np.sin(n * yaw)]) / sighting.std ** 2)
        self._blocks[block_id] = block
        return block

    def nearest(self, xy, shape=None, colour=None):
        """The block nearest ``xy`` (m in base) of that shape and colour (None: any), or None if the map has none."""
        candidates = [b for b in self.blocks() if (shape is None or b.shape == shape)
                      and (colour is None or b.colour == colour)]
        if not candidates:
            return None
        return min(candidates, key=lambda b: np.linalg.norm(b.position[:2] - np.asarray(xy, dtype=float)))

    def to_json(self):
        """JSON text of the map."""
        return json.dumps({'radius_m': self.radius, 'next_id': self._next_id,
                           'blocks': [b.to_json() for b in self.blocks()]})

    @classmethod
    def from_json(cls, text):
        """Inverse of ``to_json``."""
        d = json.loads(text)
        table_map = cls(d['radius_m'])
        table_map._next_id = int(d['next_id'])
        for entry in d['blocks']:
            block = MapBlock.from_json(entry)
            table_map._blocks[block.id] = block
        return table_map


def check_track_radius():
    """The map's default gate equals ``task.target.TRACK_RADIUS`` (m)."""
    from baxter_pnp.task.target import TRACK_RADIUS as target_radius
    return TRACK_RADIUS == target_radius
