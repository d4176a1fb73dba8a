"""The fake Baxter's head, the ROS edge (``baxter_interface.Head``): ``/robot/head/head_state`` (100 Hz),
``/robot/head/command_head_pan`` (HeadPanCommand: target rad, speed ratio 0-1, pan enable request) and
``/robot/head/command_head_nod`` (Bool: true starts a nod). The pan moves only while the robot is enabled (disable,
stop and reset hold it); the nod is the screen's and needs no enable. The head camera is on the head: it pans with it.
"""
import rospy
from std_msgs.msg import Bool

from baxter_pnp.msgs import msg
from baxter_pnp.sim.head import HeadCommander
from baxter_pnp.sim.publishers import state_publisher
from baxter_pnp.sim.world import HEAD_MAX_SPEED

HEAD_STATE_TOPIC = '/robot/head/head_state'
PAN_TOPIC = '/robot/head/command_head_pan'
NOD_TOPIC = '/robot/head/command_head_nod'
RATE_HZ = 100.0                 # simulated Hz of head_state


class HeadNode:
    """The head's topics around ``world``'s head_pan joint; ``robot`` is the shared ``RobotEnableState``."""

    def __init__(self, world, robot, queued):
        self.world, self.robot = world, robot
        self.head = HeadCommander(HEAD_MAX_SPEED)
        self._pub = state_publisher(HEAD_STATE_TOPIC, msg.HeadState)
        rospy.Subscriber(PAN_TOPIC, msg.HeadPanCommand, queued(self._on_pan), queue_size=10)
        rospy.Subscriber(NOD_TOPIC, Bool, queued(self._on_nod), queue_size=10)

    def schedules(self):
        """[(rate Hz, publish(header))] of the periodic publications."""
        return [(RATE_HZ, self._publish_head_state)]

    def hold(self):
        """Stop the pan where the head is (disable, stop, reset)."""
        angle, _ = self.world.head_pan()
        self.head.target = self.world.command_head_pan(angle, HEAD_MAX_SPEED)

    def _on_pan(self, message):
        try:
            command = self.head.pan_command(message.target, message.speed_ratio, message.enable_pan_request)
        except ValueError as error:
            rospy.logerr_throttle_identical(1.0, f'{PAN_TOPIC} ignored: {error}')
            return
        if command is None:
            rospy.logwarn_throttle(2.0, f'{PAN_TOPIC} ignored: the pan is disabled (enable_pan_request 0)')
        elif not self.robot.enabled:
            rospy.logwarn_throttle(2.0, f'{PAN_TOPIC} ignored: the robot is not enabled')
        else:
            self.head.target = self.world.command_head_pan(*command)

    def _on_nod(self, message):
        if message.data:
            self.head.nod(self.world.time)

    def _publish_head_state(self, header):
        if not self._pub.get_num_connections():
            return
        angle, _ = self.world.head_pan()
        self._pub.publish(msg.HeadState(**self.head.fields(angle, self.world.time)))
