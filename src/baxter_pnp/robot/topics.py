"""Subscribed robot streams with a watchdog (``CachedTopic``) and the waits the clients share.

Every subscribed stream keeps its last valid message and when it arrived; ``require_fresh(max_age)``
raises ``StreamLost`` naming the topic when nothing valid came for longer. Messages with NaN/inf or
of an unsupported kind are rejected (logged), never cached.

Clocks: timeouts and stream ages are wall-clock seconds, so a stalled simulated clock cannot hang a
call; ``wait_until(..., robot_time=True)`` counts ROS time instead (the robot's clock: the simulated
one with the fake Baxter), with a wall-clock backstop.
"""
import threading
import time

import rospy

from baxter_pnp.robot.errors import RobotError, RobotTimeout, ServiceUnavailable, StreamLost
from baxter_pnp.robot.sdk import COMMAND_RATE_HZ

ROBOT_TIME_BACKSTOP = 10.0     # a wait in robot time gives up after this many times its timeout of wall time ...
ROBOT_TIME_WALL_FLOOR = 1.0    # ... and not before this much wall time (s, at most its timeout): an unpaced
#                                simulator's clock can pass a whole timeout between two of its state messages
DEFAULT_MAX_AGE = 0.5          # s: a robot stream older than this is considered lost


def wait_until(condition, timeout, body=None, rate_hz=COMMAND_RATE_HZ, robot_time=False):
    """Call ``body()`` at ``rate_hz`` (wall clock) until ``condition()``; True if it held within ``timeout`` s.

    With ``robot_time`` the timeout counts ROS time (the robot's: a simulator running slower than real
    time gets the same motion time as a real robot), with a wall-clock backstop of
    ``ROBOT_TIME_BACKSTOP`` x ``timeout`` in case the robot's clock stops, and a wall-clock floor of
    ``ROBOT_TIME_WALL_FLOOR`` (at most ``timeout``) in case it runs far ahead of the wall (an unpaced simulator on
    a loaded machine: 12 s of its time in 70 ms, before the state that answers reached this process)."""
    start = time.monotonic()
    deadline = start + (ROBOT_TIME_BACKSTOP * timeout if robot_time else timeout)
    floor = start + min(timeout, ROBOT_TIME_WALL_FLOOR)
    robot_deadline = rospy.get_time() + timeout if robot_time else None
    while not condition():
        if rospy.is_shutdown():
            raise RobotError('ROS is shutting down')
        now = time.monotonic()
        if now > deadline or (robot_time and rospy.get_time() > robot_deadline and now > floor):
            return False
        if body is not None:
            body()
        time.sleep(1.0 / rate_hz)
    return True


def wait_for_subscriber(publisher, timeout):
    """Wait until ``publisher`` has a subscriber (a first message would otherwise be lost); RobotTimeout if none."""
    if not wait_until(lambda: publisher.get_num_connections() > 0, timeout, rate_hz=50.0):
        raise RobotTimeout(f'nobody subscribes to {publisher.resolved_name} after {timeout} s: '
                           f'is the robot (or the fake Baxter) running?')


def wait_for_service(name, timeout):
    """Wait up to ``timeout`` s for service ``name``; ServiceUnavailable if it is not advertised."""
    try:
        rospy.wait_for_service(name, timeout=timeout)
    except rospy.ROSException:
        raise ServiceUnavailable(f'service {name} is not available (waited {timeout} s): is the robot '
                                 f'(or the fake Baxter) running?') from None


class CachedTopic:
    """One subscribed topic: the last valid value, when it arrived (wall clock), and a freshness check.

    ``convert(message)`` turns a message into the cached value; it returns None for a message that is
    not meant for this client (ignored silently) and raises ValueError for an invalid one (logged as
    an error, not cached).
    """

    def __init__(self, topic, message_type, convert=None, buff_size=65536, tcp_nodelay=False):
        self.topic = topic
        self._convert = convert or (lambda message: message)
        self._latest = None                  # (value, wall time of arrival)
        self._arrived = threading.Condition()
        self._subscriber = rospy.Subscriber(topic, message_type, self._callback, queue_size=1,
                                            buff_size=buff_size, tcp_nodelay=tcp_nodelay)

    def _callback(self, message):
        try:
            value = self._convert(message)
        except ValueError as error:
            rospy.logerr_throttle_identical(5.0, f'{self.topic}: message rejected: {error}')
            return
        if value is None:
            return
        with self._arrived:
            self._latest = (value, time.monotonic())
            self._arrived.notify_all()

    @property
    def value(self):
        """The last valid value, or None."""
        latest = self._latest
        return None if latest is None else latest[0]

    def require_fresh(self, max_age=DEFAULT_MAX_AGE):
        """The last valid value if it is at most ``max_age`` s old; StreamLost otherwise."""
        latest = self._latest
        age = float('inf') if latest is None else time.monotonic() - latest[1]
        if age > max_age:
            raise StreamLost(self.topic, age, max_age)
        return latest[0]

    def wait(self, timeout, accept=None, what=None):
        """The first valid value (with ``accept(value)`` true, if given) within ``timeout`` s, else RobotTimeout."""
        deadline = time.monotonic() + timeout
        with self._arrived:
            while True:
                value = self.value
                if value is not None and (accept is None or accept(value)):
                    return value
                remaining = deadline - time.monotonic()
                if remaining <= 0 or rospy.is_shutdown():
                    raise RobotTimeout(f'{what or "no valid message"} on {self.topic} within {timeout} s')
                self._arrived.wait(min(remaining, 0.1))

    def unregister(self):
        self._subscriber.unregister()
