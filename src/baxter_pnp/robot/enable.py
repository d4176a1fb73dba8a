"""``RobotEnable``: the robot's state and the enable / disable / reset / stop requests (interfaces §2).

Timeouts in wall-clock seconds.
"""
import rospy
from std_msgs.msg import Bool, Empty

from baxter_pnp.msgs import msg
from baxter_pnp.robot import sdk
from baxter_pnp.robot.errors import RobotError, RobotTimeout
from baxter_pnp.robot.topics import DEFAULT_MAX_AGE, CachedTopic, wait_until


class RobotEnable:
    """``/robot/state`` and the enable / disable / reset / stop requests, with baxter_interface's semantics."""

    def __init__(self, timeout=2.0):
        self._state = CachedTopic(sdk.ROBOT_STATE_TOPIC, msg.AssemblyState)
        self._enable_pub = rospy.Publisher(sdk.ENABLE_TOPIC, Bool, queue_size=10)
        self._reset_pub = rospy.Publisher(sdk.RESET_TOPIC, Empty, queue_size=10)
        self._stop_pub = rospy.Publisher(sdk.STOP_TOPIC, Empty, queue_size=10)
        self._state.wait(timeout, what='no robot state')

    def state(self):
        """The last ``AssemblyState`` (fields ready, enabled, stopped, error, estop_button, estop_source)."""
        return self._state.value

    def require_fresh(self, max_age=DEFAULT_MAX_AGE):
        self._state.require_fresh(max_age)

    def enable(self, timeout=2.0):
        """Enable the robot (resetting it first if it is stopped); RobotTimeout if it does not within ``timeout`` s."""
        if self.state().stopped:
            self.reset()
        rospy.loginfo('robot: enable')
        self._toggle(True, timeout)

    def disable(self, timeout=5.0):
        """Disable the robot; RobotTimeout if it is still enabled after ``timeout`` s."""
        rospy.loginfo('robot: disable')
        self._toggle(False, timeout)

    def _toggle(self, enable, timeout):
        if not wait_until(lambda: self.state().enabled == enable, timeout,
                          body=lambda: self._enable_pub.publish(Bool(enable))):
            raise RobotTimeout(f'failed to {"enable" if enable else "disable"} the robot within {timeout} s '
                               f'(robot state: {self._describe()})')

    def reset(self, timeout=3.0):
        """Clear a stop or an error; False (warning) if the robot reports an error it cannot clear.

        Raises RobotError when the e-stop button is pressed, RobotTimeout when nothing clears.
        """
        state = self.state()
        if state.stopped and state.estop_button == msg.AssemblyState.ESTOP_BUTTON_PRESSED:
            raise RobotError('cannot reset the robot: its e-stop button is pressed (release it first)')
        rospy.loginfo('robot: reset')

        def cleared():
            s = self.state()
            return not (s.enabled or s.stopped or s.error or s.estop_button or s.estop_source)
        if wait_until(cleared, timeout, body=lambda: self._reset_pub.publish(Empty())):
            return True
        state = self.state()
        if state.error and not state.stopped:
            rospy.logwarn(f'robot: reset did not clear the error state ({self._describe()})')
            return False
        raise RobotTimeout(f'failed to reset the robot within {timeout} s (robot state: {self._describe()})')

    def stop(self, timeout=3.0):
        """Stop the robot (as the e-stop does); RobotTimeout if it is not stopped within ``timeout`` s."""
        rospy.loginfo('robot: stop')
        if not wait_until(lambda: self.state().stopped, timeout, body=lambda: self._stop_pub.publish(Empty())):
            raise RobotTimeout(f'failed to stop the robot within {timeout} s (robot state: {self._describe()})')

    def _describe(self):
        s = self.state()
        return (f'enabled={s.enabled} stopped={s.stopped} error={s.error} '
                f'estop_button={s.estop_button} estop_source={s.estop_source}')
