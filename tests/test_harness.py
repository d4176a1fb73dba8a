"""The test harness itself (tests/conftest.py, tests/ros_graph.py): what one test leaves in this process's rospy node
does not reach the fakes of later tests."""
import pytest
import rospy
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64

import fake_baxter_client
from baxter_pnp.msgs import msg
from baxter_pnp.sim import launcher
from fake_baxter_client import Recorder, joint_angles, joint_velocity


def test_a_fake_started_later_gets_the_robot_defaults_not_what_an_earlier_test_latched(ros_node, fake_baxter):
    """An earlier test's latched slow speed ratio (0.1) lives on in this process's shared publisher; the harness
    latches the robot's default (0.3) before a fake starts, so its left arm moves at 0.3 x 1.5 rad/s, not 0.15
    (without it MoveArms in tests/test_whole_baxter.py ran out of time when such a test ran first)."""
    earlier = rospy.Publisher('/robot/limb/left/set_speed_ratio', Float64, latch=True, queue_size=1)
    earlier.publish(Float64(0.1))
    process = fake_baxter('--enable', '--real-time-factor', '0')
    joint_states = Recorder('/robot/joint_states', JointState, keep=1000)
    command = fake_baxter_client.publisher('/robot/limb/left/joint_command', msg.JointCommand)
    try:
        q0 = joint_angles(joint_states.latest())
        command.publish(msg.JointCommand(mode=1, names=['left_s0'], command=[q0[0] + 0.4]))
        moving = joint_states.wait_for(lambda m: abs(joint_velocity(m, 'left_s0')) > 0.3, timeout=20.0)
        assert abs(joint_velocity(moving, 'left_s0')) < 0.45 * 1.05             # the default ratio's speed, no faster
    finally:
        for closing in (joint_states, command, earlier):
            (closing.close if hasattr(closing, 'close') else closing.unregister)()
        process.stop()


def test_a_master_whose_chosen_port_is_taken_first_moves_to_another(monkeypatch):
    """Two harnesses side by side (a trial batch's halves) can both be handed the same free port; the master that
    loses the bind exits, and the one answering there is the other's. RosMaster checks the answering master's pid
    and takes another port; a port given explicitly and taken is an error."""
    with launcher.RosMaster() as first:
        ports = iter([first.port])
        real_free_port = launcher.free_port
        monkeypatch.setattr(launcher, 'free_port', lambda: next(ports, None) or real_free_port())
        with launcher.RosMaster() as second:
            assert second.port != first.port
            assert second.master_api().getPid() == second.process.pid != first.process.pid
        with pytest.raises(RuntimeError, match=f'rosmaster on port {first.port}'):
            launcher.RosMaster(port=first.port).start()
