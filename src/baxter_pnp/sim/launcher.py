"""Process launcher: a private rosmaster, the fake Baxter and entry-point scripts as subprocesses.

Used by the ROS integration tests (``tests/ros_graph.py``, ``tests/conftest.py``) and the batch-trials
runners (``baxter_pnp.bench``). Every run gets its own ``rosmaster --core`` on a free loopback port, so
it never touches a developer's roscore and runs can go in parallel. Only the processes started here
are ever stopped: each runs in its own process group, which is signalled as a whole.

Typical use::

    with RosMaster() as master:
        with FakeBaxterProcess(master, ['--enable'], log_path='/tmp/fake.log'):
            run = run_script(master, 'pick_square.py', ['--mode', 'pbvs'], timeout=120.0,
                             log_path='/tmp/pick.log')
            print(run.returncode, run.wall_seconds)

``master.environment()`` additionally points this process's ``os.environ`` at the master (for rospy
in this process; rospy reads ``ROS_MASTER_URI`` once, when its node starts).

Time: a master and the fakes on it share one clock (the fake's ``--clock``): ``sim`` (``/use_sim_time`` set before
any node starts, the fake publishes ``/clock``) or ``wall`` (as a real robot). The harness's default is ``sim``
(tests and trial batches run the fake unpaced; a fake started by hand defaults to ``wall``), or
``BAXTER_PNP_CLOCK`` (e.g. ``BAXTER_PNP_CLOCK=wall pytest tests/test_fake_baxter.py`` runs those tests against
a wall-clock fake). On a wall-clock master a fake asked to run unpaced (``--real-time-factor 0``) runs paced at 1.0:
only simulated time can run faster than the wall.
"""
import contextlib
import dataclasses
import os
import shutil
import signal
import socket
import subprocess
import sys
import time

import rosgraph

from baxter_pnp.runtime import PACKAGE_ROOT, venv_python
from baxter_pnp.sim.clock import CLOCKS, HARNESS_CLOCK

SCRIPTS_DIR = os.path.join(PACKAGE_ROOT, 'scripts')
FAKE_BAXTER_SCRIPT = os.path.join(SCRIPTS_DIR, 'fake_baxter.py')
ROSMASTER = shutil.which('rosmaster') or '/usr/bin/rosmaster'
READY_TOPIC = '/robot/sim/started'   # latched, published by the fake Baxter once everything flows
CLOCK_ENV = 'BAXTER_PNP_CLOCK'       # sim | wall: the harness's clock when none is given


def harness_clock():
    """The clock of masters and fakes started without one: ``$BAXTER_PNP_CLOCK``, else ``sim`` (unpaced runs)."""
    clock = os.environ.get(CLOCK_ENV) or HARNESS_CLOCK
    if clock not in CLOCKS:
        raise ValueError(f'{CLOCK_ENV}={clock!r}: expected one of {", ".join(CLOCKS)}')
    return clock


MASTER_START_ATTEMPTS = 5      # RosMaster.start: ports tried when the chosen one is taken before the master binds it


def free_port():
    """A TCP port that is free on 127.0.0.1 right now."""
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(('127.0.0.1', 0))
        return s.getsockname()[1]


def ros_environment(master_uri, log_dir=None, base=None):
    """A copy of ``base`` (default ``os.environ``) pointing ROS at ``master_uri`` over loopback.

    Sets ``ROS_MASTER_URI``, ``ROS_IP=127.0.0.1`` and removes ``ROS_HOSTNAME`` (which would win over
    ``ROS_IP``); ``log_dir`` becomes ``ROS_LOG_DIR`` so that ROS logs stay with the run.
    """
    env = dict(os.environ if base is None else base)
    env['ROS_MASTER_URI'] = master_uri
    env['ROS_IP'] = '127.0.0.1'
    env.pop('ROS_HOSTNAME', None)
    if log_dir is not None:
        env['ROS_LOG_DIR'] = str(log_dir)
    return env


def project_python():
    """The interpreter for child scripts: the project's venv if it exists, else this one."""
    python = venv_python()
    return python if os.path.exists(python) else sys.executable


def stop_process_group(process, first_signal=signal.SIGINT, grace=5.0):
    """Signal the process group led by ``process`` (``first_signal``, then SIGKILL after ``grace`` s).

    ``process`` must have been started with ``start_new_session=True`` (it leads its own group).
    Returns the exit code.
    """
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


def wait_until(condition, timeout, interval=0.05, what='condition', process=None, log_path=None):
    """Poll ``condition()`` until true; RuntimeError after ``timeout`` s or if ``process`` exits."""
    deadline = time.monotonic() + timeout
    while not condition():
        if process is not None and process.poll() is not None:
            raise RuntimeError(f'{what}: process exited with code {process.returncode}' + log_tail(log_path))
        if time.monotonic() > deadline:
            raise RuntimeError(f'{what}: not ready after {timeout} s' + log_tail(log_path))
        time.sleep(interval)


def log_tail(log_path, lines=30):
    """The last ``lines`` lines of a log file, formatted for an error message ('' if none)."""
    if not log_path or not os.path.exists(log_path):
        return ''
    with open(log_path, errors='replace') as f:
        return '\n--- last lines of %s ---\n%s' % (log_path, ''.join(f.readlines()[-lines:]))


def _read(log_path):
    if not log_path or not os.path.exists(log_path):
        return ''
    with open(log_path, errors='replace') as f:
        return f.read()


class RosMaster:
    """``rosmaster --core -p PORT`` on 127.0.0.1 (``ROS_IP=127.0.0.1``), in its own process group.

    ``clock`` (default ``harness_clock()``): with ``sim`` the ``/use_sim_time`` parameter is set as soon as the
    master answers, before any node starts (the fake Baxter owns the clock and every node then runs in
    simulated time); with ``wall`` it is not (as on a real robot). ``log_dir`` receives the master's log (and is
    exported as ``ROS_LOG_DIR`` to children).
    """

    def __init__(self, port=None, clock=None, log_dir=None, start_timeout=10.0):
        self._port_given = port is not None
        self.port = port or free_port()
        self.uri = f'http://127.0.0.1:{self.port}'
        self.clock = clock or harness_clock()
        if self.clock not in CLOCKS:
            raise ValueError(f'clock must be one of {", ".join(CLOCKS)}, got {self.clock!r}')
        self.log_dir = log_dir
        self.start_timeout = start_timeout
        self.process = None

    def env(self, base=None):
        """Environment for a child process of this master (``ros_environment`` of ``base``)."""
        return ros_environment(self.uri, self.log_dir, base=base)

    def start(self):
        """Start the master and wait until it answers XML-RPC calls, as itself: ``free_port``'s port is free when
        chosen, not reserved, so a harness started beside this one (two trial halves) can choose it too; the master
        that loses the race exits, and the one that answers is then the other's (its pid tells). A chosen port is
        then chosen again, up to ``MASTER_START_ATTEMPTS`` times; a given one is an error."""
        for attempt in range(MASTER_START_ATTEMPTS):
            self.process = subprocess.Popen([ROSMASTER, '--core', '-p', str(self.port)], env=self.env(),
                                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                                            start_new_session=True)
            try:
                wait_until(self._serving, self.start_timeout, what=f'rosmaster on port {self.port}',
                           process=self.process)
                break
            except RuntimeError:
                self.stop()
                if self._port_given or attempt == MASTER_START_ATTEMPTS - 1:
                    raise
                self.port = free_port()
                self.uri = f'http://127.0.0.1:{self.port}'
        if self.clock == 'sim':
            self.master_api().setParam('/use_sim_time', True)
        return self

    def _serving(self):
        """True when the master at ``uri`` answers and is this object's process; RuntimeError when another answers."""
        if not rosgraph.is_master_online(self.uri):
            return False
        pid = self.master_api().getPid()
        if pid != self.process.pid:
            raise RuntimeError(f'rosmaster on port {self.port}: the port is served by another master (pid {pid})')
        return True

    def master_api(self, caller_id='/baxter_pnp_launcher'):
        """``rosgraph.Master`` client of this master."""
        return rosgraph.Master(caller_id, master_uri=self.uri)

    @contextlib.contextmanager
    def environment(self):
        """Point ``os.environ`` at this master (ROS_MASTER_URI, ROS_IP, no ROS_HOSTNAME) for the block."""
        saved = dict(os.environ)
        os.environ.clear()
        os.environ.update(self.env(base=saved))
        try:
            yield self
        finally:
            os.environ.clear()
            os.environ.update(saved)

    def stop(self):
        """Stop the master's process group."""
        if self.process is not None:
            stop_process_group(self.process, first_signal=signal.SIGTERM)

    def __enter__(self):
        return self.start()

    def __exit__(self, *exc):
        self.stop()


def fake_clock_args(args, clock):
    """The fake's ``args`` with ``--clock clock`` added unless they hold one; for the wall clock, an unpaced
    ``--real-time-factor 0`` becomes 1 (the wall clock runs at real time)."""
    args = list(args)
    if '--clock' in args:
        return args
    if clock == 'wall' and '--real-time-factor' in args:
        index = args.index('--real-time-factor') + 1
        if index < len(args) and args[index].strip() in ('0', '0.0'):
            args[index] = '1'
    return args + ['--clock', clock]


class FakeBaxterProcess:
    """``scripts/fake_baxter.py ARGS`` as a subprocess attached to ``master``.

    ``master`` is a ``RosMaster``, or None for whatever master ``os.environ`` points at. The node
    runs under the project's venv interpreter (``project_python``), so ``baxter_pnp`` is importable
    without a catkin workspace. Unless ``args`` hold a ``--clock``, it gets the master's (``harness_clock()``
    without a master; see ``fake_clock_args``). ``start()`` returns when the node is ready, i.e. when its latched
    ``/robot/sim/started`` topic is registered with the master (the node registers it once all its
    topics flow), or raises RuntimeError with the end of its log. stdout and stderr go to ``log_path``.
    """

    def __init__(self, master, args=(), log_path=None, ready_timeout=30.0):
        self.master = master
        self.args = fake_clock_args([str(a) for a in args], harness_clock() if master is None else master.clock)
        self.log_path = str(log_path) if log_path else None
        self.ready_timeout = ready_timeout
        self.process = None
        self.boot_seconds = None     # wall seconds from start to ready

    def _master_api(self):
        if self.master is not None:
            return self.master.master_api()
        return rosgraph.Master('/baxter_pnp_launcher')

    def _published(self):
        return {name for name, _ in self._master_api().getPublishedTopics('')}

    def start(self):
        if READY_TOPIC in self._published():
            raise RuntimeError(f'{READY_TOPIC} is already published: another fake Baxter is running')
        started = time.monotonic()
        self._spawn()
        wait_until(lambda: READY_TOPIC in self._published(), self.ready_timeout, what='fake_baxter',
                   process=self.process, log_path=self.log_path)
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
        env = dict(os.environ) if self.master is None else self.master.env()
        env['PYTHONUNBUFFERED'] = '1'
        log = open(self.log_path, 'w') if self.log_path else subprocess.DEVNULL
        try:
            self.process = subprocess.Popen([project_python(), FAKE_BAXTER_SCRIPT] + self.args, stdout=log,
                                            stderr=subprocess.STDOUT, start_new_session=True, env=env)
        finally:
            if log is not subprocess.DEVNULL:
                log.close()

    def log(self):
        """Everything the node wrote so far (stdout and stderr)."""
        return _read(self.log_path)

    def stop(self):
        """SIGINT (clean rospy shutdown), then SIGKILL; returns the exit code."""
        if self.process is None:
            return None
        return stop_process_group(self.process)

    def __enter__(self):
        return self.start()

    def __exit__(self, *exc):
        self.stop()


@dataclasses.dataclass
class ScriptRun:
    """Outcome of ``run_script``: exit code (None if it had to be killed), whether it timed out, wall
    seconds from start to exit, and where its stdout+stderr went."""
    returncode: object
    timed_out: bool
    wall_seconds: float
    log_path: object

    def log(self):
        """Everything the script wrote (stdout and stderr)."""
        return _read(self.log_path)


class ScriptProcess:
    """A running entry-point script (see ``start_script``): ``process`` (its ``subprocess.Popen``, leader of
    its own process group), ``wait`` for its ``ScriptRun``."""

    def __init__(self, process, log_path, started):
        self.process = process
        self.log_path = log_path
        self._started = started             # time.monotonic() at start

    def wait(self, timeout):
        """Wait for the exit, at most ``timeout`` wall seconds from now; then interrupt it (SIGINT, then
        SIGKILL) and report ``timed_out``. Returns the ``ScriptRun``."""
        try:
            returncode, timed_out = self.process.wait(timeout=timeout), False
        except subprocess.TimeoutExpired:
            returncode, timed_out = stop_process_group(self.process), True
        except BaseException:            # e.g. KeyboardInterrupt: never leave the script running
            stop_process_group(self.process)
            raise
        return ScriptRun(returncode=returncode, timed_out=timed_out, wall_seconds=time.monotonic() - self._started,
                         log_path=self.log_path)


def start_script(master, script, args=(), log_path=None):
    """Start an entry point ``script`` with ``args``, attached to ``master``; returns its ``ScriptProcess``.

    ``script`` is a path or a file name in the package's ``scripts/`` (e.g. ``'pick_square.py'``). It
    runs under the project's interpreter, in its own process group, with ``master``'s environment
    (``None``: this process's environment); stdout and stderr go to ``log_path``.
    """
    path = script if os.path.sep in str(script) else os.path.join(SCRIPTS_DIR, script)
    env = dict(os.environ) if master is None else master.env()
    env['PYTHONUNBUFFERED'] = '1'
    log_path = str(log_path) if log_path else None
    log = open(log_path, 'w') if log_path else subprocess.DEVNULL
    started = time.monotonic()
    try:
        process = subprocess.Popen([project_python(), str(path)] + [str(a) for a in args], stdout=log,
                                   stderr=subprocess.STDOUT, start_new_session=True, env=env)
    finally:
        if log is not subprocess.DEVNULL:
            log.close()
    return ScriptProcess(process, log_path, started)


def run_script(master, script, args=(), timeout=120.0, log_path=None):
    """Run an entry point ``script`` with ``args`` to completion, attached to ``master`` (see
    ``start_script``). After ``timeout`` wall seconds it is interrupted (SIGINT, then SIGKILL) and the
    result says ``timed_out``."""
    return start_script(master, script, args, log_path).wait(timeout)
