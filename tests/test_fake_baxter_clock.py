"""The fake's clock (issue 13 item 4, docs/fake_baxter.md "Time"): ``--clock wall`` runs as a real robot (paced on the
wall clock, stamps in wall time, no ``/clock``, no ``/use_sim_time``), ``--clock sim`` on simulated time; and a
program's start-up waits (``tests/startup_client.py``: ``RobotEnable`` then ``Limb``, as every SDK program starts)
never expire early: clients started any time once a wall-clock fake is up (as against a robot), and clients started
before a sim-clock fake's first ``/clock``. Each test has its own master (the session's is on the harness's clock).
"""
import json
import os
import subprocess
import time

import pytest
import yaml

from baxter_pnp.sim.clock import MessageClock, RealTimePacer, default_clock
from baxter_pnp.sim.launcher import FakeBaxterProcess, RosMaster, start_script, wait_until
from baxter_pnp.sim.node import parse_args

CLIENT = os.path.join(os.path.dirname(os.path.abspath(__file__)), 'startup_client.py')
CLIENT_TIMEOUT = 120.0          # wall s for a client to finish on a loaded machine (its own waits are 1-2 s)


def test_message_clock_stamps_simulated_or_paced_wall_time():
    wall = [100.0]
    pacer = RealTimePacer(1.0, wall_clock=lambda: wall[0], sleep=lambda seconds: wall.__setitem__(0, wall[0] + seconds))
    sim, real = MessageClock('sim', pacer), MessageClock('wall', pacer, unix_minus_wall=1.7e9)
    assert sim.publishes_clock and not real.publishes_clock
    assert real.seconds(0.0) == 1.7e9 + 100.0              # before pacing: now
    pacer.pace(0.0)
    wall[0] += 0.05                                        # the loop is 50 ms behind: stamps keep the sim's spacing
    assert (sim.seconds(1.0), real.seconds(1.0)) == (1.0, pytest.approx(1.7e9 + 101.0))
    pacer.pace(1.0)
    assert wall[0] == pytest.approx(101.0)
    with pytest.raises(ValueError, match='real-time factor of 1'):
        MessageClock('wall', RealTimePacer(0.0))
    with pytest.raises(ValueError, match='one of sim, wall'):
        MessageClock('gps', pacer)


def test_the_default_clock_is_the_wall_clock_at_real_time_and_simulated_time_otherwise():
    assert default_clock(1.0) == 'wall' and default_clock(0.0) == 'sim' and default_clock(2.5) == 'sim'
    assert parse_args([]).clock == 'wall'
    assert parse_args(['--real-time-factor', '0']).clock == 'sim'
    assert parse_args(['--clock', 'sim']).clock == 'sim'
    with pytest.raises(SystemExit):
        parse_args(['--clock', 'wall', '--real-time-factor', '0'])


REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


@pytest.mark.parametrize('launch_args, clock', [([], 'wall'), (['real_time_factor:=0'], 'sim'),
                                                 (['clock:=sim'], 'sim'), (['real_time_factor:=2', 'clock:=sim'], 'sim')])
def test_fake_baxter_launch_picks_the_clock_and_sets_use_sim_time_only_for_sim(tmp_path, launch_args, clock):
    env = {k: v for k, v in os.environ.items() if not k.startswith('ROS_')}
    env.update(ROS_PACKAGE_PATH=REPO, ROS_HOME=str(tmp_path))
    launch = os.path.join(REPO, 'launch', 'fake_baxter.launch')

    def roslaunch(*options):
        result = subprocess.run(['roslaunch', *options, launch, *launch_args], env=env, capture_output=True,
                                text=True, timeout=60)
        assert result.returncode == 0, result.stdout + result.stderr
        return result.stdout
    assert f'--clock {clock} ' in roslaunch('--args', '/fake_baxter')
    params = yaml.safe_load(roslaunch('--dump-params')) or {}
    assert params.get('/use_sim_time', False) is (clock == 'sim')


def start_clients(master, count, log_dir, tag):
    """``count`` startup clients on ``master``, each past its node's start-up and into its first wait."""
    clients = [start_script(master, CLIENT, log_path=log_dir / f'client_{tag}_{k}.log') for k in range(count)]
    for client in clients:
        wait_until(lambda: 'waiting' in open(client.log_path).read(), CLIENT_TIMEOUT, what='startup client',
                   process=client.process, log_path=client.log_path)
    return clients


def client_results(clients):
    """The JSON result of each client (they must all have exited 0: no wait expired)."""
    results = []
    for client in clients:
        run = client.wait(CLIENT_TIMEOUT)
        lines = [line for line in run.log().splitlines() if line.startswith('{')]
        assert lines and run.returncode == 0, f'startup client failed:\n{run.log()}'
        results.append(json.loads(lines[-1]))
    return results


def test_wall_clock_runs_as_a_real_robot_and_no_start_up_wait_expires(tmp_path):
    with RosMaster(clock='wall', log_dir=tmp_path / 'ros_log') as master:
        with FakeBaxterProcess(master, ['--clock', 'wall'], log_path=tmp_path / 'fake.log', ready_timeout=60) as fake:
            assert 'clock wall (no /clock)' in fake.log()
            clients = start_clients(master, 2, tmp_path, 'at_ready')     # as a robot: once it is up, any time
            time.sleep(3.0)
            clients += start_clients(master, 1, tmp_path, 'later')
            results = client_results(clients)
            published = {name for name, _ in master.master_api().getPublishedTopics('')}
            assert not master.master_api().hasParam('/use_sim_time')
        assert '/clock' not in published and '/robot/state' in published
        assert not any(result['clock_published'] for result in results)
        # stamps are the wall clock (simulated time would be ~1.8e9 s behind); 1 s allows a loaded machine's delivery
        assert all(abs(result['stamp_minus_wall_s']) < 1.0 for result in results), results
        assert all(result['wall_s'] == pytest.approx(result['ros_s'], abs=0.5) for result in results), results

        for args, reason in ((['--clock', 'wall', '--real-time-factor', '0'], '--real-time-factor must be 1'),
                             (['--clock', 'wall'], '/use_sim_time is true')):
            if reason.startswith('/use_sim_time'):
                master.master_api().setParam('/use_sim_time', True)
            refused = FakeBaxterProcess(master, args, log_path=tmp_path / 'refused.log')
            assert refused.run_to_exit(timeout=120) == 2
            assert reason in refused.log()


def test_sim_clock_clients_started_before_the_first_clock_never_expire_early(tmp_path):
    with RosMaster(clock='sim', log_dir=tmp_path / 'ros_log') as master:
        clients = start_clients(master, 3, tmp_path, 'before')
        with FakeBaxterProcess(master, ['--clock', 'sim', '--real-time-factor', '0'], log_path=tmp_path / 'fake.log',
                               ready_timeout=60) as fake:
            assert 'clock sim (/clock)' in fake.log()
            results = client_results(clients)
    assert all(result['clock_published'] for result in results)
    assert all(result['stamp_minus_wall_s'] < -1e9 for result in results)       # simulated seconds since boot
    assert all(result['ros_s'] < 4.0 for result in results), results             # 2 + 1 + 1 s of waits at most
