"""What a pick's look makes of the independent renderer's frames (``make bench-perception``'s last table).

The accuracy tables time and score the vision pipeline and each estimator on the same vertices. A look on the robot
does more (``task.eye.Eye.look``): ``perception.observe_blocks`` with the shape and colour asked for, the block's
model and edge radius and the table plane (its whole-blob fallbacks, the plane prior's refusals), then the pick's
belief rules (``task.target.choose_target``: RMS residual under ``max_residual_px``, the top face at its height on
the table within the estimate's own tolerance, then the position updated with the table's height,
``table_height_sigma``). Here the table plane is the truth's moved along its normal by an error drawn from that
sigma (what a robot's ``table_top_z`` and hand-eye calibration are good to), in a base frame whose z is its normal,
and the block's edge radius is the renderer's bevel (as a user gives a die's). Counted per frame: a target
believed; the right one (its centre within half a side of the truth); its position error (mm). Pure measurement:
the application never sees the truth.
"""
import numpy as np

from baxter_pnp import perception, pick
from baxter_pnp.models import Plane
from baxter_pnp.task import target


def true_table_plane(T_camera_block, height):
    """The table-top plane (the bottom face of a block ``height`` m tall) in the camera frame, normal towards
    the block's top."""
    normal = T_camera_block[:3, 2]
    bottom_centre = T_camera_block[:3, 3] - height * normal
    return Plane(normal, float(normal @ bottom_centre))


def base_of_table(table_plane_camera):
    """``(T_base_camera, table)``: a base frame whose z axis is the camera-frame ``table_plane_camera``'s normal,
    and the table top in it (level, at its offset): what the robot knows from forward kinematics."""
    T_base_camera = np.eye(4)
    T_base_camera[:3, :3] = np.array([*table_plane_camera.axes(), table_plane_camera.normal])
    return T_base_camera, Plane.level(table_plane_camera.offset)


def look_at(image, spec, colour, T_camera_block, table_plane, camera, config, pick_config=None):
    """One frame's look: ``(believed, right, position error mm or None)`` for the block ``spec``
    (``render_independent.Block``) of ``colour`` at ``T_camera_block``, the table top known as ``table_plane``
    (camera frame); ``pick_config`` (default ``pick.PickConfig()``) gives the belief rules."""
    pick_config = pick_config or pick.PickConfig()
    T_base_camera, table = base_of_table(table_plane)
    observations = perception.observe_blocks(image, camera, config, spec.side, spec.height, shape=spec.shape,
                                             colour=colour, table_plane=table_plane, edge_radius=spec.bevel)
    rules = target.TargetRules(spec.shape, colour, spec.side, spec.height, table, pick_config.max_residual_px,
                               pick_config.max_height_error, table_height_sigma=pick_config.table_height_sigma,
                               far_height_error=pick_config.far_height_error)
    chosen = target.choose_target(observations, T_base_camera, rules, (camera.width, camera.height))
    if chosen is None:
        return False, False, None
    error = float(np.linalg.norm(chosen.pose.T_camera_object[:3, 3] - T_camera_block[:3, 3]))
    return True, error < spec.side / 2.0, 1000.0 * error


def summarise_looks(kind, looks):
    """``look_at``'s results of one dataset: the share of frames with a believed target and with the right one, and
    the right ones' position error (median, p90, mm)."""
    errors = [error for _, right, error in looks if right]
    return {'dataset': kind, 'frames': len(looks),
            'believed': sum(believed for believed, _, _ in looks) / max(1, len(looks)),
            'right': len(errors) / max(1, len(looks)),
            'position_err_mm_median': float(np.median(errors)) if errors else float('nan'),
            'position_err_mm_p90': float(np.percentile(errors, 90)) if errors else float('nan')}


def format_as_picked(results):
    """Markdown table of ``summarise_looks``'s results."""
    lines = ['| dataset | frames | target believed | the right block | pos med mm | pos p90 mm |',
             '|---|---|---|---|---|---|']
    lines += ['| %s | %d | %.1f%% | %.1f%% | %.2f | %.2f |' % (
        r['dataset'], r['frames'], 100.0 * r['believed'], 100.0 * r['right'], r['position_err_mm_median'],
        r['position_err_mm_p90']) for r in results]
    return '\n'.join(lines)
