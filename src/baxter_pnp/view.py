"""Keeping the block in view, pure: what the hand camera sees of its own hand, and steps that keep a target in
the image and clear of the fingers.

The open fingers hide the top of Baxter's hand-camera image. ``hand_clearance_px`` ray-casts the URDF's gripper
solids (``ArmKinematics.hand_solids``) through the camera model once, giving each pixel's distance to the hidden
region; ``points_in_view`` / ``path_in_view`` test a pose (or a straight path) against the image border and that
map; ``keep_in_view_step`` shortens a look-and-move step (``servo.look_and_move_step``) so the target stays in
view. Frames and units as in ``servo``: ``T_a_b`` 4x4 in metres, pixels (u, v) distorted.
"""
import cv2
import numpy as np
from scipy.spatial.transform import Rotation

from baxter_pnp import transforms
from baxter_pnp.servo import interpolate_pose, look_and_move_step


def ray_hits(origin, directions, solid):
    """(N,) bool: which rays ``origin + t * directions[i]``, t >= 0, meet ``solid`` (a
    ``kinematics.Solid``, a box or a cylinder along its z; all in the same frame, metres)."""
    R, t = solid.T[:3, :3], solid.T[:3, 3]
    o = R.T @ (np.asarray(origin, dtype=float) - t)         # in the solid's frame
    d = np.asarray(directions, dtype=float) @ R
    h = solid.half_extents
    with np.errstate(divide='ignore', invalid='ignore'):
        axes = slice(0, 3) if solid.kind == 'box' else slice(2, 3)      # slabs: all 3 axes, or z only
        near = (-h[axes] - o[axes]) / d[:, axes]
        far = (h[axes] - o[axes]) / d[:, axes]
        entry = np.max(np.minimum(near, far), axis=1)
        exit_ = np.min(np.maximum(near, far), axis=1)
        if solid.kind == 'cylinder':    # and inside the radius: |o_xy + t d_xy| <= r, a quadratic in t
            a = np.sum(d[:, :2] ** 2, axis=1)
            b = 2.0 * d[:, :2] @ o[:2]
            c = o[:2] @ o[:2] - h[0] ** 2
            root = np.sqrt(np.maximum(b * b - 4.0 * a * c, 0.0))
            crossing = b * b - 4.0 * a * c >= 0.0
            entry = np.where(crossing, np.maximum(entry, (-b - root) / (2.0 * a)), np.inf)
            exit_ = np.where(crossing, np.minimum(exit_, (-b + root) / (2.0 * a)), -np.inf)
    return exit_ >= np.maximum(entry, 0.0)


def hand_clearance_of(kinematics, T_gripper_camera, camera):
    """``hand_clearance_px`` of ``camera`` mounted at ``T_gripper_camera`` (its pose in the gripper frame, 4x4 m)
    on the arm of ``kinematics`` (an ``ArmKinematics``: the URDF's open fingers)."""
    T_camera_gripper = np.linalg.inv(T_gripper_camera)
    return hand_clearance_px(camera, [solid.moved(T_camera_gripper) for solid in kinematics.hand_solids()])


def hand_clearance_px(camera, hand_solids_camera):
    """(H, W) float32 map: each pixel's distance (pixels) to the nearest pixel where the hand hides the scene.

    ``camera`` is a ``CameraModel``; ``hand_solids_camera`` the hand's ``kinematics.Solid`` s in the camera
    optical frame (``ArmKinematics.hand_solids`` moved there). Every pixel's ray (distortion removed) is
    tested against every solid; hidden pixels are 0.
    """
    u, v = np.meshgrid(np.arange(camera.width, dtype=float), np.arange(camera.height, dtype=float))
    xy = camera.undistort_points(np.stack([u.ravel(), v.ravel()], axis=1))
    rays = np.column_stack([xy, np.ones(len(xy))])
    hidden = np.zeros(len(rays), dtype=bool)
    for solid in hand_solids_camera:
        hidden |= ray_hits(np.zeros(3), rays, solid)
    free = (~hidden).reshape(camera.height, camera.width).astype(np.uint8)
    return cv2.distanceTransform(free, cv2.DIST_L2, 5)


def polygon_clear(pixels, clearance_px, margin_px):
    """True if the convex polygon of ``pixels`` (N, 2) lies more than ``margin_px`` from every hidden pixel
    of ``clearance_px`` (see :func:`hand_clearance_px`)."""
    face = np.zeros(clearance_px.shape, np.uint8)
    cv2.fillConvexPoly(face, cv2.convexHull(np.round(pixels).astype(np.int32)), 1)
    inside = clearance_px[face > 0]
    return bool(inside.size == 0 or inside.min() > margin_px)


def points_in_view(T_base_camera, points_base, camera, margin_px=0.0, clearance_px=None):
    """True if every point (N,3) or (3,) in ``base`` is in front of the camera and projects at least
    ``margin_px`` pixels inside the image of ``camera`` (a ``CameraModel``; distorted pixels) and, given
    the hand's ``clearance_px`` map (:func:`hand_clearance_px`), their polygon is more than ``margin_px``
    from the pixels the hand hides."""
    points_camera = transforms.transform_points(transforms.invert(T_base_camera), np.atleast_2d(points_base))
    if np.any(points_camera[:, 2] <= 0.0):
        return False
    pixels = camera.project(points_camera)
    upper = np.array([camera.width - 1.0, camera.height - 1.0]) - margin_px
    if not (np.all(pixels >= margin_px) and np.all(pixels <= upper)):
        return False
    return clearance_px is None or polygon_clear(pixels, clearance_px, margin_px)


def path_in_view(T_base_gripper_from, T_base_gripper_to, points_base, camera, T_gripper_camera, margin_px=0.0,
                 clearance_px=None, samples=12):
    """True if ``points_in_view`` holds at ``samples`` poses evenly spread along the straight (SE(3)
    interpolated) gripper path between the two poses, both ends included."""
    return all(points_in_view(interpolate_pose(T_base_gripper_from, T_base_gripper_to, s) @ T_gripper_camera,
                              points_base, camera, margin_px, clearance_px)
               for s in np.linspace(0.0, 1.0, samples))


def keep_in_view_step(T_base_gripper, T_base_goal, fraction, points_base, camera, T_gripper_camera,
                      margin_px=20.0, max_translation=None, max_rotation=None, bisections=12, clearance_px=None):
    """``look_and_move_step`` that keeps ``points_base`` (the block's centre, or its vertices) in view.

    The step is split, in the camera's axes at the current pose, into a *lateral* translation
    (across the optical axis) and the rest: the *axial* translation (along the optical axis) plus
    the rotation. Approaching and rotating are what push an off-centre target out of the image
    (x = X/Z grows as Z shrinks), while the lateral motion toward the goal re-centres it. So:

    1. the full step, if the points stay ``margin_px`` inside the image after it;
    2. otherwise the full lateral step with the axial and rotation parts scaled by the largest factor
       in [0, 1] that keeps the points in view (bisection);
    3. otherwise (even the lateral step alone loses them) the lateral step alone, scaled likewise;
       if they are already out of view (with the margin) at the current pose, the whole lateral step:
       it moves the camera toward where it sees the block as it will from the goal, while approaching or
       rotating would push the block further out. ``camera`` is a ``CameraModel``,
    ``T_gripper_camera`` the camera's pose in the gripper frame; with the hand's ``clearance_px`` map
    (:func:`hand_clearance_px`) "in view" also means not behind (nor within ``margin_px`` of) a finger.
    Returns ``T_base_gripper_next``.
    """
    def in_view(T_base_gripper_candidate):
        return points_in_view(T_base_gripper_candidate @ T_gripper_camera, points_base, camera, margin_px,
                              clearance_px)

    full_step = look_and_move_step(T_base_gripper, T_base_goal, fraction, max_translation, max_rotation)
    if in_view(full_step):
        return full_step

    R_base_camera = T_base_gripper[:3, :3] @ T_gripper_camera[:3, :3]
    translation_camera = R_base_camera.T @ (full_step[:3, 3] - T_base_gripper[:3, 3])
    lateral_base = R_base_camera @ np.array([translation_camera[0], translation_camera[1], 0.0])
    axial_base = R_base_camera @ np.array([0.0, 0.0, translation_camera[2]])
    rotvec_gripper = Rotation.from_matrix(T_base_gripper[:3, :3].T @ full_step[:3, :3]).as_rotvec()

    def step(lateral_scale, rest_scale):
        rotation = Rotation.from_matrix(T_base_gripper[:3, :3]) * Rotation.from_rotvec(rest_scale * rotvec_gripper)
        translation = T_base_gripper[:3, 3] + lateral_scale * lateral_base + rest_scale * axial_base
        return transforms.make_transform(rotation, translation)

    def largest_feasible(candidate):
        """Largest a in [0, 1] with candidate(a) in view, given candidate(0) in view (bisection)."""
        feasible, infeasible = 0.0, 1.0
        for _ in range(bisections):
            middle = 0.5 * (feasible + infeasible)
            if in_view(candidate(middle)):
                feasible = middle
            else:
                infeasible = middle
        return candidate(feasible)

    if in_view(step(1.0, 0.0)):
        return largest_feasible(lambda a: step(1.0, a))
    if in_view(T_base_gripper):
        return largest_feasible(lambda b: step(b, 0.0))
    return step(1.0, 0.0)
