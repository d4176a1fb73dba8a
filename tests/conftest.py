"""Shared pytest fixtures for ROS integration tests (harness: tests/ros_graph.py, baxter_pnp.sim.launcher).

- ``ros_master`` (session): a private ``rosmaster`` on a free loopback port, with ``/use_sim_time``
  set; ``os.environ`` points at it (ROS_MASTER_URI, ROS_IP=127.0.0.1, no ROS_HOSTNAME) for the whole
  session, so rospy in this process and every child process use it.
- ``ros_node`` (session): this process's rospy node (initialised once, in simulated time).
- ``fake_baxter`` (module): a factory ``fake_baxter(*args)`` that starts ``scripts/fake_baxter.py``
  with those arguments, waits until it is ready and returns its ``FakeBaxterProcess``; all the
  processes it started are stopped when the test module ends (``process.stop()`` stops one earlier).

Unit tests that use none of these never start a master.
"""
import pytest

from baxter_pnp.sim.launcher import FakeBaxterProcess, RosMaster
from ros_graph import init_test_node, shutdown_test_node


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
        process = FakeBaxterProcess(ros_master, args, log_path=log_path, ready_timeout=ready_timeout)
        processes.append(process)
        return process.start()

    yield start
    for process in processes:
        process.stop()
