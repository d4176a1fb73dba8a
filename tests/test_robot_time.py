"""``robot.topics.wait_until`` in robot time against a robot clock that runs far ahead of the wall (an unpaced fake
Baxter on a loaded machine): it waits at least ``ROBOT_TIME_WALL_FLOOR`` of wall time before it gives up."""
import time

import rospy
import rospy.rostime

from baxter_pnp.robot import topics


def _with_robot_clock(seconds, body):
    """``body()`` with rospy's clock set to ``seconds`` (as /clock sets it), the previous state restored after."""
    saved = rospy.rostime._rostime_initialized, rospy.rostime._rostime_current
    try:
        rospy.rostime.set_rostime_initialized(True)
        rospy.rostime._set_rostime(rospy.Time.from_sec(seconds))
        return body()
    finally:
        rospy.rostime._rostime_initialized, rospy.rostime._rostime_current = saved


def test_a_robot_clock_far_ahead_of_the_wall_does_not_end_a_wait_before_the_answer_can_arrive():
    """The robot's clock passes the 5 s timeout at once (a state message that answers 0.2 s later, in wall time):
    the wait still sees the answer; with nothing answering it gives up after the floor, not the backstop."""
    started = time.monotonic()

    def jumping():
        return topics.wait_until(lambda: time.monotonic() - started > 0.2, 5.0,
                                 body=lambda: rospy.rostime._set_rostime(rospy.Time.from_sec(1000.0)),
                                 robot_time=True)
    assert _with_robot_clock(10.0, jumping)
    started = time.monotonic()
    never = _with_robot_clock(10.0, lambda: topics.wait_until(
        lambda: False, 5.0, body=lambda: rospy.rostime._set_rostime(rospy.Time.from_sec(1000.0)), robot_time=True))
    waited = time.monotonic() - started
    assert not never and topics.ROBOT_TIME_WALL_FLOOR <= waited < topics.ROBOT_TIME_WALL_FLOOR + 0.5
