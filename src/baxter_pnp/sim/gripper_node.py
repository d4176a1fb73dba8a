"""One electric gripper of the fake Baxter, the ROS edge (``baxter_interface.Gripper``, interfaces §7): its state
(100 Hz), properties (latched, 1 Hz) and command topics under ``/robot/end_effector/<side>_gripper/``.

The protocol is ``sim.gripper.ElectricGripperProtocol`` (pure); the fingers are ``SimWorld``'s. Commands are queued
for the main loop (``queued``); the robot's enable state does not gate the gripper.
"""
import rospy

from baxter_pnp.msgs import msg
from baxter_pnp.robot import sdk
from baxter_pnp.sim.gripper import ElectricGripperProtocol, GripperCommandError
from baxter_pnp.sim.publishers import state_publisher

RATES_HZ = {'gripper_state': 100.0, 'gripper_properties': 1.0}     # simulated Hz


class GripperNode:
    """The ``side`` gripper's topics around ``world``'s fingers."""

    def __init__(self, side, world, queued):
        self.side, self.world = side, world
        self.protocol = ElectricGripperProtocol(
            lambda position, force, velocity: world.command_gripper(side, position, force, velocity))
        self.topics = sdk.gripper_topics(side)
        self._pub = {
            'gripper_state': state_publisher(self.topics.state, msg.EndEffectorState),
            'gripper_properties': rospy.Publisher(self.topics.properties, msg.EndEffectorProperties, queue_size=1,
                                                  latch=True),
        }
        rospy.Subscriber(self.topics.command, msg.EndEffectorCommand, queued(self._on_command), queue_size=10)

    def schedules(self):
        """[(rate Hz, publish(header))] of the periodic publications."""
        return [(rate, getattr(self, '_publish_' + key)) for key, rate in RATES_HZ.items()]

    def _on_command(self, message):
        try:
            self.protocol.handle_command(message.command, message.args, message.sender, message.sequence)
        except GripperCommandError as error:
            rospy.logwarn(f'{self.topics.command}: {error}')

    def _publish_gripper_state(self, header):
        if not self._pub['gripper_state'].get_num_connections():
            if not (self.protocol.ready and self.world.gripper_at_rest(self.side)):     # else nothing would change
                self.protocol.update(self.world.time, self.world.gripper_state(self.side))
            return
        self.protocol.update(self.world.time, self.world.gripper_state(self.side))
        fields = self.protocol.state()
        fields['timestamp'] = header.stamp
        self._pub['gripper_state'].publish(msg.EndEffectorState(**fields))

    def _publish_gripper_properties(self, header):
        self._pub['gripper_properties'].publish(msg.EndEffectorProperties(**self.protocol.properties()))
