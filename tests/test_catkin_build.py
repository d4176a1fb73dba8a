"""The package works the ROS way: catkin_make builds it in a workspace and rosrun runs its scripts."""
import os
import subprocess

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def run_in_workspace(workspace, command):
    """Run a shell command with the workspace's devel/setup.bash sourced; returns CompletedProcess."""
    script = 'source %s/devel/setup.bash && %s' % (workspace, command)
    return subprocess.run(['bash', '-c', script], capture_output=True, text=True, timeout=120)


def test_catkin_make_then_rosrun(tmp_path):
    workspace = tmp_path / 'ws'
    (workspace / 'src').mkdir(parents=True)
    os.symlink(REPO, workspace / 'src' / 'baxter_pnp')
    env = {k: v for k, v in os.environ.items() if not k.startswith('ROS_') and k != 'CMAKE_PREFIX_PATH'}
    env['PWD'] = str(workspace)           # catkin_make takes its base path from PWD, not from the cwd
    build = subprocess.run(['catkin_make', '-DPYTHON_EXECUTABLE=/usr/bin/python3'], cwd=workspace,
                           capture_output=True, text=True, timeout=300, env=env)
    assert build.returncode == 0, build.stdout[-3000:] + build.stderr[-3000:]

    found = run_in_workspace(workspace, 'rospack find baxter_pnp')
    assert found.stdout.strip() == str(workspace / 'src' / 'baxter_pnp')

    for script in ('detect_image.py', 'calibrate_camera.py'):
        result = run_in_workspace(workspace, 'rosrun baxter_pnp %s --help' % script)
        assert result.returncode == 0, result.stderr
        assert 'usage: %s' % script in result.stdout

    # The devel space's Python (Debian's /usr/bin/python3) sees the package and the SDK message types.
    probe = run_in_workspace(workspace, '/usr/bin/python3 -c "from baxter_pnp.msgs import msg; '
                                        'print(msg.JointCommand._type, msg.JointCommand._md5sum)"')
    assert probe.stdout.split() == ['baxter_core_msgs/JointCommand', '19bfec8434dd568ab3c633d187c36f2e'], probe.stderr
