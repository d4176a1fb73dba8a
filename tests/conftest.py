"""Shared pytest fixtures for ROS integration tests (harness: tests/ros_graph.py, baxter_pnp.sim.launcher).

- ``ros_master`` (session): a private ``rosmaster`` on a free loopback port, on the harness's clock
  (``BAXTER_PNP_CLOCK``, default ``sim``: ``/use_sim_time`` set; ``wall``: not set, and every fake runs
  ``--clock wall``, paced; ``baxter_pnp.sim.launcher.harness_clock``); ``os.environ`` points at it
  (ROS_MASTER_URI, ROS_IP=127.0.0.1, no ROS_HOSTNAME) for the whole session, so rospy in this process and
  every child process use it.
- ``ros_node`` (session): this process's rospy node (initialised once, on the master's clock).
- ``fake_baxter`` (module): a factory ``fake_baxter(*args)`` that starts ``scripts/fake_baxter.py``
  with those arguments, waits until it is ready and returns its ``FakeBaxterProcess``; all the
  processes it started are stopped when the test module ends (``process.stop()`` stops one earlier).

- ``keeps_real_time``: for a test that measures rates or durations in ROS time against a running fake; in a
  wall-clock session (ROS time = the wall clock) it skips the test unless the fake keeps pace.

Unit tests that use none of these never start a master.
"""
import time

import pytest

from baxter_pnp.sim.launcher import FakeBaxterProcess, RosMaster, harness_clock

REAL_TIME_ENOUGH = 0.95      # simulated s per wall s for the wall clock's rates and durations to hold (10 % checks)
from ros_graph import init_test_node, reset_latched_limb_settings, shutdown_test_node


@pytest.fixture(scope='session')
def ros_master(tmp_path_factory):
    log_dir = tmp_path_factory.mktemp('ros_log')
    with RosMaster(log_dir=log_dir) as master, master.environment():
        yield master
        shutdown_test_node()


@pytest.fixture(scope='session')
def ros_node(ros_master):
    return init_test_node()


@pytest.fixture(scope='module')
def fake_baxter(ros_master, tmp_path_factory):
    processes = []
    log_dir = tmp_path_factory.mktemp('fake_baxter')

    def start(*args, ready_timeout=30.0):
        log_path = log_dir / f'fake_baxter_{len(processes)}.log'
        reset_latched_limb_settings()      # the robot's defaults, whatever an earlier test of this process latched
        process = FakeBaxterProcess(ros_master, args, log_path=log_path, ready_timeout=ready_timeout)
        processes.append(process)
        return process.start()

    yield start
    for process in processes:
        process.stop()


@pytest.fixture
def keeps_real_time(ros_node):
    """Sim clock: nothing. Wall clock: the fake's pace over 1 wall s (``/robot/joint_states`` counted by its
    ``header.seq``, 100 per simulated s); skip unless it reaches ``REAL_TIME_ENOUGH``: a fake that lags runs as an
    overloaded robot, its rates and durations are right in simulated time only, which then is not ROS time."""
    if harness_clock() != 'wall':
        return None
    import rospy
    from sensor_msgs.msg import JointState
    seqs = []
    subscriber = rospy.Subscriber('/robot/joint_states', JointState,
                                  lambda message: seqs.append((time.monotonic(), message.header.seq)))
    try:
        deadline = time.monotonic() + 10.0
        while (not seqs or seqs[-1][0] - seqs[0][0] < 1.0) and time.monotonic() < deadline:
            time.sleep(0.05)
    finally:
        subscriber.unregister()
    if len(seqs) < 2:
        pytest.fail('no /robot/joint_states from the fake within 10 s')
    (wall0, seq0), (wall1, seq1) = seqs[0], seqs[-1]
    pace = (seq1 - seq0) / 100.0 / (wall1 - wall0)
    if pace < REAL_TIME_ENOUGH:
        pytest.skip(f'wall clock: the fake runs at {pace:.2f}x real time on this machine (< {REAL_TIME_ENOUGH}): '
                    f'rates and durations in ROS time do not apply')
    return pace
