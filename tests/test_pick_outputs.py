"""pick_square.py's published outputs and parameters, as another node sees them (README, "The pick application").

A real rosmaster, the real fake Baxter, the real application; this pytest process is a separate ROS node: it
watches the graph (``/baxter_pnp/debug_image``, ``/baxter_pnp/target_pose``, tf frame ``block``, the latched
``/baxter_pnp/result``, the arm's speed ratio) and judges by the fake's ground truth (``/fake_baxter/*``, which
only tests and benchmarks read). Stamps are simulated time (s) from the message headers, never wall-clock
receipt.

- one pick-and-place run carries the outputs, the output directory with ``--save-views``, the parameter layers
  (YAML, then ``~private``, then the command line) and ``--camera-calibration``: the fake's camera has focal
  lengths 3 % longer than its camera_info says, the file has the true ones, and the estimates must be right;
- bad parameters (command line, ``~private``, a wrong calibration file) exit 2 before the robot is touched;
- ``--table-top-z`` is the safety floor: set above the real table, the descent is refused and the run fails.
"""
import json
import os
import re
import threading
from contextlib import contextmanager

import cv2
import numpy as np
import pytest
import rospy
import tf2_ros
import yaml
from geometry_msgs.msg import PoseArray, PoseStamped
from scipy.spatial.transform import Rotation
from sensor_msgs.msg import Image
from std_msgs.msg import Float64, String

from baxter_pnp.camera import DEFAULT_CAMERA_YAML, SensorWindow, load_default_camera
from baxter_pnp.msgs import msg
from baxter_pnp.pick_app import DEFAULT_CONFIG
from baxter_pnp.ros_image import msg_to_bgr
from baxter_pnp.sim.launcher import wait_until
from baxter_pnp.sim.scene import DEFAULT_SCENE_YAML
from baxter_pnp.transforms import make_transform, pose_msg_to_matrix, rotation_angle_between
from test_pick_square import BLOCK_HEIGHT, TABLE_TOP_Z, ground_truth_block, gripper_pose, run_pick

PLACE_XY = (0.62, 0.12)
FOCAL_SCALE = 1.03      # true / published focal lengths of the fake's camera: 3 % off costs 8-11 mm of depth (README)
IMAGE_SIZE = (640, 400)             # the hand camera mode the app opens (width, height px)
APP_NODE = '/pick_square'           # the application's node name: its private parameters live under it
RESULT_KEYS = {'success', 'time_s', 'steps', 'final_error_mm_est', 'mode', 'failure_reason', 'placed',
               'place_error_mm_est'}  # README: "latched JSON: success, time_s, steps, final_error_mm_est, ..."
VIEW_NAME = re.compile(r'view_(\d{4})_t(\d+\.\d\d)\.png$')
# A look's estimate of the block against the ground truth. README, "Perception": 40 mm squares 0.10-0.40 m away,
# position error median 0.15 mm, p90 1.0 mm (targets 1 and 3 mm), orientation p90 0.86 deg. In a run the endpoint
# pose at the frame's stamp adds its error, and the first looks are from 0.33-0.41 m, at and beyond the far end of
# that range, where the depth error (it dominates, along the optical axis) grows with the square of the distance
# (2.7 mm measured at 0.41 m). So: the run's median within the 1 mm target, every look within the 3 mm target plus
# 1 mm for the far looks, every orientation within 2 deg (p90 0.86 deg, doubled for the far looks' noise).
ESTIMATE_MEDIAN_POSITION_TOLERANCE = 0.001     # m
ESTIMATE_POSITION_TOLERANCE = 0.004            # m
ESTIMATE_ROTATION_TOLERANCE = np.radians(2.0)
# The look after lifting sees the block in the fingers, 0.12-0.15 m away with its edges partly behind the finger
# pads (outside the benchmark's unoccluded conditions): 2.1 deg seen once under load; 3 deg for those looks.
ESTIMATE_ROTATION_TOLERANCE_IN_HAND = np.radians(3.0)
LIFTED = 0.01                                   # m above its resting height: the block is in the hand


def stamp_s(header):
    """A message header's stamp in simulated seconds."""
    return header.stamp.to_sec()


def from_others(callback):
    """``callback`` for messages of other nodes only: what this test process published itself (a latched
    output of an earlier test's in-process task, say) is not the app's."""
    def filtered(message):
        if message._connection_header.get('callerid') != rospy.get_name():
            callback(message)
    return filtered


class GraphWatcher:
    """What a separate node sees of a pick: the app's outputs and the fake's ground truth, each with its header
    stamp (simulated s). Subscribes at construction (before the app starts); ``close()`` unsubscribes. ``with_tf``:
    also keep every tf transform (``tf_buffer``; create the watcher after the fake starts, since a new fake's
    clock going back to 0 clears the buffer)."""

    def __init__(self, with_tf=False):
        self._lock = threading.Lock()
        self.debug_images = []      # (stamp s, encoding, width, height, frame_id)
        self.last_debug_image = None
        self.target_poses = []      # (header stamp: a rospy.Time, frame_id, T_base_block)
        self.results = []           # (result dict, the connection's 'latching' header field), after the first look
        self.speed_ratios = []      # what the app sent to /robot/limb/left/set_speed_ratio
        self.truth = []             # (stamp s, T_base_block of the scene's first block): ground truth
        self.lowest_tip_z = np.inf  # lowest gripper tip z (base, m) on the fake's endpoint state: ground truth
        self.enabled_seen = False   # /robot/state reported enabled at any time
        self.joint_commands = 0     # messages on /robot/limb/left/joint_command
        self.tf_buffer = tf2_ros.Buffer(cache_time=rospy.Duration(3600.0)) if with_tf else None
        self._subscribers = [tf2_ros.TransformListener(self.tf_buffer)] if with_tf else []
        self._subscribers += [
            rospy.Subscriber('/baxter_pnp/debug_image', Image, from_others(self._on_debug_image), queue_size=None),
            rospy.Subscriber('/baxter_pnp/target_pose', PoseStamped, from_others(self._on_target_pose),
                             queue_size=None),
            rospy.Subscriber('/robot/limb/left/set_speed_ratio', Float64, from_others(self._on_speed_ratio)),
            rospy.Subscriber('/fake_baxter/object_poses', PoseArray, self._on_object_poses, queue_size=None),
            rospy.Subscriber('/robot/limb/left/endpoint_state', msg.EndpointState, self._on_endpoint, queue_size=None),
            rospy.Subscriber('/robot/state', msg.AssemblyState, self._on_robot_state),
            rospy.Subscriber('/robot/limb/left/joint_command', msg.JointCommand, from_others(self._on_joint_command))]

    def _on_debug_image(self, image):
        with self._lock:
            self.debug_images.append((stamp_s(image.header), image.encoding, image.width, image.height,
                                      image.header.frame_id))
            self.last_debug_image = image
            if len(self.debug_images) == 1:
                # Subscribe to the result once the app has looked, i.e. seconds after it created its result
                # publisher: rospy marks a publisher latched only after advertising it, and a subscriber that
                # connects in between is told 'latching: 0' (a race of rospy's, not the app's).
                self._subscribers.append(rospy.Subscriber('/baxter_pnp/result', String, from_others(self._on_result)))

    def _on_target_pose(self, pose):
        with self._lock:
            self.target_poses.append((pose.header.stamp, pose.header.frame_id, pose_msg_to_matrix(pose.pose)))

    def _on_result(self, message):
        with self._lock:
            self.results.append((json.loads(message.data), message._connection_header.get('latching')))

    def _on_speed_ratio(self, message):
        with self._lock:
            self.speed_ratios.append(message.data)

    def _on_object_poses(self, poses):
        with self._lock:
            self.truth.append((stamp_s(poses.header), pose_msg_to_matrix(poses.poses[0])))

    def _on_endpoint(self, state):
        with self._lock:
            self.lowest_tip_z = min(self.lowest_tip_z, state.pose.position.z)

    def _on_robot_state(self, state):
        self.enabled_seen |= state.enabled

    def _on_joint_command(self, command):
        with self._lock:
            self.joint_commands += 1

    def truth_at(self, stamp):
        """The ground-truth T_base_block nearest in simulated time to ``stamp`` (published at 30 Hz)."""
        with self._lock:
            times = np.array([t for t, _ in self.truth])
            return self.truth[int(np.argmin(np.abs(times - stamp)))][1]

    def wait_for_truth(self, timeout=10.0):
        """Wait (at most ``timeout`` wall s) until the ground truth flows: its first pose then predates the app."""
        wait_until(lambda: bool(self.truth), timeout, what='ground truth on /fake_baxter/object_poses')

    def close(self):
        with self._lock:
            subscribers = list(self._subscribers)
        for subscriber in subscribers:
            subscriber.unregister()


@contextmanager
def private_parameters(values):
    """``values`` set as the application node's private parameters (``~name``) for the block, then deleted."""
    for name, value in values.items():
        rospy.set_param('%s/%s' % (APP_NODE, name), value)
    try:
        yield
    finally:
        for name in values:
            if rospy.has_param('%s/%s' % (APP_NODE, name)):
                rospy.delete_param('%s/%s' % (APP_NODE, name))


def logged_configuration(log):
    """The effective parameters the app logs at start (``pick_square: {...}``)."""
    match = re.search(r'pick_square: (\{.*\})', log)
    assert match, 'no configuration line in the log'
    return json.loads(match.group(1))


def symmetric_rotation_error(T_a, T_b, symmetry=np.pi / 2):
    """Rotation angle (rad) between two block poses, up to the block's symmetry about its +z (square: 90 deg)."""
    turns = int(round(2 * np.pi / symmetry))
    return min(rotation_angle_between(T_a @ make_transform(Rotation.from_euler('z', k * symmetry)), T_b)
               for k in range(turns))


def saved_views(views_dir):
    """[(index, stamp s, path)] of ``views/view_NNNN_tT.png``, in index order; every file must be so named."""
    names = sorted(os.listdir(views_dir))
    views = []
    for name in names:
        match = VIEW_NAME.match(name)
        assert match, 'unexpected file %s in views/' % name
        views.append((int(match.group(1)), float(match.group(2)), os.path.join(views_dir, name)))
    return views


def reported_looks(log):
    """The looks the log reports: one per servo step line, per re-acquisition (a look that did not find the
    block whole), the look after lifting and the look after placing."""
    patterns = (r'pick \[\w+\] step \d+:', r'block cut by the image border', r'block not in view',
                r'grasp verified by a look|look after lifting|a look finds the block still on the table',
                r'estimated by a look|look after placing')
    return sum(len(re.findall(pattern, log)) for pattern in patterns)


def scene_with_focal_error(tmp_path, focal_scale):
    """The default scene with the camera's true focal lengths ``focal_scale`` x the published ones."""
    with open(DEFAULT_SCENE_YAML) as f:
        scene = yaml.safe_load(f)
    scene['camera_error']['focal_scale'] = focal_scale
    path = tmp_path / 'scene.yaml'
    path.write_text(yaml.safe_dump(scene))
    return path


def calibrated_camera_file(tmp_path, focal_scale):
    """A camera_calibration_parsers YAML of the fake's true camera: the published one, focal lengths scaled."""
    with open(DEFAULT_CAMERA_YAML) as f:
        calibration = yaml.safe_load(f)
    for matrix, fx, fy in (('camera_matrix', 0, 4), ('projection_matrix', 0, 5)):
        calibration[matrix]['data'][fx] *= focal_scale
        calibration[matrix]['data'][fy] *= focal_scale
    path = tmp_path / 'calibrated_camera.yaml'
    path.write_text(yaml.safe_dump(calibration))
    return path


def test_pick_and_place_outputs_seen_by_another_node(ros_master, ros_node, fake_baxter, tmp_path):
    """One pick and place with every output on and the parameters in three layers, judged by the ground truth
    and as a separate node sees the app's topics. (README, "The pick application".) The camera's focal lengths are
    3 % off its camera_info: only with the ``--camera-calibration`` file are the estimates within their accuracy.

    Layers (each key observable): ``mode`` is ibvs in the YAML, hybrid as ``~mode``, pbvs on the command line
    (expected pbvs); ``lift_height`` 0.07 m in the YAML, 0.12 m as ``~lift_height`` (expected 0.12: the block's
    true lift); ``speed_ratio`` 0.4 in the YAML only (expected 0.4 on ``set_speed_ratio``, not the default 0.3).
    """
    # paced at 1x, as a robot: unpaced on a loaded machine the block ended 2.5 and 3.0 mm off twice in ~15 suite runs
    # (the place batches, unpaced, never above 1.2 mm: README "Place")
    fake = fake_baxter('--real-time-factor', '1', '--clock', 'sim', '--scene',
                       scene_with_focal_error(tmp_path, FOCAL_SCALE))
    watcher = GraphWatcher(with_tf=True)
    try:
        with open(DEFAULT_CONFIG) as f:
            yaml_values = yaml.safe_load(f)
        yaml_values.update(mode='ibvs', lift_height=0.07, speed_ratio=0.4)
        config_path = tmp_path / 'pick.yaml'
        config_path.write_text(yaml.safe_dump(yaml_values))
        calibration_path = calibrated_camera_file(tmp_path, FOCAL_SCALE)
        out = tmp_path / 'out'
        watcher.wait_for_truth()
        with private_parameters({'mode': 'hybrid', 'lift_height': 0.12}):
            run, result = run_pick(ros_master, tmp_path, '--config', config_path, '--mode', 'pbvs',
                                   '--place', '%.2f,%.2f' % PLACE_XY, '--output-dir', out, '--save-views',
                                   '--camera-calibration', calibration_path)
        log = run.log()
        assert run.returncode == 0, log[-3000:]
        assert result['success'] and result['placed'] and result['failure_reason'] is None
        assert 'camera model from %s instead of camera_info' % calibration_path in log
        check_parameter_layers(log, result, watcher)
        check_place(result)
        check_result_topic(watcher, result, out)
        views = check_output_dir(out, log, result)
        check_debug_images(watcher, views)
        check_target_poses(watcher, views, result)
    finally:
        watcher.close()
        fake.stop()


def check_parameter_layers(log, result, watcher):
    """The command line over ``~private`` over the YAML over the defaults (see the test's docstring)."""
    effective = logged_configuration(log)
    assert (effective['mode'], effective['lift_height'], effective['speed_ratio']) == ('pbvs', 0.12, 0.4)
    assert result['mode'] == 'pbvs' and 'pick [pbvs] step 1:' in log
    assert watcher.speed_ratios and set(watcher.speed_ratios) == {0.4}
    z_before = watcher.truth[0][1][2, 3]
    highest_z = max(T_base_block[2, 3] for _, T_base_block in watcher.truth)
    # the block's true lift (and carry) height: 0.12 m; 5 mm for it settling in the fingers (+1.7 mm seen): tells
    # it from the YAML's 0.07 m and the default 0.10 m
    assert highest_z - z_before == pytest.approx(0.12, abs=0.005)


def check_place(result):
    """The block on the table at PLACE_XY (ground truth); the app's estimate of the place error against the truth."""
    T_base_block = ground_truth_block()
    true_error = np.hypot(T_base_block[0, 3] - PLACE_XY[0], T_base_block[1, 3] - PLACE_XY[1])
    # README: placement error median 0.4 mm, largest 1.2 mm (ground truth, 18 blocks); 1 mm of margin
    assert true_error < 0.0022, 'placed %.1f mm from the place position (the app\'s look: %s mm)' % (
        1000 * true_error, result['place_error_mm_est'])
    # resting on the table: its top face block_height above the table top (0.5 mm: contact penetration)
    assert T_base_block[2, 3] == pytest.approx(TABLE_TOP_Z + BLOCK_HEIGHT, abs=0.0005)
    # the estimate (a look from 0.25 m after placing): the estimate's p90 of 1.0 mm (README, "Perception"), plus
    # 0.5 mm for the endpoint pose at the frame's stamp
    assert result['place_error_mm_est'] == pytest.approx(1000 * true_error, abs=1.5)


def check_result_topic(watcher, result, out):
    """/baxter_pnp/result: once, latched, the documented keys, the same as --result-json and OUTPUT_DIR's."""
    assert len(watcher.results) == 1, 'one result per cycle'
    published, latching = watcher.results[0]
    assert latching == '1', 'the result topic is not latched'
    assert RESULT_KEYS <= set(published)
    assert published == result == json.loads((out / 'result.json').read_text())


def check_output_dir(out, log, result):
    """``--output-dir`` with ``--save-views``: readable images, one view per look the log reports, numbered and
    stamped in order, the last one the final view. Returns the views (``saved_views``)."""
    final_view = cv2.imread(str(out / 'final_view.png'))
    assert final_view.shape == (IMAGE_SIZE[1], IMAGE_SIZE[0], 3)
    assert cv2.imread(str(out / 'errors.png')) is not None
    views = saved_views(out / 'views')
    assert [index for index, _, _ in views] == list(range(1, len(views) + 1))
    assert len(views) == reported_looks(log) >= result['steps'] + 3   # steps 0..n, after lifting, after placing
    assert all(a[1] <= b[1] for a, b in zip(views, views[1:])), 'views not in time order'
    for _, _, path in views:
        image = cv2.imread(path)
        assert image is not None and image.shape == final_view.shape, path
    assert np.array_equal(cv2.imread(views[-1][2]), final_view)
    return views


def saved_view_at(views, stamp):
    """The path of the saved view of the look at ``stamp`` (simulated s; file names hold it to 0.01 s), or None."""
    for _, view_stamp, path in views:
        if abs(view_stamp - stamp) <= 0.005 + 1e-9:
            return path
    return None


def check_debug_images(watcher, views):
    """/baxter_pnp/debug_image: bgr8, 640x400, in the camera's frame, one per saved look (same stamp, same image)."""
    assert watcher.debug_images
    for stamp, encoding, width, height, frame_id in watcher.debug_images:
        assert (encoding, (width, height), frame_id) == ('bgr8', IMAGE_SIZE, 'left_hand_camera')
        assert saved_view_at(views, stamp), 'a debug image of no saved look (stamp %.3f s)' % stamp
    view = saved_view_at(views, stamp_s(watcher.last_debug_image.header))
    assert np.array_equal(msg_to_bgr(watcher.last_debug_image), cv2.imread(view)), \
        'the debug image is not the annotated view %s' % view


def check_target_poses(watcher, views, result):
    """/baxter_pnp/target_pose and tf ``block``: in base, the same pose at each look, where the block truly was then
    (within the estimate's accuracy, module constants)."""
    assert len(watcher.target_poses) >= result['steps'] + 1
    position_errors = []
    for header_stamp, frame_id, T_base_target in watcher.target_poses:
        stamp = header_stamp.to_sec()
        assert frame_id == 'base'
        assert saved_view_at(views, stamp), 'a target pose of no saved look (stamp %.3f s)' % stamp
        transform = watcher.tf_buffer.lookup_transform('base', 'block', header_stamp)
        t, q = transform.transform.translation, transform.transform.rotation
        T_base_block_tf = make_transform(Rotation.from_quat([q.x, q.y, q.z, q.w]), [t.x, t.y, t.z])
        np.testing.assert_allclose(T_base_block_tf, T_base_target, atol=1e-6)
        T_base_block_true = watcher.truth_at(stamp)
        position_errors.append(np.linalg.norm(T_base_target[:3, 3] - T_base_block_true[:3, 3]))
        rotation_error = symmetric_rotation_error(T_base_target, T_base_block_true)
        in_hand = T_base_block_true[2, 3] > TABLE_TOP_Z + BLOCK_HEIGHT + LIFTED
        assert rotation_error < (ESTIMATE_ROTATION_TOLERANCE_IN_HAND if in_hand else ESTIMATE_ROTATION_TOLERANCE), \
            'target pose at %.2f s turned %.1f deg from the truth' % (stamp, np.degrees(rotation_error))
    errors_mm = np.round(1000 * np.array(position_errors), 1).tolist()
    assert np.median(position_errors) < ESTIMATE_MEDIAN_POSITION_TOLERANCE, 'target poses %s mm off' % errors_mm
    assert max(position_errors) < ESTIMATE_POSITION_TOLERANCE, 'target poses %s mm off' % errors_mm


def test_bad_parameters_exit_2_before_the_robot_is_touched(ros_master, ros_node, fake_baxter, tmp_path):
    """A bad command-line value, a bad ``~param``, and ``--camera-calibration`` files that are not a camera or are
    calibrated at a size smaller than the camera mode: exit status 2, a log
    line naming the problem, no result, and the robot untouched (never enabled, no joint command, the arm still).
    (README, "Failure modes": "a bad parameter exits 2 before anything moves".)"""
    fake = fake_baxter('--real-time-factor', '0')        # boots disabled: enabling it would be the app's doing
    watcher = GraphWatcher()
    try:
        T_base_gripper_before = gripper_pose()
        small = tmp_path / 'camera_320x200.yaml'
        load_default_camera().windowed(SensorWindow.centred(640, 480, 320, 200)).to_yaml(str(small))
        cases = [(['--colour', 'purple'], {}, 'purple'),
                 ([], {'speed_ratio': 1.5}, 'speed_ratio'),
                 (['--camera-calibration', DEFAULT_SCENE_YAML], {}, 'image_width'),   # a scene, not a camera
                 (['--camera-calibration', small], {}, 'smaller than the camera mode 640x400')]
        for args, private, named in cases:
            with private_parameters(private):
                run, result = run_pick(ros_master, tmp_path, *args)
            assert not watcher.enabled_seen, '%s: the robot was enabled' % named
            assert watcher.joint_commands == 0, '%s: the arm was commanded' % named
            assert run.returncode == 2 and result is None, run.log()[-3000:]
            assert 'bad configuration' in run.log() and named in run.log()
        np.testing.assert_allclose(gripper_pose(), T_base_gripper_before, atol=1e-4)   # 0.1 mm: joint noise
    finally:
        watcher.close()
        fake.stop()


@pytest.mark.parametrize('above, picked', [(0.01, True), (0.014, False)])
def test_table_top_z_is_the_safety_floor(ros_master, ros_node, fake_baxter, tmp_path, above, picked):
    """``--table-top-z`` ``above`` the real table: the block (that much lower than the app expects, within
    max_height_error: still a target) needs the tip below the floor's limit (table_top_z + tip_margin). 1 cm: the
    grasp is raised to 1 mm above that limit, still 4 mm below the block's top face (``pick.MIN_GRIP_DEPTH`` 3
    mm), and the block is picked there; 14 mm: the limit is 1 mm under the top face, the descent is refused, the
    run fails cleanly (exit 1, unsafe_command, retreat, block untouched). Either way the tip, monitored on the fake's
    endpoint state, never went below that limit. (README, "On a real Baxter" 4b: ``table_top_z`` is the safety
    floor.)"""
    table_top_z, tip_margin = TABLE_TOP_Z + above, 0.005
    fake = fake_baxter('--real-time-factor', '0')
    watcher = GraphWatcher()
    try:
        watcher.wait_for_truth()
        T_base_block_before = watcher.truth[0][1]
        run, result = run_pick(ros_master, tmp_path, '--table-top-z', table_top_z)
        log = run.log()
        # the limit, on the true tip height (first: the claim itself); 0.5 mm for the endpoint state's joint noise
        assert watcher.lowest_tip_z >= table_top_z + tip_margin - 0.0005, \
            'the tip went down to %.4f m' % watcher.lowest_tip_z
        if picked:
            assert run.returncode == 0 and result['success'], log[-3000:]
            assert 'the grasp raised to 6.0 mm above the table' in log
            return
        assert run.returncode == 1, log[-3000:]
        assert not result['success'] and result['failure_reason'] == 'unsafe_command', log[-3000:]
        assert re.search(r'descend to grasp.*\n.*below the table top %.3f m \+ margin %.3f m'
                         % (table_top_z, tip_margin), log), 'the refusal does not name the floor'
        assert 'pick: retreat' in log
        np.testing.assert_allclose(ground_truth_block()[:3, 3], T_base_block_before[:3, 3], atol=0.001)   # untouched
    finally:
        watcher.close()
        fake.stop()
