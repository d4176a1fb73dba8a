"""The fake Baxter's digital and analog I/O and navigators, the ROS edge (``baxter_interface.DigitalIO``,
``AnalogIO``, ``Navigator``).

Publishes each component's state (``/robot/digital_io/<name>/state`` DigitalIOState, ``/robot/analog_io/<name>/state``
AnalogIOState), the aggregates (``/robot/digital_io_states``, ``/robot/analog_io_states``), each navigator's
``/robot/navigators/<name>_navigator/state`` and ``/robot/navigators_states``, at ``RATE_HZ`` and at once when a value
changes; takes output commands on ``/robot/digital_io/command`` and ``/robot/analog_io/command``. The hand range
sensors' analog inputs follow the world's range sensors (mm). Tests press buttons (and turn wheels) through the
fake's own topics ``/fake_baxter/set_digital_input`` (DigitalOutputCommand) and ``/fake_baxter/set_analog_input``
(AnalogOutputCommand): what a person's hand does on the robot. The components are ``sim.io_board``'s.
"""
import math

import rospy

from baxter_pnp.msgs import msg
from baxter_pnp.sim.io_board import ARMS, NAVIGATORS, RANGE_OUT_OF_RANGE_MM, IOBoard, IOCommandError

RATE_HZ = 10.0                  # simulated Hz of the periodic state publications (changes go out at once)
DIGITAL_COMMAND_TOPIC = '/robot/digital_io/command'
ANALOG_COMMAND_TOPIC = '/robot/analog_io/command'
SET_DIGITAL_INPUT_TOPIC = '~set_digital_input'       # the fake's own: a test presses a button
SET_ANALOG_INPUT_TOPIC = '~set_analog_input'


class IONode:
    """I/O topics around an ``IOBoard``; ``range_m(side)`` is the hand range sensor's distance (m, inf if none);
    ``ros_time(now)`` the stamp of simulated time ``now`` (s)."""

    def __init__(self, range_m, queued, ros_time):
        self.board = IOBoard()
        self._range_m, self._ros_time = range_m, ros_time
        self._digital = {name: rospy.Publisher(f'/robot/digital_io/{name}/state', msg.DigitalIOState, queue_size=10)
                         for name in self.board.digital}
        self._analog = {name: rospy.Publisher(f'/robot/analog_io/{name}/state', msg.AnalogIOState, queue_size=10)
                        for name in self.board.analog}
        self._navigators = {name: rospy.Publisher(f'/robot/navigators/{name}_navigator/state', msg.NavigatorState,
                                                  queue_size=10) for name in NAVIGATORS}
        self._all = {'digital': rospy.Publisher('/robot/digital_io_states', msg.DigitalIOStates, queue_size=10),
                     'analog': rospy.Publisher('/robot/analog_io_states', msg.AnalogIOStates, queue_size=10),
                     'navigators': rospy.Publisher('/robot/navigators_states', msg.NavigatorStates, queue_size=10)}
        subscriptions = ((DIGITAL_COMMAND_TOPIC, msg.DigitalOutputCommand, self.board.command),
                         (ANALOG_COMMAND_TOPIC, msg.AnalogOutputCommand, self.board.command),
                         (SET_DIGITAL_INPUT_TOPIC, msg.DigitalOutputCommand, self.board.set_input),
                         (SET_ANALOG_INPUT_TOPIC, msg.AnalogOutputCommand, self.board.set_input))
        for topic, message_type, apply in subscriptions:
            rospy.Subscriber(topic, message_type, queued(self._applier(topic, apply)), queue_size=100)

    def schedules(self):
        """[(rate Hz, publish(header))] of the periodic publications."""
        return [(RATE_HZ, self._publish_all)]

    def tick(self, now):
        """Publish at once the components (and navigators) whose value changed."""
        changed = self.board.take_changed()
        if changed:
            self._publish(changed, self._ros_time(now), aggregates=False)

    @staticmethod
    def _applier(topic, apply):
        def on_message(message):
            try:
                apply(message.name, message.value)
            except IOCommandError as error:
                rospy.logerr(f'{topic} ignored: {error}')
        return on_message

    def _publish_all(self, header):
        for side in ARMS:
            distance_m = self._range_m(side)
            self.board.set_input(f'{side}_hand_range', distance_m * 1000.0 if math.isfinite(distance_m)
                                 else RANGE_OUT_OF_RANGE_MM)
        self.board.take_changed()
        self._publish(set(self.board.digital) | set(self.board.analog), header.stamp, aggregates=True)

    def _publish(self, names, stamp, aggregates):
        """Publish the states of components ``names`` (and their navigators), with the aggregates if
        ``aggregates``; a message is built only for a topic someone subscribes to."""
        board = self.board
        listened = {kind: aggregates and self._all[kind].get_num_connections() > 0 for kind in self._all}

        def wanted(kind, publishers, candidates):       # in board order (the aggregates' order)
            return [name for name in candidates if listened[kind] or publishers[name].get_num_connections() > 0]
        digital = {name: msg.DigitalIOState(state=int(board.digital[name]), isInputOnly=board.is_input_only(name))
                   for name in wanted('digital', self._digital, [n for n in board.digital if n in names])}
        analog = {name: msg.AnalogIOState(timestamp=stamp, value=board.analog[name],
                                          isInputOnly=board.is_input_only(name))
                  for name in wanted('analog', self._analog, [n for n in board.analog if n in names])}
        navigators = {name: msg.NavigatorState(**board.navigator(name))
                      for name in wanted('navigators', self._navigators, board.navigators_of(names))}
        for publishers, messages in ((self._digital, digital), (self._analog, analog),
                                     (self._navigators, navigators)):
            for name, message in messages.items():
                if publishers[name].get_num_connections() > 0:
                    publishers[name].publish(message)
        if listened['digital']:
            self._all['digital'].publish(msg.DigitalIOStates(names=list(digital), states=list(digital.values())))
        if listened['analog']:
            self._all['analog'].publish(msg.AnalogIOStates(names=list(analog), states=list(analog.values())))
        if listened['navigators']:
            self._all['navigators'].publish(msg.NavigatorStates(names=list(navigators),
                                                                states=list(navigators.values())))
