"""`rostest baxter_pnp pick_square.test` runs one headless pick (fake Baxter + app + check node) and passes: the
check node (tests/check_pick_result.py) judges the pick by the fake's ground truth, not only by the app's result."""
import os
import subprocess

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def test_rostest_pick_square(tmp_path):
    env = {k: v for k, v in os.environ.items() if not k.startswith('ROS_')}
    env.update(ROS_PACKAGE_PATH=REPO, ROS_IP='127.0.0.1', ROS_HOME=str(tmp_path))
    result = subprocess.run(['rostest', 'baxter_pnp', 'pick_square.test'], env=env, capture_output=True,
                            text=True, timeout=400)
    output = result.stdout + result.stderr
    assert result.returncode == 0, output[-4000:]
    assert 'RESULT: SUCCESS' in output and 'FAILURES: 0' in output
    assert '[baxter_pnp.rosunit-pick_square_result/test_verified_pick][passed]' in output   # the check itself ran
    assert 'pick: SUCCESS' in output
