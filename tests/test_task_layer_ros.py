"""The task layer composed into a new task in a few lines (docs/ARCHITECTURE.md, "Adding a task"), against a real
rosmaster and the real fake Baxter: connect, go to the start pose, look, hover over the block. Judged on the fake's
ground truth; the look's outputs are checked as another node sees them (debug image, target pose)."""
import numpy as np
import pytest
import rospy
from geometry_msgs.msg import PoseArray, PoseStamped
from sensor_msgs.msg import Image

from baxter_pnp import pick, vision
from baxter_pnp.pick_app import DEFAULT_CONFIG
from baxter_pnp.task import target
from baxter_pnp.task.eye import DEBUG_IMAGE_TOPIC, TARGET_POSE_TOPIC, BlockQuery, Eye
from baxter_pnp.task.motion import Motion
from baxter_pnp.task.session import RobotSession
from baxter_pnp.task.settings import load_configs
from baxter_pnp.transforms import invert, pose_msg_to_matrix


def hover_over_block(config, session_config):
    """The docs' example task: returns (the look, the gripper pose reached)."""
    session = RobotSession(session_config, log_name='hover')
    session.connect()
    motion = Motion(session)
    eye = Eye(session, vision.VisionConfig.from_yaml(),
              BlockQuery(config.shape, config.colour, config.side_length, config.block_height, config.estimator,
                         session.table))
    rules = target.TargetRules.of(config, session.table)
    motion.move_to_joints(session.start_pose(config.start_pose), 'start pose')
    look = eye.look(choose=lambda observations, T_base_camera, camera: target.choose_target(
        observations, T_base_camera, rules, (camera.width, camera.height)))
    assert look.target is not None, 'no block in view of the start pose'
    motion.move_to_pose(pick.hover_pose(look.T_base_block, config, look.T_base_gripper), 'hover over the block')
    rospy.sleep(0.5)        # simulated s: "arrived" allows 0.5 deg a joint (mm at the tip); judge where the arm settles
    T_reached = session.limb.endpoint_pose()
    session.camera.close()
    return look, T_reached


@pytest.mark.timeout(180)
def test_a_task_composed_of_session_motion_and_eye_hovers_over_the_block(ros_master, ros_node, fake_baxter):
    fake = fake_baxter('--real-time-factor', '0')
    seen = {}
    subscribers = [rospy.Subscriber(TARGET_POSE_TOPIC, PoseStamped, lambda m: seen.__setitem__('target', m)),
                   rospy.Subscriber(DEBUG_IMAGE_TOPIC, Image, lambda m: seen.__setitem__('image', m))]
    try:
        config, session_config = load_configs(pick.PickConfig, DEFAULT_CONFIG)
        look, T_base_gripper = hover_over_block(config, session_config)
        T_base_block = pose_msg_to_matrix(
            rospy.wait_for_message('/fake_baxter/object_poses', PoseArray, timeout=10.0).poses[0])
        # the look put the block where it is (ground truth), to a millimetre or two
        assert np.linalg.norm(look.T_base_block[:3, 3] - T_base_block[:3, 3]) < 0.003
        # the gripper hovers centred above it, hover_height + grasp_depth above the top face
        block_in_gripper = (invert(T_base_gripper) @ T_base_block)[:3, 3]
        assert np.hypot(*block_in_gripper[:2]) < 0.004
        assert block_in_gripper[2] == pytest.approx(config.hover_height - config.grasp_depth, abs=0.004)
        # what a user watches, as a subscriber sees it: the look's own messages (the latest, stamped with its frame;
        # a latched target pose of an earlier look in this process may come first)
        stamp = rospy.Time.from_sec(look.frame.stamp)
        deadline = rospy.get_time() + 5.0
        while rospy.get_time() < deadline and not (
                'image' in seen and 'target' in seen and seen['target'].header.stamp == stamp):
            rospy.sleep(0.05)
        assert seen['image'].encoding == 'bgr8' and (seen['image'].width, seen['image'].height) == (640, 400)
        assert seen['target'].header.frame_id == 'base'
        np.testing.assert_allclose(pose_msg_to_matrix(seen['target'].pose), look.T_base_block, atol=1e-6)
    finally:
        for subscriber in subscribers:
            subscriber.unregister()
        fake.stop()
