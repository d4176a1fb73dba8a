#!/usr/bin/python3
"""rostest node of pick_square.test: the application's result (latched /baxter_pnp/result) is a verified pick."""
import json
import os
import sys
import unittest

sys.path.insert(0, os.path.join(os.path.dirname(os.path.realpath(__file__)), os.pardir, 'src'))  # a checkout
from baxter_pnp.runtime import use_project_venv  # noqa: E402
use_project_venv(__file__)

import rospy  # noqa: E402
import rostest  # noqa: E402
from std_msgs.msg import String  # noqa: E402


class PickResultTest(unittest.TestCase):
    def test_verified_pick(self):
        message = rospy.wait_for_message('/baxter_pnp/result', String, timeout=200.0)
        result = json.loads(message.data)
        self.assertTrue(result['success'], 'pick failed: %s' % result['failure_reason'])
        self.assertGreaterEqual(result['steps'], 1)
        self.assertLess(result['final_error_mm_est'], 5.0)


if __name__ == '__main__':
    rospy.init_node('check_pick_result')
    rostest.rosrun('baxter_pnp', 'pick_square_result', PickResultTest)
