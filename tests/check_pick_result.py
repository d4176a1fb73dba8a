#!/usr/bin/python3
"""rostest node of pick_square.test: a verified pick, judged by the fake's ground truth, not only by the app's word.

The app's latched ``/baxter_pnp/result`` must report a success; then the fake's ground truth must show it: the
block (``/fake_baxter/object_poses``, top-face centre frame) lifted 10 cm above where the scene (``~scene``) put it
on the table, and held between the fingers, centred on the gripper tip's axis with its top face ``grasp_depth``
above the tip (the tip from ``/robot/limb/left/endpoint_state``, the forward kinematics of the fake's true angles).
Metres, ``base`` frame.
"""
import json
import os
import sys
import unittest

sys.path.insert(0, os.path.join(os.path.dirname(os.path.realpath(__file__)), os.pardir, 'src'))  # a checkout
from baxter_pnp.runtime import use_project_venv  # noqa: E402
use_project_venv(__file__)

import numpy as np  # noqa: E402
import rospy  # noqa: E402
import rostest  # noqa: E402
from geometry_msgs.msg import PoseArray  # noqa: E402
from sensor_msgs.msg import Image  # noqa: E402
from std_msgs.msg import String  # noqa: E402

from baxter_pnp.msgs import msg  # noqa: E402
from baxter_pnp.sim.scene import load_scene  # noqa: E402
from baxter_pnp.transforms import invert, pose_msg_to_matrix  # noqa: E402

LIFT_HEIGHT = 0.10      # m: README, "lift 10 cm" (config lift_height)
GRASP_DEPTH = 0.012     # m: config/pick_square.yaml grasp_depth, the fingertips below the top face
CENTRING = 0.002        # m: README, centring 0.2-0.3 mm median, p90 0.5 mm; 2 mm leaves room for noise
SETTLING = 0.005        # m: the block settles in the closing fingers (it rides up ~2 mm): margin on heights


class PickResultTest(unittest.TestCase):
    def test_verified_pick(self):
        scene = load_scene(rospy.get_param('~scene'))
        # Subscribe to the result once the app has looked, seconds after it created its result publisher: rospy
        # marks a publisher latched only after advertising it, and a subscriber connecting in between is told
        # 'latching: 0' (a race of rospy's). The pick takes many looks: the result comes after this one.
        rospy.wait_for_message('/baxter_pnp/debug_image', Image, timeout=120.0)
        message = rospy.wait_for_message('/baxter_pnp/result', String, timeout=200.0)
        result = json.loads(message.data)
        self.assertTrue(result['success'], 'pick failed: %s' % result['failure_reason'])
        self.assertGreaterEqual(result['steps'], 1)
        self.assertEqual(message._connection_header.get('latching'), '1', 'the result topic is not latched')

        poses = rospy.wait_for_message('/fake_baxter/object_poses', PoseArray, timeout=10.0)
        state = rospy.wait_for_message('/robot/limb/left/endpoint_state', msg.EndpointState, timeout=10.0)
        T_base_block, T_base_gripper = pose_msg_to_matrix(poses.poses[0]), pose_msg_to_matrix(state.pose)
        resting_z = scene.table.top_z + scene.objects[0].height
        self.assertAlmostEqual(T_base_block[2, 3] - resting_z, LIFT_HEIGHT, delta=SETTLING,
                               msg='the block is not 10 cm above the table')
        block_in_gripper = (invert(T_base_gripper) @ T_base_block)[:3, 3]   # gripper z: along the fingers, down
        self.assertLess(np.hypot(*block_in_gripper[:2]), CENTRING, 'off-centre by %s m' % block_in_gripper[:2])
        self.assertAlmostEqual(-block_in_gripper[2], GRASP_DEPTH, delta=SETTLING,
                               msg='the top face is %.1f mm above the tip' % (-1000 * block_in_gripper[2]))


if __name__ == '__main__':
    rospy.init_node('check_pick_result')
    rostest.rosrun('baxter_pnp', 'pick_square_result', PickResultTest)
