"""A program's start-up against the robot, as ``baxter_interface`` does it (for tests/test_fake_baxter_clock.py):
``RobotEnable()`` (``robot/state`` within 2 s of ROS time), then ``Limb('left')`` (``robot/joint_states`` and
``endpoint_state`` within 1 s each), the waits of ``enable_robot.py`` and every example program.

Prints ``waiting`` once its node is up, as its first wait begins, then one JSON line: ``ok``, the error if a wait
expired, the wall and ROS seconds the waits took, whether ``/clock`` is published, and, from one
``robot/joint_states`` message, its stamp minus the wall time of its arrival (s). Exit code 0 when every wait held.
"""
import json
import os
import sys
import time

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import rospy  # noqa: E402
from sensor_msgs.msg import JointState  # noqa: E402

from sdk_clients import SdkLimb, SdkRobotEnable  # noqa: E402


def main():
    rospy.init_node('startup_client', anonymous=True, disable_signals=True)
    print('waiting', flush=True)           # RobotEnable's wait begins now
    wall0, ros0 = time.monotonic(), rospy.get_time()
    result = {'ok': True, 'error': None}
    try:
        SdkRobotEnable()
        SdkLimb('left')
    except OSError as error:
        result.update(ok=False, error=str(error))
    result.update(wall_s=time.monotonic() - wall0, ros_s=rospy.get_time() - ros0,
                  clock_published='/clock' in {name for name, _ in rospy.get_published_topics()})
    if result['ok']:
        message = rospy.wait_for_message('robot/joint_states', JointState, timeout=10.0)
        result['stamp_minus_wall_s'] = message.header.stamp.to_sec() - time.time()
    print(json.dumps(result), flush=True)
    return 0 if result['ok'] else 1


if __name__ == '__main__':
    sys.exit(main())
