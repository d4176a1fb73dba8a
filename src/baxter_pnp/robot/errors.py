"""What the robot clients raise: ``RobotError`` and its kinds (stream ages in wall-clock seconds)."""


class RobotError(RuntimeError):
    """The robot did not do what was asked, or an interface it must provide is missing."""


class RobotTimeout(RobotError):
    """The robot did not reach the expected state within the timeout."""


class StreamLost(RobotError):
    """A robot topic stopped delivering valid messages (``topic``: its name, ``age``: seconds since the last)."""

    def __init__(self, topic, age, max_age):
        self.topic, self.age = topic, age
        since = 'no valid message received yet' if age == float('inf') else f'last valid message {age:.2f} s ago'
        super().__init__(f'stream lost: {topic} ({since}, max age {max_age:.2f} s)')


class ServiceUnavailable(RobotError):
    """A ROS service the robot must provide is not advertised."""


class IKFailure(RobotError):
    """The robot's IK service found no joint solution (the message gives the reason)."""
