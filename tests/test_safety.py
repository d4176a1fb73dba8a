"""Unit tests of baxter_pnp.safety on the left arm's real kinematics (urdf/baxter.urdf): no ROS."""
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from baxter_pnp.kinematics import NEUTRAL, ArmKinematics
from baxter_pnp.models import Plane
from baxter_pnp.safety import ArmSafety, SafetyLimits, UnsafeCommand
from baxter_pnp.transforms import make_transform

TABLE_Z = -0.15
DOWN = Rotation.from_euler('xyz', [np.pi, 0, 0])          # gripper z axis pointing down (-z of base)
ALONG_X = Rotation.from_euler('xyz', [0, np.pi / 2, 0])   # gripper z axis pointing along +x of base


@pytest.fixture(scope='module')
def kinematics():
    arm = ArmKinematics('left')
    yield arm
    arm.close()


@pytest.fixture(scope='module')
def safety(kinematics):
    return ArmSafety.for_arm(kinematics, table_top_z=TABLE_Z, tip_margin=0.01, hand_margin=0.05)


def ik(kinematics, rotation, xyz, seed=None):
    q = kinematics.ik(make_transform(rotation, xyz), seed=seed)
    assert q is not None, f'test set-up: no IK solution for {xyz}'
    return q


def test_safe_move_passes(safety, kinematics):
    q_above = ik(kinematics, DOWN, (0.7, 0.3, -0.05))
    q_lower = ik(kinematics, DOWN, (0.7, 0.3, -0.12), seed=q_above)
    safety.check_joint_target(q_lower, q_above)
    safety.check_joint_target(np.array(NEUTRAL) + 0.1, NEUTRAL)
    safety.check_velocity(np.full(7, 0.2), 0.2, q_above)
    safety.check_cartesian_target(make_transform(DOWN, (0.7, 0.3, -0.12)), make_transform(DOWN, (0.7, 0.3, -0.05)))


@pytest.mark.parametrize('bad', [np.nan, np.inf, -np.inf])
def test_non_finite_values_are_rejected(safety, bad):
    q = np.array(NEUTRAL)
    broken = q.copy()
    broken[3] = bad
    with pytest.raises(UnsafeCommand, match='NaN or inf'):
        safety.check_joint_target(broken, q)
    with pytest.raises(UnsafeCommand, match='NaN or inf'):
        safety.check_joint_target(q, broken)
    with pytest.raises(UnsafeCommand, match='NaN or inf'):
        safety.check_velocity(np.where(np.arange(7) == 2, bad, 0.0), 0.2, q)
    T = make_transform(DOWN, (0.7, 0.3, 0.0))
    T[1, 3] = bad
    with pytest.raises(UnsafeCommand, match='NaN or inf'):
        safety.check_cartesian_target(T)
    with pytest.raises(UnsafeCommand, match='dt'):
        safety.check_velocity(np.zeros(7), bad, q)


def test_wrong_vector_length_is_rejected(safety):
    with pytest.raises(UnsafeCommand, match='7 elements'):
        safety.check_joint_target(np.zeros(6), NEUTRAL)


def test_joint_limit_violation_names_the_joint(safety, kinematics):
    q = np.array(NEUTRAL)
    target = q.copy()
    target[3] = kinematics.lower[3] - 0.01                  # left_e1 lower limit is -0.05 rad
    with pytest.raises(UnsafeCommand, match='left_e1 target .* outside its limits'):
        safety.check_joint_target(target, q)


def test_joint_step_bound(kinematics):
    safety = ArmSafety(SafetyLimits.from_kinematics(kinematics, max_joint_step=0.3),
                       joint_names=kinematics.joint_names)
    q = np.array(NEUTRAL)
    safety.check_joint_target(q + 0.29, q)
    target = q.copy()
    target[0] += 0.31
    with pytest.raises(UnsafeCommand, match='left_s0 would move by 0.310 rad'):
        safety.check_joint_target(target, q)


def test_cartesian_step_bound_on_joint_moves(kinematics):
    safety = ArmSafety.for_arm(kinematics, max_cartesian_step=0.05)
    q_from = ik(kinematics, DOWN, (0.7, 0.3, 0.0))
    q_to = ik(kinematics, DOWN, (0.7, 0.3, -0.08), seed=q_from)
    with pytest.raises(UnsafeCommand, match='left_gripper would move by 0.080 m'):
        safety.check_joint_target(q_to, q_from)


def test_target_below_the_table_is_refused(safety, kinematics):
    q_above = ik(kinematics, DOWN, (0.7, 0.3, -0.10))
    q_below = ik(kinematics, DOWN, (0.7, 0.3, -0.145), seed=q_above)   # 5 mm above the table, margin 10 mm
    with pytest.raises(UnsafeCommand, match='left_gripper would be at z = -0.145 m, below the table'):
        safety.check_joint_target(q_below, q_above)
    # Lifting an arm that is already too low is allowed: every configuration of the move is higher.
    safety.check_joint_target(q_above, q_below)


def test_a_tilted_table_plane_is_the_floor_where_the_tip_is(kinematics):
    """A calibrated table plane (1 deg about base y, 5 mm above ``table_top_z`` under the target) replaces
    ``table_top_z``: a tip 12 mm above the level table is 7 mm above the plane there, closer than the margin."""
    slope = np.tan(np.radians(1.0))
    xy = (0.7, 0.3)
    plane = Plane(np.array([-slope, 0.0, 1.0]), 0.0)              # z = slope * x ...
    plane = Plane(plane.normal, plane.offset + plane.normal[2] * (TABLE_Z + 0.005 - slope * xy[0]))  # ... moved
    assert plane.z_at(xy) == pytest.approx(TABLE_Z + 0.005)
    tilted = ArmSafety.for_arm(kinematics, table_top_z=TABLE_Z, table_plane=plane, tip_margin=0.01)
    level = ArmSafety.for_arm(kinematics, table_top_z=TABLE_Z, tip_margin=0.01)
    q_above = ik(kinematics, DOWN, (*xy, -0.10))
    q_low = ik(kinematics, DOWN, (*xy, TABLE_Z + 0.012), seed=q_above)
    level.check_joint_target(q_low, q_above)
    with pytest.raises(UnsafeCommand, match='below the table top %.3f m' % (TABLE_Z + 0.005)):
        tilted.check_joint_target(q_low, q_above)
    with pytest.raises(ValueError, match='tilted 20.0 deg'):
        SafetyLimits(kinematics.lower, kinematics.upper, table_plane=Plane((np.sin(np.radians(20)), 0,
                                                                            np.cos(np.radians(20))), 0.0))


def test_path_through_the_table_is_refused(safety, kinematics):
    """Both ends clear the table, but the straight joint-space path between them dips into it (wrist pitch)."""
    q_low = ik(kinematics, DOWN, (0.7, 0.3, -0.148))
    w1 = kinematics.joint_names.index('left_w1')
    q_a, q_b = q_low.copy(), q_low.copy()
    q_a[w1] += 0.4
    q_b[w1] -= 0.4
    for q in (q_a, q_b):
        assert kinematics.fk(q, 'left_gripper')[2, 3] > TABLE_Z + 0.02    # each end alone is safe
        safety.check_joint_target(q, q)
    with pytest.raises(UnsafeCommand, match=r'left_gripper would be at z = .* at \d+% of the joint move'):
        safety.check_joint_target(q_b, q_a)


def test_hand_and_camera_clearance(safety, kinematics):
    """Gripper pointing along +x 30 mm above the table: the tip clears it, the hand and camera do not."""
    T_base_gripper = make_transform(ALONG_X, (0.7, 0.3, -0.12))
    q = ik(kinematics, ALONG_X, (0.7, 0.3, -0.12))
    q_start = ik(kinematics, ALONG_X, (0.7, 0.3, 0.05), seed=q)
    with pytest.raises(UnsafeCommand, match='left_hand(_camera)? would be at z'):
        safety.check_joint_target(q, q_start)
    with pytest.raises(UnsafeCommand, match='left_hand(_camera)? would be at z'):
        safety.check_cartesian_target(T_base_gripper)
    # Without FK only the tip can be checked, and it is clear of the table.
    ArmSafety(safety.limits).check_cartesian_target(T_base_gripper)


def test_workspace_box(kinematics):
    safety = ArmSafety.for_arm(kinematics, workspace_min=(0.3, -0.5, -0.5), workspace_max=(1.0, 0.5, 0.5))
    with pytest.raises(UnsafeCommand, match='y = 0.600 m, outside the workspace box'):
        safety.check_cartesian_target(make_transform(DOWN, (0.7, 0.6, 0.0)))
    q_inside = ik(kinematics, DOWN, (0.7, 0.45, 0.0))
    q_outside = ik(kinematics, DOWN, (0.7, 0.55, 0.0), seed=q_inside)
    safety.check_joint_target(q_inside, q_inside)
    with pytest.raises(UnsafeCommand, match='outside the workspace box'):
        safety.check_joint_target(q_outside, q_inside)


def test_cartesian_target_checks(safety):
    T = make_transform(DOWN, (0.7, 0.3, 0.0))
    skewed = T.copy()
    skewed[:3, :3] *= 1.01
    with pytest.raises(UnsafeCommand, match='proper rotation'):
        safety.check_cartesian_target(skewed)
    with pytest.raises(UnsafeCommand, match='left_gripper would be at z = -0.150 m'):
        safety.check_cartesian_target(make_transform(DOWN, (0.7, 0.3, -0.15)))
    with pytest.raises(UnsafeCommand, match='would move by 0.500 m'):
        safety.check_cartesian_target(T, make_transform(DOWN, (0.7, 0.3, 0.5)))


def test_velocity_checks(safety, kinematics):
    q = ik(kinematics, DOWN, (0.7, 0.3, -0.12))
    too_fast = np.zeros(7)
    too_fast[1] = 1.6                                        # left_s1 limit is 1.5 rad/s
    with pytest.raises(UnsafeCommand, match='left_s1 velocity 1.600 rad/s exceeds its limit 1.500'):
        safety.check_velocity(too_fast, 0.01, q)
    # The tip velocity that takes it down 50 mm in 0.2 s (J^+ v) ends below the table + margin.
    J = kinematics.jacobian(q)
    qdot_down = np.linalg.pinv(J) @ np.array([0, 0, -0.25, 0, 0, 0])
    safety.check_velocity(qdot_down, 0.02, q)                # 5 mm lower: still clear
    with pytest.raises(UnsafeCommand, match='left_gripper would be at z'):
        safety.check_velocity(qdot_down, 0.2, q)
    at_limit = q.copy()
    at_limit[3] = kinematics.lower[3]
    with pytest.raises(UnsafeCommand, match='left_e1 target'):
        safety.check_velocity(np.where(np.arange(7) == 3, -0.5, 0.0), 0.2, at_limit)


def test_joint_only_checks_without_fk(kinematics):
    safety = ArmSafety(SafetyLimits.from_kinematics(kinematics))
    q_below = ik(kinematics, DOWN, (0.7, 0.3, -0.2))         # under the table, but no FK to know it
    safety.check_joint_target(q_below, q_below)
    with pytest.raises(UnsafeCommand, match='joint 3 target'):
        safety.check_joint_target(np.where(np.arange(7) == 3, 3.0, 0.0), np.zeros(7))


@pytest.mark.parametrize('overrides', [
    {'joint_lower': np.full(7, 2.0)},                 # above left_s1's upper limit 1.047
    {'tip_margin': -0.01},
    {'max_joint_step': 0.0},
    {'workspace_min': (0, 0, 1), 'workspace_max': (1, 1, 0)},
    {'velocity_limits': np.zeros(7)},
])
def test_invalid_limits_are_rejected(kinematics, overrides):
    args = {'joint_lower': kinematics.lower, 'joint_upper': kinematics.upper}
    args.update(overrides)
    with pytest.raises(ValueError):
        SafetyLimits(**args)
