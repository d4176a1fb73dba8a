"""A block outside the start view, end to end: pick_square.py surveys the table (``task.survey``), maps the block
and picks it; the table map as another node sees it (latched JSON, rviz markers). Real rosmaster, real fake
Baxter; judged on the fake's ground truth.
"""
import json

import numpy as np
import rospy
import yaml
from std_msgs.msg import String
from visualization_msgs.msg import MarkerArray

from baxter_pnp.sim.scene import DEFAULT_SCENE_YAML
from baxter_pnp.task.survey import TABLE_MAP_JSON_TOPIC, TABLE_MAP_TOPIC
from baxter_pnp.transforms import invert
from test_pick_square import ground_truth_block, gripper_pose, run_pick

OUT_OF_VIEW_XY = [0.62, -0.15]      # m: 0.4 m to the right of the default block, outside the `down` start view
FAR_RIGHT_XY = [0.616, -0.306]      # m: the IBVS batch's scene 63 (seed 22): no view pose over it is reachable


def scene_with_block_at(xy, tmp_path):
    """The default scene with its block moved to ``xy`` (m, base), written to tmp_path; the path."""
    with open(DEFAULT_SCENE_YAML) as f:
        scene = yaml.safe_load(f)
    scene['objects'][0]['xy'] = list(xy)
    scene_path = tmp_path / 'scene.yaml'
    scene_path.write_text(yaml.safe_dump(scene))
    return scene_path


def test_a_block_outside_the_start_view_is_surveyed_mapped_and_picked(ros_master, ros_node, fake_baxter, tmp_path):
    """Issue 14: a target outside the start view is found by a survey (<= 15 s of robot time for the tour), put
    in the table map within 5 mm of the truth, and picked (verified, centred within 2 mm of the gripper axis).
    The fake runs at 1x: the tour's robot time is then a robot's (unpaced, the application's computing counts at
    the fake's speed-up, 2-5x)."""
    fake = fake_baxter('--real-time-factor', '1', '--scene', scene_with_block_at(OUT_OF_VIEW_XY, tmp_path))
    seen = {}           # topic -> last message, as another node sees them during the run
    subscribers = [rospy.Subscriber(topic, kind, lambda message, topic=topic: seen.__setitem__(topic, message))
                   for topic, kind in ((TABLE_MAP_JSON_TOPIC, String), (TABLE_MAP_TOPIC, MarkerArray))]
    try:
        T_base_block_before = ground_truth_block()
        z_before = T_base_block_before[2, 3]
        run, result = run_pick(ros_master, tmp_path, '--mode', 'pbvs')
        log = run.log()
        assert run.returncode == 0 and result['success'], log[-3000:]
        assert 'not in view: surveying the table' in log
        def robot_time(text):       # [INFO] [wall, robot time]: ... of the first log line containing ``text``
            return float(next(line for line in log.splitlines() if text in line).split(', ')[1].split(']')[0])
        tour = robot_time('the survey found') - robot_time('survey view 1 of')
        assert 0 < tour <= 15.0, tour
        mapped = json.loads(seen[TABLE_MAP_JSON_TOPIC].data)['blocks']
        assert len(mapped) == 1 and mapped[0]['shape'] == 'square' and mapped[0]['colour'] == 'green', mapped
        # 5 mm: the map fuses estimates from 0.43 m up at the image's edge (1.5 mm std) and the block frame's
        # position is its top-face centre in both
        np.testing.assert_allclose(mapped[0]['position_m'][:2], T_base_block_before[:2, 3], atol=0.005)
        error = np.linalg.norm(np.subtract(mapped[0]['position_m'], T_base_block_before[:3, 3]))
        assert error <= 3 * mapped[0]['std_m'], (error, mapped[0]['std_m'])     # the map says how far it may be
        markers = seen[TABLE_MAP_TOPIC].markers
        assert [m.ns for m in markers if m.action == m.ADD] == ['table_map'] and markers[-1].header.frame_id == 'base'
        T_base_block = ground_truth_block()
        assert T_base_block[2, 3] - z_before > 0.09, 'the block was not lifted'
        block_in_gripper = (invert(gripper_pose()) @ T_base_block)[:3, 3]
        assert np.hypot(*block_in_gripper[:2]) < 0.002, 'grasp off-centre by %s m' % block_in_gripper[:2]
    finally:
        for subscriber in subscribers:
            subscriber.unregister()
        fake.stop()


def test_a_surveyed_block_with_no_reachable_view_over_it_is_picked_from_the_view_that_saw_it(
        ros_master, ros_node, fake_baxter, tmp_path):
    """Issue 16: the IBVS batch's two failures. The survey maps a block far to the right whose view pose
    (``pick.view_pose``, over the block) the left arm cannot reach; the picker looks again from the survey view
    nearest the block among those that saw it (visited, so reachable) and picks it with the image-based law
    (verified, centred within 2 mm). Before 0e30161 it fell back to the start pose raised, out of view:
    ``block_lost``."""
    fake = fake_baxter('--real-time-factor', '0', '--scene', scene_with_block_at(FAR_RIGHT_XY, tmp_path))
    try:
        run, result = run_pick(ros_master, tmp_path, '--mode', 'ibvs')
        log = run.log()
        assert 'not in view: surveying the table' in log, log[-3000:]
        assert 'from the survey view that saw it' in log, log[-3000:]
        assert run.returncode == 0 and result['success'], log[-3000:]
        T_base_block = ground_truth_block()
        block_in_gripper = (invert(gripper_pose()) @ T_base_block)[:3, 3]
        assert np.hypot(*block_in_gripper[:2]) < 0.002, 'grasp off-centre by %s m' % block_in_gripper[:2]
    finally:
        fake.stop()
