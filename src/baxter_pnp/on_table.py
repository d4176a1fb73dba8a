"""A block's pose from its top-face polygon on a known table (beyond the thesis): the polygon's vertices cast onto
the plane of the top face (the table plane raised by the block's height) and the model's top face fitted to them
there, in position, yaw and size.

The polygon pose (``pose.estimate_pose``) takes the depth from the top face's size in the image. A face's edges are
found to a pixel or two wherever the face is small, blurred or rounded (a die's rim, a triangle's blunted corners:
the 15-25 px faces of the independent renderer are seen 0.69-1.41 times their size): on a 15 px face one pixel is 7 %
of the depth, 35 mm at 0.5 m, and the pick's height rule refuses the pose. Standing on the known table the block has
three degrees of freedom; the polygon's centre and edge directions fix them to a few millimetres whatever its size
error (docs/perception.md, "A small face's pose on the table"), and the fitted size says whether the polygon can be
the block's top face at all.

Frames and units: the camera optical frame, metres; the plane's normal points up, towards the camera
(``models.Plane``); pixels distorted as the camera delivers them unless said otherwise.
"""
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class TopFaceFit:
    """The model's top face fitted to a polygon on the table.

    ``T_camera_block``: 4x4 pose (top-face centre, z along the table's normal, the model's size); ``scale``: the
    polygon's size over the model's (a similarity fit in the top face's plane); ``residual_px``: RMS distance
    (distorted px) of the polygon's vertices to the fitted face of that size, projected: how much the polygon's shape
    is the model's; ``side_px``: the polygon's mean side (px)."""
    T_camera_block: np.ndarray
    scale: float
    residual_px: float
    side_px: float


def fit_top_face(vertices_px, camera, model, table_plane):
    """The ``TopFaceFit`` of ``model``'s top face (``models.PolygonModel``, ``model.height`` above ``table_plane``, in
    the camera frame) to the polygon ``vertices_px`` ((n, 2) distorted pixels, n = ``model.n``, either winding); None
    when a vertex's ray does not meet that plane in front of the camera or the polygon is degenerate; ValueError for
    the wrong vertex count or a camera below the table."""
    vertices = np.asarray(vertices_px, dtype=float).reshape(-1, 2)
    if len(vertices) != model.n:
        raise ValueError(f'fit_top_face: a {model.shape} needs {model.n} vertices, got {len(vertices)}')
    if table_plane.signed_distance(np.zeros(3)) <= 0:
        raise ValueError('fit_top_face: the camera must be on the side the table plane\'s normal points to')
    normal = table_plane.normal
    rays = np.column_stack([camera.undistort_points(vertices), np.ones(len(vertices))])
    along = rays @ normal
    if not np.all(np.isfinite(rays)) or np.any(along >= 0.0):
        return None                        # a ray parallel to the plane or meeting it behind the camera
    points = rays * ((table_plane.offset + model.height) / along)[:, None]
    e1, e2 = table_plane.axes()
    centre = points.mean(axis=0)
    seen = (points - centre) @ e1 + 1j * ((points - centre) @ e2)     # in the plane, complex: e1 + i e2
    face = model.vertices[:, 0] + 1j * model.vertices[:, 1]          # block frame, centred on the top face
    size = float(np.vdot(face, face).real)
    if not np.any(np.abs(seen) > 0.0):
        return None
    # a similarity z = scale * e^(i yaw) for each pairing of the vertices (either winding, any first vertex) by least
    # squares; the pairing with the least residual wins
    pairings = (np.arange(model.n)[None, :] + np.arange(model.n)[:, None]) % model.n
    pairings = np.concatenate([pairings, pairings[:, ::-1]])
    candidates = seen[pairings]                                       # (2n, n)
    z = candidates @ face.conj() / size
    best = int(np.argmin(np.sum(np.abs(candidates - z[:, None] * face) ** 2, axis=1)))
    z, paired = z[best], pairings[best]
    yaw = float(np.angle(z))
    x = np.cos(yaw) * e1 + np.sin(yaw) * e2
    T = np.eye(4)
    T[:3, :3] = np.column_stack([x, np.cross(normal, x), normal])
    T[:3, 3] = centre
    fitted = z * face
    projected = camera.project(centre + np.outer(fitted.real, e1) + np.outer(fitted.imag, e2))
    residual = float(np.sqrt(np.mean(np.sum((projected - vertices[paired]) ** 2, axis=1))))
    side_px = float(np.mean(np.linalg.norm(vertices - np.roll(vertices, -1, axis=0), axis=1)))
    return TopFaceFit(T, float(abs(z)), residual, side_px)
