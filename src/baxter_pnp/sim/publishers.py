"""Publishers of the fake's periodic state topics.

rospy's queued publishers (any ``queue_size``) give each subscriber connection a writer thread and hand it every
message with a thread switch (``time.sleep(0)`` in ``QueuedConnection.write_data``). The fake publishes about a
thousand small state messages per simulated second from its loop, so those switches and the writer threads'
share of the GIL cost it a sixth of its speed with a client picking (docs/fake_baxter.md, "Time"). Its state
topics are therefore written synchronously (rospy's ``queue_size=None``): serialised and sent in the loop's thread,
a few hundred bytes into the kernel's socket buffer. A subscriber that stopped reading for long enough to fill that
buffer would hold the loop, as it would hold a roscpp publisher's; the cameras' images keep rospy's queue.
"""
import warnings

import rospy


def state_publisher(topic, message_type):
    """A ``rospy.Publisher`` of ``topic`` that writes each message in the calling thread (no queue, no thread)."""
    with warnings.catch_warnings():     # rospy warns of queue_size=None, which is this function's point
        warnings.simplefilter('ignore', SyntaxWarning)
        return rospy.Publisher(topic, message_type, queue_size=None)
