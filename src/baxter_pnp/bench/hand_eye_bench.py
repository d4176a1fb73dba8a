"""``make bench-hand-eye``: the hand-eye calibration on the fake Baxter, judged on the scene's ground truth.

For each case (a scene with a chessboard and a true camera off the published one), on a fresh master and fake:
run ``calibrate_hand_eye.py``, compare the recovered mount (and focal length) with the truth, then pick the
scene's block with the URDF's mount and with the calibration and measure, on the fake's ground truth, how far
off the gripper axis the block is held. Prints a table (README, "Calibration on the robot").
"""
import argparse
import json
import os
import time

import numpy as np

from baxter_pnp.runtime import PACKAGE_ROOT, command_summary

SCENES = os.path.join(PACKAGE_ROOT, 'config', 'scenes')
# name: (scene, refine the intrinsics too: --intrinsics, then the pick uses them)
CASES = {
    'mount': ('hand_eye.yaml', False),
    'mount+focal': ('hand_eye_focal.yaml', True),
}


def urdf_T_hand_camera(side='left'):
    """The URDF's camera mount (what tf publishes): ``<side>_hand_camera`` in ``<side>_hand`` (4x4, m)."""
    from baxter_pnp.kinematics import ArmKinematics
    kinematics = ArmKinematics(side)
    try:
        return kinematics.relative(side + '_hand', side + '_hand_camera')
    finally:
        kinematics.close()


def block_in_gripper_mm():
    """(x, y) mm of the held block's top-face centre off the gripper axis, from the fake's ground truth (in a
    ROS node: ``experiments.call_in_ros_node``)."""
    import rospy
    from geometry_msgs.msg import PoseArray

    from baxter_pnp.bench.ground_truth import block_in_gripper_mm as in_gripper
    from baxter_pnp.msgs import msg
    from baxter_pnp.transforms import pose_msg_to_matrix
    objects = rospy.wait_for_message('/fake_baxter/object_poses', PoseArray, timeout=10.0)
    endpoint = rospy.wait_for_message('/robot/limb/left/endpoint_state', msg.EndpointState, timeout=10.0)
    return in_gripper(pose_msg_to_matrix(endpoint.pose), pose_msg_to_matrix(objects.poses[0]))[:2].tolist()


def run_case(name, out_dir):
    """One case on its own master and fake: a dict of what was measured."""
    from baxter_pnp import hand_eye
    from baxter_pnp.bench.experiments import call_in_ros_node
    from baxter_pnp.camera import CameraModel
    from baxter_pnp.sim.launcher import FakeBaxterProcess, RosMaster, run_script
    from baxter_pnp.sim.scene import load_scene
    from baxter_pnp.transforms import pose_error
    scene_file, with_intrinsics = CASES[name]
    scene_path = os.path.join(SCENES, scene_file)
    scene = load_scene(scene_path)
    work = os.path.join(out_dir, name)
    os.makedirs(work, exist_ok=True)
    output, intrinsics = os.path.join(work, 'hand_eye.yaml'), os.path.join(work, 'camera.yaml')
    args = ['-o', output, '--result-json', os.path.join(work, 'calibration.json')]
    args += ['--intrinsics', intrinsics] if with_intrinsics else []
    row = {'case': name, 'scene': scene_file}
    with RosMaster(log_dir=os.path.join(work, 'ros_log')) as master:
        for pick_with in ('urdf', 'calibration'):
            with FakeBaxterProcess(master, ['--scene', scene_path, '--real-time-factor', '0'],
                                   log_path=os.path.join(work, 'fake_%s.log' % pick_with)):
                if pick_with == 'calibration':
                    started = time.monotonic()
                    run = run_script(master, 'calibrate_hand_eye.py', args, timeout=600,
                                     log_path=os.path.join(work, 'calibrate.log'))
                    with open(os.path.join(work, 'calibration.json')) as stream:
                        result = json.load(stream)
                    row.update(calibration_ok=run.returncode == 0, robot_time_s=result['time_s'],
                               wall_s=round(time.monotonic() - started, 1), views=result.get('views_used'))
                    if run.returncode != 0:
                        row['failure'] = result.get('failure_reason')
                        break
                    calibration = hand_eye.load_hand_eye(output)
                    T_true = urdf_T_hand_camera() @ scene.camera_error.T_published_true
                    translation, rotation = pose_error(T_true, calibration.T_parent_child)
                    row.update(error_mm=round(1000 * translation, 3), error_deg=round(float(np.degrees(rotation)), 4),
                               std_mm=calibration.std_mm, std_deg=calibration.std_deg, rms_px=calibration.rms_px)
                    if with_intrinsics:
                        fx_published = published_fx()
                        fx = CameraModel.from_yaml(intrinsics).K[0, 0]
                        row['focal_error_pct'] = round(100 * (fx / (fx_published * scene.camera_error.focal_scale)
                                                              - 1), 3)
                    pick_args = ['--hand-eye', output] + (['--camera-calibration', intrinsics]
                                                           if with_intrinsics else [])
                else:
                    pick_args = []
                pick = run_script(master, 'pick_square.py', ['--result-json', os.path.join(work, 'pick.json'),
                                                             *pick_args], timeout=300,
                                  log_path=os.path.join(work, 'pick_%s.log' % pick_with))
                offset = call_in_ros_node(master, block_in_gripper_mm) if pick.returncode == 0 else None
                row['pick_%s' % pick_with] = (None if offset is None else round(float(np.hypot(*offset)), 2))
    return row


def published_fx():
    """fx (px) of the fake's published 640x400 hand camera (its camera_info model)."""
    from baxter_pnp.sim.cameras import sensor_model, sensor_window
    return sensor_model('left_hand_camera').windowed(sensor_window(640, 400, False)).K[0, 0]


def main(argv=None):
    parser = argparse.ArgumentParser(prog='bench_hand_eye.py', description=command_summary(__doc__))
    parser.add_argument('--out', default='out/bench_hand_eye')
    parser.add_argument('--cases', default=','.join(CASES), help='comma-separated of: %s' % ', '.join(CASES))
    args = parser.parse_args(argv)
    rows = [run_case(name, os.path.abspath(args.out)) for name in args.cases.split(',')]
    columns = ('case', 'calibration_ok', 'views', 'robot_time_s', 'wall_s', 'rms_px', 'error_mm', 'std_mm',
               'error_deg', 'std_deg', 'focal_error_pct', 'pick_urdf', 'pick_calibration')
    print('| ' + ' | '.join(columns) + ' |')
    print('|' + '---|' * len(columns))
    for row in rows:
        print('| ' + ' | '.join(str(row.get(c, '-')) for c in columns) + ' |')
    print('pick_*: the held block off the gripper axis (mm, ground truth), picking with the URDF\'s mount and with '
          'the calibration')
    with open(os.path.join(args.out, 'results.json'), 'w') as stream:
        json.dump(rows, stream, indent=2)
    return 0 if all(row.get('calibration_ok') for row in rows) else 1
