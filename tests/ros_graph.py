"""Harness for ROS integration tests: the process launcher of ``baxter_pnp.sim.launcher`` plus this
process's rospy test node.

Every integration test run gets its own ``rosmaster --core`` on a free loopback port (``RosMaster``),
so tests never touch a developer's roscore and can run in parallel CI jobs. Only the processes started
by the launcher are ever stopped (each runs in its own process group, which is signalled as a whole).

(The module is not called ``rosgraph.py``: pytest puts ``tests/`` on ``sys.path``, and a
``rosgraph`` module there would shadow the ROS package of that name that rospy imports.)

Typical use, through the fixtures of ``conftest.py``::

    def test_something(ros_node, fake_baxter):
        process = fake_baxter('--enable', '--open-camera', 'left_hand_camera:640x400@20')
        msg = rospy.wait_for_message('/robot/state', AssemblyState, timeout=5)

Without pytest::

    with RosMaster() as master, master.environment():
        with FakeBaxterProcess(['--enable'], log_path='/tmp/fake.log') as fake:
            init_test_node()
            ...
"""
import functools

from baxter_pnp.sim import launcher
from baxter_pnp.sim.launcher import RosMaster, free_port, ros_environment, run_script  # noqa: F401 (re-exported)

# The tests' fake Baxter attaches to the master ``os.environ`` points at (the session's, see conftest.py).
FakeBaxterProcess = functools.partial(launcher.FakeBaxterProcess, None)


def init_test_node(name='pytest'):
    """Initialise this process's rospy node once (anonymous, no signal handlers); later calls do nothing.

    rospy allows one node per process and reads ROS_MASTER_URI when it starts, so call this inside
    the environment of the master the whole process uses (the session fixture of conftest.py).
    """
    import rospy
    if not rospy.core.is_initialized():
        rospy.init_node(name, anonymous=True, disable_signals=True)
    return rospy.get_name()


def reset_latched_limb_settings():
    """Latch the robot's defaults (speed ratio 0.3, command timeout 0.2 s) on each limb-setting topic this process
    still publishes latched. rospy keeps one publisher per topic and node, alive while any test's ``Publisher``
    object is, and its latched message reaches every fake started later on the session master: a test's slow
    speed ratio (0.1) once slowed a later module's left arm until MoveArms timed out. Call before a fake starts."""
    import rospy
    from std_msgs.msg import Float64
    from baxter_pnp.robot import sdk
    if not rospy.core.is_initialized():
        return
    manager = rospy.impl.registration.get_topic_manager()
    for side in ('left', 'right'):
        topics = sdk.limb_topics(side)
        for topic, value in ((topics.speed_ratio, sdk.DEFAULT_SPEED_RATIO),
                             (topics.command_timeout, sdk.COMMAND_TIMEOUT)):
            if manager.has_publication(topic):
                publisher = rospy.Publisher(topic, Float64, latch=True, queue_size=1)
                publisher.publish(Float64(value))
                publisher.unregister()


def shutdown_test_node():
    """Shut this process's rospy node down (its master is going away)."""
    import rospy
    if rospy.core.is_initialized():
        rospy.signal_shutdown('test session finished')
