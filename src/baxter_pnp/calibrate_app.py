"""``calibrate_hand_eye.py``: the hand camera's mount on the arm (and its intrinsics, and the table plane) from
the arm's own moves around a chessboard lying on the table.

The calibration task on the task layer (``baxter_pnp.task``): the robot session, safe motion, the hand camera.
Pure cores: ``board_views`` (where to look from), ``calibration`` (corners, coverage, conditioning) and
``hand_eye`` (the solver and its file). Only the Baxter SDK's topics and services, so the same run works on a
real robot and on the fake Baxter (scene ``config/scenes/hand_eye.yaml``):

1. connect, move to the start pose, find the board (its pose in ``base`` through the current mount: tf, the
   URDF or ``--hand-eye``);
2. plan diverse viewpoints around it, keep those in view (clear of the fingers), safe and with an IK solution;
3. at each: move, let the arm settle, take a frame, its sub-pixel corners and the hand pose at its stamp;
4. back at the start pose, check the board did not move (its corners where they were in the first view);
5. solve (``hand_eye.solve_hand_eye``), write the calibration file (and ``--intrinsics``), print the launch line.

Exit status 0 with the file written; 1 when the run fails (nothing written); 2 for bad parameters.
"""
import argparse
import json
import os
import time
from dataclasses import dataclass
from typing import NamedTuple, Optional, Tuple

import numpy as np
import rospy

from baxter_pnp import board_views, calibration, hand_eye, robot, view
from baxter_pnp.params import ParameterError, Parameters
from baxter_pnp.runtime import PACKAGE_ROOT, command_summary
from baxter_pnp.task import cli
from baxter_pnp.task.motion import Motion
from baxter_pnp.task.session import RobotSession, TaskFailure, failure_reason
from baxter_pnp.transforms import invert

DEFAULT_CONFIG = os.path.join(PACKAGE_ROOT, 'config', 'calibrate_hand_eye.yaml')
BOARD_MOVED_PX = 3.0        # px: the start view's corners moved more than this at the end: the board moved


@dataclass
class HandEyeTaskConfig(Parameters):
    """The calibration task's parameters (metres, degrees, seconds of robot time)."""
    pattern: Tuple[int, int] = (9, 6)       # inner corners (columns, rows)
    square: float = 0.025                   # square side (m): measure the printed board
    board_thickness: float = 0.0            # m between the table top and the printed squares
    views: int = 20                         # viewpoints to use (the solve needs at least hand_eye.MIN_VIEWS)
    distances: Tuple[float, float] = (0.25, 0.45)   # camera to board centre (m)
    max_tilt_deg: float = 30.0              # optical axis to board normal
    max_roll_deg: float = 45.0              # rotation about the optical axis
    refine_intrinsics: bool = False         # also refine fx, fy, cx, cy (and distortion) of the camera
    start_pose: str = 'down'                # config/start_poses.yaml: the board must be in view from here
    settle_time: float = 0.5                # s the arm rests before a view's frame is taken
    seed: int = 0                           # of the viewpoint plan

    def validate(self):
        self.require(len(self.pattern) == 2 and min(self.pattern) >= 2, 'pattern', 'must be [columns, rows] >= 2')
        self.require(self.pattern[0] != self.pattern[1], 'pattern',
                     'must not be square (columns == rows): its orientation would be ambiguous')
        self.require_positive('square', 'views', 'max_tilt_deg')
        self.require_non_negative('board_thickness', 'max_roll_deg', 'settle_time')
        self.require(self.views >= hand_eye.MIN_VIEWS, 'views', 'must be >= %d' % hand_eye.MIN_VIEWS)
        self.require(0 < self.distances[0] < self.distances[1], 'distances', 'must be [near, far] metres')
        self.require(self.max_tilt_deg <= 60.0, 'max_tilt_deg', 'must be <= 60 (the corners blur beyond)')


def oriented_corners(corners_px, predicted_px):
    """``corners_px`` (N, 2) in the order of ``predicted_px`` (N, 2): as found or reversed (OpenCV may start a
    board's grid from either end), whichever lies nearer the prediction."""
    corners_px = np.asarray(corners_px, dtype=float).reshape(-1, 2)
    reversed_px = corners_px[::-1]
    if np.mean(np.linalg.norm(reversed_px - predicted_px, axis=1)) < np.mean(np.linalg.norm(corners_px - predicted_px,
                                                                                             axis=1)):
        return reversed_px
    return corners_px


@dataclass
class CalibrationRun:
    """What a run found (for the log, the result JSON and the tests)."""
    success: bool = False
    failure_reason: Optional[str] = None
    views_planned: int = 0
    views_taken: int = 0
    time_s: float = 0.0                      # robot time of the run
    result: Optional[hand_eye.HandEyeResult] = None

    def to_json(self):
        out = {'success': self.success, 'failure_reason': self.failure_reason, 'views_planned': self.views_planned,
               'views_taken': self.views_taken, 'time_s': round(self.time_s, 2)}
        r = self.result
        if r is not None:
            out.update(rms_px=round(r.rms_px, 3), views_used=r.views_used, std_mm=round(r.std_mm, 3),
                       std_deg=round(r.std_deg, 4), outliers_px={k: round(v, 2) for k, v in r.outliers_px.items()},
                       translation=[round(float(v), 5) for v in r.T_hand_camera[:3, 3]],
                       methods={k: [round(float(a), 3), round(float(b), 4)] for k, (a, b) in r.methods.items()})
        return out


class HandEyeRun:
    """One calibration run: ``config`` a :class:`HandEyeTaskConfig`, ``session_config`` a SessionConfig."""

    def __init__(self, config, session_config):
        self.config = config
        self.session = RobotSession(session_config, log_name='calibrate')
        self.motion = Motion(self.session)
        self.run_result = CalibrationRun()
        self.T_hand_gripper = None
        self.object_points = calibration.board_object_points(config.pattern, config.square)

    def run(self):
        """The whole procedure; returns the CalibrationRun (``result`` set on success). Never raises for robot
        or calibration failures: they end in ``failure_reason`` after a retreat to the start pose."""
        session, c = self.session, self.config
        try:
            session.connect()
            session.start_clock()
            hand_eye_prior = session.hand_eye
            self.T_hand_gripper = hand_eye_prior.T_hand_camera @ invert(hand_eye_prior.T_gripper_camera)
            session.open_gripper()
            start = session.start_pose(c.start_pose)
            self.motion.move_to_joints(start, 'start pose %s' % c.start_pose)
            first = self.take_view('start', T_base_board=None)
            if first is None:
                raise TaskFailure('board_not_found', 'no %dx%d chessboard in view of the %s start pose: lay it flat '
                                  'on the table under the hand camera' % (*c.pattern, c.start_pose))
            T_base_board = self.board_in_base(first)
            views = [first] + self.visit(self.plan(T_base_board, first.camera), T_base_board)
            self.motion.move_to_joints(start, 'back to the start pose')
            self.check_board_still(first)
            self.run_result.views_taken = len(views)
            self.solve(views)
            self.run_result.success = True
        except Exception as error:      # noqa: BLE001 - task, robot and calibration failures end the run
            reason = failure_reason(error)
            if reason is None:
                raise
            self.run_result.failure_reason = reason
            rospy.logerr('calibrate: FAILED (%s): %s' % (reason, error))
            self.motion.retreat(reason)
        finally:
            self.run_result.time_s = session.elapsed()
        return self.run_result

    # ------------------------------------------------------------------------------------------ views
    def plan(self, T_base_board, camera):
        """The viewpoints to visit: ``board_views`` candidates kept when the whole board is in view clear of
        the fingers, the gripper pose passes the safety checks and IK solves it; up to ``views`` - 1 of them
        (the start view is one), in a short order from the arm's pose. [T_base_gripper]"""
        c, session = self.config, self.session
        T_gripper_camera = session.hand_eye.T_gripper_camera
        clearance = view.hand_clearance_of(session.kinematics, T_gripper_camera, camera)
        plan = []
        candidates = board_views.candidate_views(T_base_board, c.pattern, c.square, count=c.views,
                                                 distances=c.distances, max_tilt_deg=c.max_tilt_deg,
                                                 max_roll_deg=c.max_roll_deg, seed=c.seed, camera=camera,
                                                 clearance_px=clearance)
        rejected = {'unsafe': 0, 'no IK': 0}     # the candidates all see the board clear of the fingers
        for T_base_camera in candidates:
            if len(plan) == c.views - 1:
                break
            T_base_gripper = T_base_camera @ invert(T_gripper_camera)
            try:
                session.safety.check_cartesian_target(T_base_gripper)
                session.limb.solve_ik(T_base_gripper, seed=session.limb.joint_angles())
            except robot.IKFailure:
                rejected['no IK'] += 1
                continue
            except ValueError:          # UnsafeCommand
                rejected['unsafe'] += 1
                continue
            plan.append(T_base_camera)
        rospy.loginfo('calibrate: %d viewpoints planned (of %d candidates: %s)'
                      % (len(plan), len(candidates), ', '.join('%d %s' % (n, k) for k, n in rejected.items())))
        self.run_result.views_planned = len(plan) + 1
        if len(plan) + 1 < hand_eye.MIN_VIEWS:
            raise TaskFailure('too_few_views', 'only %d reachable viewpoints see the whole board (need %d): move '
                              'the board nearer the arm or lower the start pose' % (len(plan) + 1, hand_eye.MIN_VIEWS))
        ordered = board_views.order_views(plan, session.limb.endpoint_pose() @ T_gripper_camera)
        return [T_base_camera @ invert(T_gripper_camera) for T_base_camera in ordered]

    def visit(self, plan, T_base_board):
        """Move through ``plan`` (gripper poses) and take a view at each; the views where the board was found."""
        views = []
        for k, T_base_gripper in enumerate(plan, start=1):
            self.session.check_deadline()
            self.motion.move_to_pose(T_base_gripper, 'viewpoint %d of %d' % (k, len(plan)))
            taken = self.take_view('view_%02d' % k, T_base_board)
            if taken is None:
                rospy.logwarn('calibrate: viewpoint %d: the board is not found in the image; skipped' % k)
            else:
                views.append(taken)
        return views

    def take_view(self, name, T_base_board):
        """After ``settle_time`` of rest: a frame, its board corners (oriented like the board model, predicted
        through ``T_base_board`` when given) and the hand pose at its stamp; None without a board."""
        session, c = self.session, self.config
        rospy.sleep(c.settle_time)
        session.check_robot()
        try:
            frame = session.camera.wait_for_frame(rospy.get_time(), timeout=session.config.frame_timeout)
        except robot.RobotTimeout as error:
            raise robot.StreamLost(session.camera.image_topic, session.config.frame_timeout,
                                   session.config.frame_timeout) from error
        camera = session.camera_override or frame.camera
        corners = calibration.find_board_corners(frame.image_bgr, c.pattern)
        if corners is None:
            return None
        T_base_hand = session.limb.endpoint_pose_at(frame.stamp) @ invert(self.T_hand_gripper)
        corners = corners.reshape(-1, 2)
        if T_base_board is not None:
            T_camera_board = invert(T_base_hand @ session.hand_eye.T_hand_camera) @ T_base_board
            corners = oriented_corners(corners, camera.project(
                (T_camera_board[:3, :3] @ self.object_points.T).T + T_camera_board[:3, 3]))
        board_view = hand_eye.BoardView(T_base_hand, corners, name)
        rospy.loginfo('calibrate: %s: board found at %.3f s, hand at %s mm' % (
            name, frame.stamp, np.round(1000 * T_base_hand[:3, 3], 1).tolist()))
        return _Taken(board_view, camera)

    def board_in_base(self, taken):
        """The board's pose in base from one view through the current mount (the plan's centre)."""
        T_camera_board = hand_eye.board_pose_in_camera(taken.view.corners_px, taken.camera, self.config.pattern,
                                                       self.config.square)
        T_base_board = taken.view.T_base_hand @ self.session.hand_eye.T_hand_camera @ T_camera_board
        rospy.loginfo('calibrate: board at %s mm in base, normal %s' % (
            np.round(1000 * T_base_board[:3, 3], 1).tolist(), np.round(T_base_board[:3, 2], 3).tolist()))
        return T_base_board

    def check_board_still(self, first):
        """TaskFailure('board_moved') when the start view's corners are no longer where they were."""
        again = self.take_view('start_again', None)
        if again is None:
            raise TaskFailure('board_moved', 'the board is no longer found from the start pose')
        shift = np.linalg.norm(oriented_corners(again.view.corners_px, first.view.corners_px)
                               - first.view.corners_px, axis=1)
        if np.max(shift) > BOARD_MOVED_PX:
            raise TaskFailure('board_moved', 'the board moved during the run: its corners seen from the start pose '
                              'moved up to %.1f px (more than %.1f px)' % (np.max(shift), BOARD_MOVED_PX))
        rospy.loginfo('calibrate: the board did not move (start view corners within %.2f px)' % np.max(shift))

    # ------------------------------------------------------------------------------------------ solving
    def solve(self, taken):
        c = self.config
        views = [t.view for t in taken]
        camera = taken[0].camera
        try:
            result = hand_eye.solve_hand_eye(views, camera, c.pattern, c.square,
                                             refine_intrinsics=c.refine_intrinsics,
                                             board_thickness=c.board_thickness)
        except hand_eye.HandEyeError as error:
            raise TaskFailure('calibration_failed', str(error)) from None
        self.run_result.result = result
        for name, rms in result.per_view_rms_px.items():
            rospy.loginfo('calibrate: %s: RMS %.3f px' % (name, rms))
        for name, rms in result.outliers_px.items():
            rospy.logwarn('calibrate: %s left out as an outlier (RMS %.2f px)' % (name, rms))
        for method, (mm, deg) in result.methods.items():
            rospy.loginfo('calibrate: OpenCV %s alone: %.2f mm, %.3f deg from the refined mount' % (method, mm, deg))
        if c.refine_intrinsics:
            report = calibration.coverage([v.corners_px for v in views], (camera.width, camera.height), c.pattern)
            rospy.loginfo('calibrate: coverage %s' % json.dumps(report, default=str))
        rospy.loginfo('calibrate: mount %s mm, RMS %.3f px over %d views, 1-sigma %.2f mm / %.3f deg'
                      % (np.round(1000 * result.T_hand_camera[:3, 3], 2).tolist(), result.rms_px,
                         result.views_used, result.std_mm, result.std_deg))
        return result


class _Taken(NamedTuple):
    """A view and the camera model of its frame."""
    view: hand_eye.BoardView
    camera: object              # camera.CameraModel


# ==================================================================================== entry point
def parse_pattern(text):
    return list(calibration.parse_pattern(text))


def parse_args(argv):
    parser = argparse.ArgumentParser(prog='calibrate_hand_eye.py', description=command_summary(__doc__))
    parser.add_argument('--pattern', type=parse_pattern, help='inner corners COLSxROWS, e.g. 9x6')
    parser.add_argument('--square', type=float, help='square side (m), measured on the printed board')
    parser.add_argument('--views', type=int, help='viewpoints (default 20)')
    parser.add_argument('--refine-intrinsics', action='store_true', default=None,
                        help='also refine the camera intrinsics (implied by --intrinsics)')
    parser.add_argument('--start-pose', help='start pose (config/start_poses.yaml) with the board in view')
    parser.add_argument('-o', '--output', required=True, metavar='FILE.yaml', help='the hand-eye calibration file')
    parser.add_argument('--intrinsics', metavar='OUT.yaml',
                        help='also write the refined camera (camera_calibration_parsers format)')
    cli.add_session_arguments(parser, DEFAULT_CONFIG)
    return parser.parse_args(argv)


TASK_KEYS = ('pattern', 'square', 'views', 'refine_intrinsics', 'start_pose')


def build_run(args):
    extra = {'refine_intrinsics': True} if args.intrinsics else {}
    config, session_config = cli.read_configs(HandEyeTaskConfig, args, TASK_KEYS, extra)
    for path, key in ((args.output, '--output'), (args.intrinsics, '--intrinsics')):
        if path and not os.path.isdir(os.path.dirname(os.path.abspath(path))):
            raise ParameterError(key, 'the directory of %s does not exist' % path)
    return config, session_config


def write_outputs(args, run, session_config):
    """The calibration file (and intrinsics), the launch line, the result JSON."""
    result = run.result
    hand_eye.write_hand_eye(args.output, result, side=session_config.side)
    rospy.loginfo('calibrate: wrote %s' % args.output)
    if args.intrinsics:
        result.camera.to_yaml(args.intrinsics)
        rospy.loginfo('calibrate: wrote %s (fx %.2f fy %.2f cx %.2f cy %.2f)' % (
            args.intrinsics, result.camera.K[0, 0], result.camera.K[1, 1], result.camera.K[0, 2], result.camera.K[1, 2]))
    print(hand_eye.static_transform_publisher_line(result, side=session_config.side))


def main(argv=None):
    args, configs = cli.start('calibrate_hand_eye', argv, parse_args, build_run)
    if configs is None:
        return 2
    config, session_config = configs
    started = time.monotonic()
    run = HandEyeRun(config, session_config).run()
    if run.success:
        write_outputs(args, run, session_config)
    if args.result_json:
        with open(args.result_json, 'w') as stream:
            json.dump(run.to_json(), stream, indent=2)
    rospy.loginfo('calibrate_hand_eye: %s in %.1f s of robot time (%.1f s wall)'
                  % ('SUCCESS' if run.success else 'FAILURE', run.time_s, time.monotonic() - started))
    return 0 if run.success else 1
