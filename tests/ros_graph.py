"""Harness for ROS integration tests: a private rosmaster, the fake Baxter as a subprocess, a rospy test node.

Every integration test run gets its own ``rosmaster --core`` on a free loopback port, so tests never
touch a developer's roscore and can run in parallel CI jobs. Only the processes started here are
ever stopped (each runs in its own process group, which is signalled as a whole).

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
import contextlib
import os
import signal
import socket
import subprocess
import sys
import time

import rosgraph

REPO_ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
FAKE_BAXTER_SCRIPT = os.path.join(REPO_ROOT, 'scripts', 'fake_baxter.py')
ROSMASTER = '/usr/bin/rosmaster'
READY_TOPIC = '/robot/sim/started'   # latched, published by the fake Baxter once everything flows


def free_port():
    """A TCP port that is free on 127.0.0.1 right now."""
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(('127.0.0.1', 0))
        return s.getsockname()[1]


def ros_environment(master_uri, log_dir=None, base=None):
    """A copy of ``base`` (default ``os.environ``) pointing ROS at ``master_uri`` over loopback.

    Sets ``ROS_MASTER_URI``, ``ROS_IP=127.0.0.1`` and removes ``ROS_HOSTNAME`` (which would win over
    ``ROS_IP``); ``log_dir`` becomes ``ROS_LOG_DIR`` so that ROS logs stay with the test run.
    """
    env = dict(os.environ if base is None else base)
    env['ROS_MASTER_URI'] = master_uri
    env['ROS_IP'] = '127.0.0.1'
    env.pop('ROS_HOSTNAME', None)
    if log_dir is not None:
        env['ROS_LOG_DIR'] = str(log_dir)
    return env


def _stop_process_group(process, first_signal=signal.SIGINT, grace=5.0):
    """Signal the process group led by ``process`` (``first_signal``, then SIGKILL after ``grace`` s)."""
    if process.poll() is not None:
        return process.returncode
    for sig, wait in ((first_signal, grace), (signal.SIGKILL, 5.0)):
        with contextlib.suppress(ProcessLookupError):
            os.killpg(process.pid, sig)
        try:
            return process.wait(timeout=wait)
        except subprocess.TimeoutExpired:
            continue
    return process.poll()


def _wait_until(condition, timeout, interval=0.05, what='condition', process=None, log_path=None):
    """Poll ``condition()`` until true; RuntimeError after ``timeout`` s or if ``process`` exits."""
    deadline = time.monotonic() + timeout
    while not condition():
        if process is not None and process.poll() is not None:
            raise RuntimeError(f'{what}: process exited with code {process.returncode}' + _tail(log_path))
        if time.monotonic() > deadline:
            raise RuntimeError(f'{what}: not ready after {timeout} s' + _tail(log_path))
        time.sleep(interval)


def _tail(log_path, lines=30):
    if not log_path or not os.path.exists(log_path):
        return ''
    with open(log_path, errors='replace') as f:
        return '\n--- last lines of %s ---\n%s' % (log_path, ''.join(f.readlines()[-lines:]))


class RosMaster:
    """``rosmaster --core -p PORT`` on 127.0.0.1, in its own process group.

    ``use_sim_time`` (default True) sets the ``/use_sim_time`` parameter as soon as the master answers,
    before any node starts: the fake Baxter owns the clock and every node of the test then runs in
    simulated time. ``log_dir`` receives the master's log (and is exported as ``ROS_LOG_DIR``).
    """

    def __init__(self, port=None, use_sim_time=True, log_dir=None, start_timeout=10.0):
        self.port = port or free_port()
        self.uri = f'http://127.0.0.1:{self.port}'
        self.use_sim_time = use_sim_time
        self.log_dir = log_dir
        self.start_timeout = start_timeout
        self.process = None

    def start(self):
        """Start the master and wait until it answers XML-RPC calls."""
        env = ros_environment(self.uri, self.log_dir)
        self.process = subprocess.Popen([ROSMASTER, '--core', '-p', str(self.port)], env=env,
                                        stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                                        start_new_session=True)
        _wait_until(lambda: rosgraph.is_master_online(self.uri), self.start_timeout,
                    what=f'rosmaster on port {self.port}', process=self.process)
        if self.use_sim_time:
            self.master_api().setParam('/use_sim_time', True)
        return self

    def master_api(self, caller_id='/ros_graph_harness'):
        """``rosgraph.Master`` client of this master."""
        return rosgraph.Master(caller_id, master_uri=self.uri)

    def published_topics(self):
        """Names of the topics that have at least one publisher."""
        return {name for name, _ in self.master_api().getPublishedTopics('')}

    @contextlib.contextmanager
    def environment(self):
        """Point ``os.environ`` at this master (ROS_MASTER_URI, ROS_IP, no ROS_HOSTNAME) for the block."""
        saved = dict(os.environ)
        os.environ.clear()
        os.environ.update(ros_environment(self.uri, self.log_dir, base=saved))
        try:
            yield self
        finally:
            os.environ.clear()
            os.environ.update(saved)

    def stop(self):
        """Stop the master's process group."""
        if self.process is not None:
            _stop_process_group(self.process, first_signal=signal.SIGTERM)

    def __enter__(self):
        return self.start()

    def __exit__(self, *exc):
        self.stop()


class FakeBaxterProcess:
    """``scripts/fake_baxter.py ARGS`` as a subprocess of the current ROS environment (``os.environ``).

    It runs under this process's interpreter (the project's venv under pytest), so ``baxter_pnp`` is
    importable without a catkin workspace.

    ``start()`` returns when the node is ready, i.e. when its latched ``/robot/sim/started`` topic is
    registered with the master (the node registers it once all its topics flow), or raises
    RuntimeError with the end of its log. stdout and stderr go to ``log_path``.
    """

    def __init__(self, args=(), log_path=None, ready_timeout=30.0):
        self.args = [str(a) for a in args]
        self.log_path = str(log_path) if log_path else None
        self.ready_timeout = ready_timeout
        self.process = None
        self.boot_seconds = None     # wall seconds from start to ready

    def start(self):
        master = rosgraph.Master('/ros_graph_harness')
        if READY_TOPIC in {name for name, _ in master.getPublishedTopics('')}:
            raise RuntimeError(f'{READY_TOPIC} is already published: another fake Baxter is running')
        started = time.monotonic()
        self._spawn()
        _wait_until(lambda: READY_TOPIC in {name for name, _ in master.getPublishedTopics('')},
                    self.ready_timeout, what='fake_baxter', process=self.process, log_path=self.log_path)
        self.boot_seconds = time.monotonic() - started
        return self

    def run_to_exit(self, timeout=30.0):
        """Run without waiting for readiness (e.g. to test a start-up error); returns the exit code."""
        self._spawn()
        try:
            return self.process.wait(timeout=timeout)
        except subprocess.TimeoutExpired:
            self.stop()
            raise

    def _spawn(self):
        log = open(self.log_path, 'w') if self.log_path else subprocess.DEVNULL
        try:
            self.process = subprocess.Popen([sys.executable, FAKE_BAXTER_SCRIPT] + self.args, stdout=log,
                                            stderr=subprocess.STDOUT, start_new_session=True,
                                            env=dict(os.environ, PYTHONUNBUFFERED='1'))
        finally:
            if log is not subprocess.DEVNULL:
                log.close()

    def log(self):
        """Everything the node wrote so far (stdout and stderr)."""
        if not self.log_path or not os.path.exists(self.log_path):
            return ''
        with open(self.log_path, errors='replace') as f:
            return f.read()

    def stop(self):
        """SIGINT (clean rospy shutdown), then SIGKILL; returns the exit code."""
        if self.process is None:
            return None
        return _stop_process_group(self.process)

    def __enter__(self):
        return self.start()

    def __exit__(self, *exc):
        self.stop()


def init_test_node(name='pytest'):
    """Initialise this process's rospy node once (anonymous, no signal handlers); later calls do nothing.

    rospy allows one node per process and reads ROS_MASTER_URI when it starts, so call this inside
    the environment of the master the whole process uses (the session fixture of conftest.py).
    """
    import rospy
    if not rospy.core.is_initialized():
        rospy.init_node(name, anonymous=True, disable_signals=True)
    return rospy.get_name()


def shutdown_test_node():
    """Shut this process's rospy node down (its master is going away)."""
    import rospy
    if rospy.core.is_initialized():
        rospy.signal_shutdown('test session finished')
