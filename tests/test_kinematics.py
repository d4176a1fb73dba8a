"""ArmKinematics on urdf/baxter.urdf: FK against baxter_description's spot checks, Jacobian, IK."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from baxter_pnp.kinematics import NEUTRAL, ArmKinematics, pose_difference
from baxter_pnp.transforms import from_xyz_quat, rotation_angle_between, to_xyz_quat

UNTUCKED = [-0.08000, -0.99998, -1.18997, 1.94002, 0.67000, 1.03001, -0.50000]
ZEROS = [0.0] * 7

# ../shared/reference/baxter_kinematics.md section 4: (joints, frame, position, quaternion xyzw). The static
# baxter.urdf's `left_gripper` (hand + 0.025 m) is our `left_gripper_base`.
SPOT_CHECKS = [
    (ZEROS, 'left_hand', (0.797462, 0.992465, 0.320976), (-0.270599, 0.653281, 0.270599, 0.653281)),
    (ZEROS, 'left_gripper', (0.908972, 1.103976, 0.320976), (-0.270599, 0.653281, 0.270599, 0.653281)),
    (NEUTRAL, 'left_hand', (0.633928, 0.828931, 0.219351), (-0.382097, 0.922462, 0.021189, 0.051155)),
    (NEUTRAL, 'left_gripper_base', (0.635883, 0.830885, 0.194505), (-0.382097, 0.922462, 0.021189, 0.051155)),
    (NEUTRAL, 'left_gripper', (0.646258, 0.841260, 0.062618), (-0.382097, 0.922462, 0.021189, 0.051155)),
    (NEUTRAL, 'left_hand_camera', (0.599763, 0.811735, 0.199861), (-0.922463, 0.382096, -0.021189, 0.051155)),
    (UNTUCKED, 'left_gripper_base', (0.572564, 0.181197, 0.246173), (0.140765, 0.989647, 0.011656, 0.025469)),
    (UNTUCKED, 'left_gripper', (0.579689, 0.183307, 0.113681), (0.140765, 0.989647, 0.011656, 0.025469)),
]


@pytest.fixture(scope='module')
def left():
    kinematics = ArmKinematics('left')
    yield kinematics
    kinematics.close()


@pytest.fixture(scope='module')
def right():
    kinematics = ArmKinematics('right')
    yield kinematics
    kinematics.close()


@pytest.mark.parametrize('q, frame, position, quaternion', SPOT_CHECKS)
def test_fk_matches_baxter_description(left, q, frame, position, quaternion):
    xyz, quat = to_xyz_quat(left.fk(q, frame))
    assert np.max(np.abs(xyz - position)) < 1e-4
    assert min(np.max(np.abs(quat - quaternion)), np.max(np.abs(quat + np.array(quaternion)))) < 1e-4


def test_joint_limits_and_names(left, right):
    assert left.joint_names == ['left_s0', 'left_s1', 'left_e0', 'left_e1', 'left_w0', 'left_w1', 'left_w2']
    np.testing.assert_allclose(left.lower, [-1.70167993878, -2.147, -3.05417993878, -0.05, -3.059, -1.57079632679,
                                            -3.059])
    np.testing.assert_allclose(left.upper, [1.70167993878, 1.047, 3.05417993878, 2.618, 3.059, 2.094, 3.059])
    np.testing.assert_allclose(left.velocity_limits, [1.5, 1.5, 1.5, 1.5, 4.0, 4.0, 4.0])
    assert right.joint_names[0] == 'right_s0'
    np.testing.assert_allclose(right.lower, left.lower)


def test_right_arm_mirrors_left_at_zero(left, right):
    # At zero angles each arm lies in the vertical plane of its mount, so the right hand mirrors the left in y.
    for frame in ('hand', 'gripper'):
        p_left = left.fk(ZEROS, f'left_{frame}')[:3, 3]
        p_right = right.fk(ZEROS, f'right_{frame}')[:3, 3]
        np.testing.assert_allclose(p_right, p_left * [1, -1, 1], atol=1e-6)


@pytest.mark.parametrize('frame', ['left_gripper', 'left_hand_camera'])
def test_jacobian_matches_finite_differences(left, frame):
    q = np.array([0.3, -0.6, -0.4, 1.5, 0.5, 1.0, -0.7])
    J = left.jacobian(q, frame)
    eps = 1e-3
    numeric = np.zeros((6, 7))
    for i in range(7):
        dq = np.zeros(7)
        dq[i] = eps
        T_plus, T_minus = left.fk(q + dq, frame), left.fk(q - dq, frame)
        numeric[:3, i] = (T_plus[:3, 3] - T_minus[:3, 3]) / (2 * eps)
        numeric[3:, i] = Rotation.from_matrix(T_plus[:3, :3] @ T_minus[:3, :3].T).as_rotvec() / (2 * eps)
    assert J.shape == (6, 7)
    assert np.max(np.abs(J - numeric)) < 1e-3


def _random_reachable_targets(kinematics, count, seed):
    """FK of random joint vectors whose gripper ends up in front of the robot, above the table."""
    rng = np.random.default_rng(seed)
    joints, targets = [], []
    while len(targets) < count:
        q = rng.uniform(kinematics.lower, kinematics.upper)
        T = kinematics.fk(q)
        if 0.35 < T[0, 3] < 1.0 and -0.15 < T[2, 3] < 0.45:
            joints.append(q)
            targets.append(T)
    return joints, targets


def test_ik_solves_random_reachable_poses(left):
    _, targets = _random_reachable_targets(left, 50, seed=7)
    solved = 0
    for T in targets:
        q = left.ik(T)
        if q is None:
            continue
        solved += 1
        assert np.all(q >= left.lower) and np.all(q <= left.upper)
        T_reached = left.fk(q)
        assert np.linalg.norm(T_reached[:3, 3] - T[:3, 3]) < 1e-3
        assert rotation_angle_between(T_reached, T) < np.radians(0.5)
    assert solved >= 48, f'IK solved only {solved}/50 reachable poses'


def test_ik_from_a_nearby_seed_stays_near_it(left):
    joints, targets = _random_reachable_targets(left, 10, seed=3)
    for q_true, T in zip(joints, targets):
        seed = np.clip(q_true + 0.05, left.lower, left.upper)
        q = left.ik(T, seed=seed)
        assert q is not None
        assert np.max(np.abs(q - q_true)) < 0.2


def test_ik_of_the_camera_frame(left):
    q_true = np.array([-0.2, -0.9, 0.1, 1.6, 0.0, 0.9, 0.3])
    T = left.fk(q_true, 'left_hand_camera')
    q = left.ik(T, frame='left_hand_camera', seed=NEUTRAL)
    assert q is not None
    error = pose_difference(left.fk(q, 'left_hand_camera'), T)
    assert np.linalg.norm(error[:3]) < 1e-3 and np.linalg.norm(error[3:]) < np.radians(0.5)


@pytest.mark.parametrize('position', [(2.5, 0.25, 0.0), (1.0, 1.2, 0.13)])
def test_ik_of_unreachable_pose_returns_none(left, position):
    # 2 m beyond the workspace (rejected by the reach bound), and 1.34 m from the shoulder: inside the
    # 1.41 m bound but beyond the straight arm's 1.21 m (found unreachable by search).
    T = from_xyz_quat(position, (0.0, 1.0, 0.0, 0.0))
    assert left.ik(T) is None


def test_hand_solids_project_where_the_fake_renders_the_open_fingers():
    """The fingers hide the top of the hand camera's image: the URDF's gripper solids, ray-cast through the
    published camera model, must cover the same pixels as the fake's rendering of the empty table."""
    from baxter_pnp import view
    from baxter_pnp.bench import trial_scenes
    from baxter_pnp.transforms import invert
    T_base_camera, T_base_gripper, camera, _ = trial_scenes.start_view('down')
    kinematics = ArmKinematics('left')
    try:
        solids = kinematics.hand_solids()
    finally:
        kinematics.close()
    T_camera_gripper = invert(T_base_camera) @ T_base_gripper
    geometric = view.hand_clearance_px(camera, [solid.moved(T_camera_gripper) for solid in solids]) == 0
    rendered = trial_scenes.rendered_hand_clearance_px('down') == 0
    assert 0.05 < rendered.mean() < 0.2                          # the fingers are in view at all
    assert np.sum(geometric != rendered) < 0.02 * rendered.sum()  # and in the same place (edges differ)
    closed = ArmKinematics('left')
    try:
        closed_solids = closed.hand_solids(opening=0.0)
    finally:
        closed.close()
    finger_gaps = [abs(s.T[1, 3]) for s in solids if s.kind == 'box']
    assert max(finger_gaps) > max(abs(s.T[1, 3]) for s in closed_solids if s.kind == 'box') + 0.015
