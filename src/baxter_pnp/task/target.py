"""Target choice, pure: which of a look's observations is the block, and where to look from when it is lost or
cut by the image border.

A look gives ``perception.BlockObservation`` s (pose in the camera frame); ``T_base_camera`` (4x4, m) puts them
in ``base``. An estimate is *believable* when its RMS reprojection residual is below ``max_residual_px`` and (a
block lying on the table) its top face is within ``height_tolerance`` of the table top + block height:
``max_height_error``, or three of the estimate's own standard deviations along base z (its covariance rotated
into base) up to ``far_height_error``: a far block seen at a grazing angle, whose depth is uncertain by a centimetre or
more, is believed and approached (PBVS steps a fraction of the way, the velocity laws go to the view pose, and
the nearer looks shrink its uncertainty, and the tolerance with it), not dropped. Blocks within two sides of
``place_xy`` count as already placed. Among believable ones the target is the one nearest
the last estimate (tracking the same block), else the largest / most central (``vision.select_target``); its
position is then updated with the table's height, known to ``table_height_sigma`` (``on_the_table``).
"""
import dataclasses
from dataclasses import dataclass
from typing import Optional, Sequence

import numpy as np

from baxter_pnp import perception, pose, vision
from baxter_pnp.models import Plane
from baxter_pnp.transforms import invert, raised, transform_points

TRACK_RADIUS = 0.05     # m: an estimate this close to the last one is the same block
GRASP_HEIGHT_WARNING = 0.003    # m: see grasp_height_suspect
STEADY_WINDOW = 3       # steady_position: the newest looks averaged, those within STEADY_GATE combined stds plus
STEADY_GATE = 3.0       # STEADY_SLACK (m) of the newest
STEADY_SLACK = 0.001


@dataclass(frozen=True)
class TargetRules:
    """What the target is and which estimates of it to believe (metres, pixels; positions in base)."""
    shape: str
    colour: str
    side_length: float
    block_height: float
    table: Plane                # the table top in base
    max_residual_px: float
    max_height_error: float
    place_xy: Optional[Sequence[float]] = None
    table_height_sigma: float = 0.0   # how well the table top's height is known (m); 0: the target keeps its estimate
    far_height_error: float = 0.08    # the most an uncertain (far) estimate's height tolerance grows to (m)

    @classmethod
    def of(cls, task_config, table):
        """The rules of a task config with ``shape``, ``colour``, ``side_length``, ``block_height``,
        ``max_residual_px``, ``max_height_error``, ``place_xy``, ``table_height_sigma`` and ``far_height_error``
        (e.g. ``pick.PickConfig``) on the ``table`` top (``models.Plane`` in base)."""
        c = task_config
        return cls(c.shape, c.colour, c.side_length, c.block_height, table, c.max_residual_px,
                   c.max_height_error, c.place_xy, c.table_height_sigma, c.far_height_error)


def believable(observation, T_base_camera, rules, on_table=True, placed_too=False):
    """True if ``observation``'s estimate can be the target (see the module docstring); ``on_table`` checks the
    height, ``placed_too`` accepts blocks at ``place_xy``."""
    pose = observation.pose
    if pose is None or pose.residual_px > rules.max_residual_px:
        return False
    position = (T_base_camera @ pose.T_camera_object)[:3, 3]
    if (not placed_too and rules.place_xy is not None
            and np.linalg.norm(position[:2] - np.asarray(rules.place_xy)) < 2 * rules.side_length):
        return False
    return not on_table or abs(height_error(pose, T_base_camera, rules)) <= height_tolerance(pose, T_base_camera, rules)


def height_error(pose, T_base_camera, rules):
    """How far (m) the estimate ``pose`` puts the top face above (+) or below (-) the table top + block height."""
    position = (T_base_camera @ pose.T_camera_object)[:3, 3]
    return float(position[2] - (rules.table.z_at(position[:2]) + rules.block_height))


def implied_side_length(pose, T_base_camera, rules):
    """The side length (m) for which the estimate ``pose`` would put the top face at its height on the table, None
    if its ray does not meet that height in front of the camera. The image fixes a block's pose up to scale about
    the camera centre: a block smaller than the model is estimated farther along the same ray, by the ratio of
    the sizes (a 38.6 mm block taken for 40 mm: 3.6 % farther, 7 mm low at 0.19 m)."""
    ray = T_base_camera[:3, :3] @ pose.T_camera_object[:3, 3]
    position = T_base_camera[:3, 3] + ray
    expected_z = rules.table.z_at(position[:2]) + rules.block_height
    scale = (expected_z - T_base_camera[2, 3]) / ray[2] if ray[2] != 0 else -1.0
    return float(rules.side_length * scale) if scale > 0 else None


def height_tolerance(pose, T_base_camera, rules):
    """How far (m) the estimate ``pose`` may put a block off its height on the table (module docstring)."""
    std_z = height_std(pose, T_base_camera)
    if std_z is None:
        return rules.max_height_error
    return float(np.clip(3.0 * std_z, rules.max_height_error, max(rules.far_height_error, rules.max_height_error)))


def height_std(pose, T_base_camera):
    """The standard deviation (m) of the estimate ``pose`` along base z (its covariance rotated into base), None
    without a covariance."""
    if pose.covariance is None:
        return None
    z_base = T_base_camera[2, :3]           # base z in camera coordinates: var_z = z^T C z
    return float(np.sqrt(max(z_base @ pose.covariance[:3, :3] @ z_base, 0.0)))


def rejected_for_height(observations, T_base_camera, rules):
    """The ``observations`` of the target's shape and colour that only their height on the table keeps from being
    believable (``believable`` with ``on_table=False`` accepts them, with it not)."""
    return [o for o in observations
            if (o.detection.shape, o.detection.colour) == (rules.shape, rules.colour)
            and believable(o, T_base_camera, rules, on_table=False)
            and abs(height_error(o.pose, T_base_camera, rules)) > height_tolerance(o.pose, T_base_camera, rules)]


def grasp_height_suspect(pose, T_base_camera, rules):
    """True if the estimate a grasp goes by is off its height on the table by more than ``GRASP_HEIGHT_WARNING``
    and three of its own stds along z (believed, yet unlikely from noise: a wrong ``side_length``?)."""
    std_z = height_std(pose, T_base_camera) or 0.0
    return abs(height_error(pose, T_base_camera, rules)) > max(3.0 * std_z, GRASP_HEIGHT_WARNING)


def choose_target(observations, T_base_camera, rules, image_size, T_base_last=None, on_table=True,
                  placed_too=False):
    """The target among ``observations`` (``perception.BlockObservation`` s) or None: the believable one
    within TRACK_RADIUS of the last estimate ``T_base_last`` (4x4 in base) if any, else the largest / most
    central (``vision.select_target``; ``image_size`` (width, height) px)."""
    posed = [o for o in observations if believable(o, T_base_camera, rules, on_table, placed_too)]
    if not posed:
        return None
    if T_base_last is not None:
        distances = [np.linalg.norm((T_base_camera @ o.pose.T_camera_object)[:3, 3] - T_base_last[:3, 3])
                     for o in posed]
        if min(distances) < TRACK_RADIUS:
            return posed[int(np.argmin(distances))]
    chosen = vision.select_target([o.detection for o in posed], rules.shape, rules.colour, image_size)
    chosen = next(o for o in posed if o.detection is chosen)
    return on_the_table(chosen, T_base_camera, rules) if on_table else chosen


def on_the_table(observation, T_base_camera, rules):
    """``observation`` with its position updated by the table: its top face lies ``block_height`` above the table
    top, known to ``table_height_sigma`` (a scalar Kalman update along the estimate's own translation covariance,
    ``K = C n / (n^T C n + sigma^2)``; the covariance shrinks to match). A far block's depth from its polygon's
    size is uncertain by centimetres, the table's height by millimetres; a close block's estimate hardly moves.
    Applied to a believed target only, after the height rule has judged its raw estimate. Unchanged without a
    ``table_height_sigma`` or a covariance."""
    estimate = observation.pose
    if rules.table_height_sigma <= 0.0 or estimate.covariance is None:
        return observation
    R_base_camera, t_base_camera = T_base_camera[:3, :3], T_base_camera[:3, 3]
    covariance = R_base_camera @ estimate.covariance[:3, :3] @ R_base_camera.T       # translation, in base
    position = R_base_camera @ estimate.T_camera_object[:3, 3] + t_base_camera
    normal = rules.table.normal
    innovation = rules.table.offset + rules.block_height - normal @ position
    gain = covariance @ normal / (normal @ covariance @ normal + rules.table_height_sigma ** 2)
    T_camera_object = estimate.T_camera_object.copy()
    T_camera_object[:3, 3] += R_base_camera.T @ (gain * innovation)
    updated = estimate.covariance.copy()
    updated[:3, :3] = R_base_camera.T @ (covariance - np.outer(gain, normal @ covariance)) @ R_base_camera
    return dataclasses.replace(observation, pose=dataclasses.replace(estimate, T_camera_object=T_camera_object,
                                                                     covariance=updated))


def predicted_target(observation, T_base_block, T_base_camera, camera, model):
    """``observation`` (the block's last believable ``perception.BlockObservation``) carried to a new camera pose:
    the block, still at ``T_base_block`` (4x4 in base), seen from ``T_base_camera`` through ``camera`` (a
    ``CameraModel``): its pose in the camera frame and ``model``'s top-face vertices projected (distorted pixels),
    the estimate's method ``'predicted'`` and no covariance. What the velocity laws go on with through a look that
    does not show the block believably (a shadow or a glare over it for a frame or two)."""
    T_camera_block = invert(T_base_camera) @ T_base_block
    vertices_px = camera.project(transform_points(T_camera_block, model.vertices))
    detection = dataclasses.replace(observation.detection, vertices_px=vertices_px,
                                    centroid_px=vertices_px.mean(axis=0), touches_border=False)
    return perception.BlockObservation(detection, pose.PoseEstimate(T_camera_block, 0.0, 'predicted'))


def recentred(T_base_gripper, T_base_camera, T_base_block, rise):
    """Gripper pose translated so the camera's optical axis meets the (partly visible) block's estimated centre
    at its height, and ``rise`` m higher (a wider view)."""
    axis = T_base_camera[:3, 2]
    plane_z = T_base_block[2, 3]
    hit = T_base_camera[:3, 3] + axis * (plane_z - T_base_camera[2, 3]) / axis[2] if abs(axis[2]) > 1e-3 \
        else T_base_camera[:3, 3]
    T = np.array(T_base_gripper, dtype=float)
    T[:2, 3] += T_base_block[:2, 3] - hit[:2]
    T[2, 3] += rise
    return T


def search_pose(T_base_gripper, lost, backoff_height, T_base_view=None, reachable=None):
    """Where to look from after ``lost`` + 1 looks in a row without the block: ``T_base_view`` (a view of where
    it was last seen, e.g. ``pick.view_pose``) ``lost * backoff_height`` higher when given and ``reachable``
    (a predicate on a gripper pose), else ``backoff_height`` above the current ``T_base_gripper``.
    Returns (pose, True if it is the view of the last-seen block)."""
    if T_base_view is not None:
        T_view = raised(T_base_view, lost * backoff_height)
        if reachable is None or reachable(T_view):
            return T_view, True
    return raised(T_base_gripper, backoff_height), False


def steady_position(history, window=STEADY_WINDOW):
    """The position (3,) in base of a block standing still, from ``history`` [(position (3,) m, std m or None)] of
    the looks at it, newest last: the inverse-variance mean of the newest looks, at most ``window``, back to the
    first that lies farther than ``STEADY_GATE`` combined stds plus ``STEADY_SLACK`` from the newest (a block
    moved, or estimated otherwise now, starts afresh); the newest alone when its std is unknown. A PBVS approach
    whose estimates alternate between two solutions a few millimetres apart steps toward their mean instead of
    chasing each one (docs/trials.md, "Session 22")."""
    newest, newest_std = history[-1]
    newest = np.asarray(newest, dtype=float)
    if newest_std is None:
        return newest
    total, weights = np.zeros(3), 0.0
    for position, std in reversed(history[-window:]):
        position = np.asarray(position, dtype=float)
        if std is None or np.linalg.norm(position - newest) > STEADY_GATE * np.hypot(std, newest_std) + STEADY_SLACK:
            break
        weight = 1.0 / max(std, 1e-6) ** 2
        total, weights = total + weight * position, weights + weight
    return total / weights
