"""The fake's ground truth as the runners see it: the target block's and the gripper's true poses over time.

``GroundTruthMonitor`` subscribes to ``/fake_baxter/object_poses`` (the first object's pose) and to the arm's
endpoint and gripper state (runners only: the application never reads the ground truth). Frames: ``base``
(Baxter's), ``left_gripper`` (the tip frame, z along the fingers, they close along y), ``block`` (top-face
centre). Poses are 4x4 matrices in metres; times are simulated seconds; the CSV trace is in millimetres.
"""
import csv
import math
import threading
import time
from typing import NamedTuple

import numpy as np

from baxter_pnp.bench.trial_scenes import SIDE
from baxter_pnp.transforms import invert, pose_msg_to_matrix

LIFT_THRESHOLD = 0.05                 # m the block must rise for a pick to count as lifted


def block_in_gripper_mm(T_base_gripper, T_base_block):
    """(3,) position of the block's top-face centre in the gripper frame (mm)."""
    return 1000.0 * (invert(T_base_gripper) @ T_base_block)[:3, 3]


class GroundTruthSample(NamedTuple):
    """The simulator's state at one ``/fake_baxter/object_poses`` message."""
    stamp: float                 # simulated time (s)
    T_base_block: np.ndarray     # the target block (objects[0]), top-face centre frame
    T_base_gripper: np.ndarray   # latest endpoint state (left_gripper)
    gripper_percent: float       # latest gripper opening (0 closed .. 100 open)


def write_ground_truth(samples, path):
    """The trace as CSV: time (s), block and gripper positions (base, mm), block yaw (deg), the block
    centre in the gripper frame (mm) and the gripper opening (%)."""
    with open(path, 'w', newline='') as f:
        writer = csv.writer(f)
        writer.writerow(['t_s', 'block_x_mm', 'block_y_mm', 'block_z_mm', 'block_yaw_deg', 'gripper_x_mm',
                         'gripper_y_mm', 'gripper_z_mm', 'block_in_gripper_x_mm', 'block_in_gripper_y_mm',
                         'block_in_gripper_z_mm', 'gripper_percent'])
        for sample in samples:
            yaw = math.degrees(math.atan2(sample.T_base_block[1, 0], sample.T_base_block[0, 0]))
            writer.writerow(['%.4f' % sample.stamp] + ['%.2f' % v for v in (
                *(1000 * sample.T_base_block[:3, 3]), yaw, *(1000 * sample.T_base_gripper[:3, 3]),
                *block_in_gripper_mm(sample.T_base_gripper, sample.T_base_block), sample.gripper_percent)])


class GroundTruthMonitor:
    """Records the simulator's ground truth during a trial (runner only; needs this process's rospy node).

    On every ``/fake_baxter/object_poses`` message (30 Hz simulated) it stores a ``GroundTruthSample``
    (the first object's pose, the latest ``/robot/limb/left/endpoint_state`` pose and gripper opening);
    ``respawns`` is the latest ``/fake_baxter/respawns`` count (scenes with a ``respawn:`` key).
    """

    def __init__(self):
        import rospy
        from geometry_msgs.msg import PoseArray
        from std_msgs.msg import UInt32

        from baxter_pnp.msgs import msg
        self._lock = threading.Lock()
        self.samples = []            # GroundTruthSample, in arrival order
        self._gripper_pose = None
        self._gripper_position = None
        self.respawns = 0
        self._subscribers = [
            rospy.Subscriber('/fake_baxter/respawns', UInt32, self._on_respawns, queue_size=1),
            rospy.Subscriber('/fake_baxter/object_poses', PoseArray, self._on_objects, queue_size=10),
            rospy.Subscriber(f'/robot/limb/{SIDE}/endpoint_state', msg.EndpointState, self._on_endpoint, queue_size=1),
            rospy.Subscriber(f'/robot/end_effector/{SIDE}_gripper/state', msg.EndEffectorState, self._on_gripper,
                             queue_size=1)]

    def _on_respawns(self, message):
        self.respawns = message.data

    def _on_endpoint(self, message):
        with self._lock:
            self._gripper_pose = pose_msg_to_matrix(message.pose)

    def _on_gripper(self, message):
        with self._lock:
            self._gripper_position = float(message.position)

    def _on_objects(self, message):
        if not message.poses:
            return
        with self._lock:
            if self._gripper_pose is not None and self._gripper_position is not None:
                self.samples.append(GroundTruthSample(message.header.stamp.to_sec(),
                                                      pose_msg_to_matrix(message.poses[0]), self._gripper_pose,
                                                      self._gripper_position))

    def count(self):
        with self._lock:
            return len(self.samples)

    def snapshot(self):
        """A copy of the sample list."""
        with self._lock:
            return list(self.samples)

    def wait_for_samples(self, count, timeout=10.0):
        """The sample list once it holds more than ``count`` samples (wall ``timeout`` s), else RuntimeError."""
        deadline = time.monotonic() + timeout
        while self.count() <= count:
            if time.monotonic() > deadline:
                raise RuntimeError('no ground truth from /fake_baxter/object_poses')
            time.sleep(0.02)
        return self.snapshot()

    def close(self):
        for subscriber in self._subscribers:
            subscriber.unregister()


def pre_close_sample(samples, open_above=95.0, drop=2.0):
    """The last sample before the gripper first started closing: once open (above ``open_above`` %;
    calibration opens it first), its opening fell more than ``drop`` points below the widest seen since
    (a block held crooked can stop the fingers above 90 %). None if it never closed."""
    widest = None
    for k, position in enumerate(sample.gripper_percent for sample in samples):
        if widest is not None and position < widest - drop:
            return samples[k - 1]
        if position >= open_above:
            widest = max(position, widest or position)
    return None


def lift_times(samples, rest_z, threshold=LIFT_THRESHOLD):
    """Simulated times (s) at which the target block started a lift: its top face rose to ``threshold`` (m)
    above ``rest_z`` (its top face's height at rest on the table) from below; ``samples``:
    ``GroundTruthSample``s in time order."""
    times, up = [], False
    for sample in samples:
        rising = sample.T_base_block[2, 3] - rest_z >= threshold
        if rising and not up:
            times.append(sample.stamp)
        up = rising
    return times
