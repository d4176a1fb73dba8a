"""``table_task.py``: tasks with every block on the table (issue 14): ``survey``, ``sort``, ``stack``, ``clear``.

Each run: connect, start pose, a survey of the table (``task.survey``: the table map, published and printed one
line a block), then the task's moves (``table_plan``: where each block goes, never where another stands), each
a pick (``task.picker``: the same steps as ``pick_square.py``), a put-down (lifted before every lateral move),
and a look that verifies it; a step whose look does not verify it is tried again (``step_retries``), from
where the look (or, if it saw nothing, a new survey) finds the block. A stacked block is put on the one below
after a look at that block's top face from its view pose (the held block is then moved over it and released
``place_clearance`` above it). A final survey reports what ended where and notices blocks moved by accident
(a sort or a clear then has one more round). Exit status 0 only when every step and the final survey verify.

Outputs (``--output-dir``): ``result.json`` (``TableTaskResult``), ``table_map.json`` (the last survey's map),
``final_view.png``; ``--result-json``; the latched ``/baxter_pnp/result``. Frames: ``base``; 4x4, metres.
"""
import argparse
import json
import os
import sys
import time
from dataclasses import asdict, dataclass, field
from typing import List, Optional

import numpy as np
import rospy

from baxter_pnp import perception, pick, survey, table_map, table_plan, vision
from baxter_pnp.params import ParameterError
from baxter_pnp.runtime import PACKAGE_ROOT, command_summary
from baxter_pnp.table_plan import PlanError, TableTaskConfig
from baxter_pnp.task import cli, target
from baxter_pnp.task.eye import BlockQuery, Eye
from baxter_pnp.task.motion import Motion
from baxter_pnp.task.outputs import Outputs
from baxter_pnp.task.picker import Picker
from baxter_pnp.task.session import FATAL_REASONS, RobotSession, failure_reason
from baxter_pnp.task.survey import Survey
from baxter_pnp.transforms import make_transform, raised

DEFAULT_CONFIG = os.path.join(PACKAGE_ROOT, 'config', 'table_task.yaml')
TASKS = ('survey', 'sort', 'stack', 'clear')
SEEN_NEAR = 0.04        # m: a block seen this close (xy) to where it was believed is that block
LOOK_HEIGHT = 0.20      # m: a straight-down look at a block has the gripper tip this far above its top face
ROUNDS = 2              # sort / clear: plan-and-move rounds (the second after a final survey found a block astray)


@dataclass
class StepResult:
    """One move of a task: ``move`` (``table_plan.Move.to_json``), whether a look ``verified`` it, ``attempts``,
    ``error_mm`` (the look's xy distance of the block to its place, or on a stack to the block below; mm),
    ``failure_reason`` of the last failed attempt, ``time_s`` (robot time since the task started, at its end)."""
    move: dict
    verified: bool = False
    attempts: int = 0
    error_mm: Optional[float] = None
    failure_reason: Optional[str] = None
    time_s: float = 0.0


@dataclass
class TableTaskResult:
    """A table task's outcome (``result.json``): maps are ``MapBlock.to_json`` lists; ``disturbed`` the blocks
    no move touched that the final survey finds elsewhere; ``not_in_place`` the verified moves whose block the
    final survey does not see at its place; times in s of robot time."""
    task: str
    mode: str
    success: bool = False
    failure_reason: Optional[str] = None
    detail: str = ''
    steps: List[StepResult] = field(default_factory=list)
    initial_map: list = field(default_factory=list)
    final_map: list = field(default_factory=list)
    disturbed: list = field(default_factory=list)
    not_in_place: list = field(default_factory=list)
    survey_time_s: float = 0.0
    total_time_s: float = 0.0
    history: list = field(default_factory=list)     # no per-step servo history (task.outputs plots none)

    def to_json(self):
        return asdict(self)


class TableTaskApplication:
    """One ``task`` (TASKS) run with ``options`` (``bins`` {colour: (x, y)}, ``at`` (x, y) and ``order``
    [colours], ``to`` (x, y), ``shape`` or None); ``config`` a ``TableTaskConfig``, ``session_config`` a
    ``task.settings.SessionConfig``. Construct after ``rospy.init_node``; ``run()`` returns the result."""

    def __init__(self, task, options, config, session_config, vision_config, output_dir=None, result_json=None):
        self.task, self.options, self.config = task, options, config
        self.session = session = RobotSession(session_config, log_name='table_task')
        self.motion = Motion(session)
        self.outputs = Outputs(output_dir, result_json, 1, config.mode)
        self.output_dir = output_dir
        query = BlockQuery(None, None, config.side_length, config.block_height, config.estimator, session.table,
                           config.edge_radius, towers=True)
        self.eye = Eye(session, vision_config, query,
                       views_dir=self.outputs.views_dir if session_config.save_views else None)
        self.survey = Survey(session, self.motion, self.eye, session_config.table_area)
        self.area = survey.TableRect(*session_config.table_area)
        self.picker = Picker(session, self.motion, self.eye, config)
        self.picker.stay_on_block = True    # several blocks alike: pick the one the map means, no other
        self.result = TableTaskResult(task, config.mode)
        self.map = table_map.TableMap()
        self.camera = None
        self.tower_top = None               # stack: (shape, colour, T_base_block) of the top block, last seen
        self.in_place_ids = set()           # stack: the initial map's id of a bottom block already in place

    # ================================================================================ the run
    def run(self):
        """The task (module docstring). Never raises for robot faults: the result names the failure."""
        session, result = self.session, self.result
        try:
            session.connect()
            session.open_gripper()
            self.motion.move_to_joints(session.start_pose(self.config.start_pose),
                                       'start pose %s' % self.config.start_pose)
            session.start_clock()
            self.survey_table()
            result.initial_map = [b.to_json() for b in self.map.blocks()]
            result.survey_time_s = session.elapsed()
            if self.task != 'survey':
                initial = self.map.blocks()
                (self.run_stack if self.task == 'stack' else self.run_areas)()
                self.final_survey(initial)
            result.success = (result.failure_reason is None and all(s.verified for s in result.steps)
                              and not result.disturbed and not result.not_in_place)
        except PlanError as error:
            self.fail('no_plan', str(error))
        except Exception as error:      # noqa: BLE001 - a task or robot failure ends the run; others raise
            if failure_reason(error) is None:
                raise
            self.fail(failure_reason(error), str(error))
        finally:
            result.total_time_s = session.elapsed()
            self.finish()
        return result

    def fail(self, reason, detail):
        self.result.failure_reason, self.result.detail = reason, detail
        rospy.logerr('table_task: FAILED (%s): %s' % (reason, detail))
        if reason != 'no_plan':
            self.motion.retreat(reason)

    def finish(self):
        r = self.result
        verified = sum(s.verified for s in r.steps)
        (rospy.loginfo if r.success else rospy.logerr)(
            'table_task %s: %s in %.1f s: %d of %d step(s) verified%s%s%s'
            % (r.task, 'SUCCESS' if r.success else 'FAILURE', r.total_time_s, verified, len(r.steps),
               '' if not r.disturbed else ', %d block(s) moved by accident' % len(r.disturbed),
               '' if not r.not_in_place else ', %d block(s) not at their place' % len(r.not_in_place),
               '' if r.failure_reason is None else ', reason: %s' % r.failure_reason))
        if self.output_dir:
            os.makedirs(self.output_dir, exist_ok=True)
            with open(os.path.join(self.output_dir, 'table_map.json'), 'w') as f:
                json.dump(json.loads(self.map.to_json()), f, indent=1)
        self.outputs.cycle_done([r], self.eye.last_annotated)

    # ================================================================================ looking
    def level(self, observation, T_base_camera):
        """The stack level of a believable observation, None for an estimate not to trust
        (``table_plan.level_of_pose``)."""
        return table_plan.level_of_pose(observation.pose, T_base_camera, self.session.table, self.config)

    def survey_table(self):
        """A survey (``task.survey``) into a new table map, printed one line a block."""
        if self.camera is None:
            self.camera = self.eye.frame().camera
        self.map = self.survey.run(lambda o, T_base_camera: self.level(o, T_base_camera) is not None, self.camera)
        print('table map: %d block(s)' % len(self.map), flush=True)
        for block in self.map.blocks():
            print(table_plan.block_line(block), flush=True)
        return self.map

    def look_poses(self, T_base_block):
        """Gripper poses to look at a block at ``T_base_block`` from, best first: its view pose
        (``Picker.view_pose_of``: low in the image, ``view_depth`` away), then straight down ``LOOK_HEIGHT``
        above it with the optical axis through it, the gripper turned by each of the survey's yaws."""
        yield self.picker.view_pose_of(T_base_block, self.session.limb.endpoint_pose(), self.camera)
        T_gripper_camera = self.session.hand_eye.T_gripper_camera
        for yaw in survey.YAWS:
            T_down = survey.down_pose(T_base_block[:2, 3], T_base_block[2, 3] + LOOK_HEIGHT, yaw)
            yield target.recentred(T_down, T_down @ T_gripper_camera, T_base_block, 0.0)

    def look_from_view(self, T_base_block, what):
        """Move to the first reachable of ``look_poses`` (none: ``backoff_height`` up from here) and look;
        returns the Look (no target chosen)."""
        limb = self.session.limb
        T_look = next((T for T in self.look_poses(T_base_block) if self.picker.reachable(T)), None)
        if T_look is None:
            rospy.logwarn('table_task: no reachable pose to look at %s from: looking from higher up' % what)
            T_look = raised(limb.endpoint_pose(), self.config.backoff_height)
        self.motion.move_to_pose(T_look, 'look at %s' % what)
        return self.eye.look(after_stamp=rospy.get_time())

    def seen(self, look, shape, colour, level, near_xy, radius=SEEN_NEAR):
        """(T_base_block, its ``table_map.Sighting``) of the look's ``shape`` ``colour`` block on ``level`` (None:
        any) nearest ``near_xy`` within ``radius`` (m), or (None, None). On a given level, its estimate is moved
        along its viewing ray onto that level's height (``table_plan.on_height``: a depth error, and the lateral
        error that comes with it, removed; the sighting keeps the lateral error, ``table_map.lateral_std``); one whose
        polygon's pose is on no level or one level off is posed on it by its top face or silhouette where that fits
        (``table_plan.on_level``)."""
        c, table = self.config, self.session.table
        best, best_distance = None, radius
        for observation in look.observations:
            d = observation.detection
            if (d.shape, d.colour) != (shape, colour):
                continue
            if level is None:
                estimate = observation.pose if self.level(observation, look.T_base_camera) is not None else None
            else:
                estimate, refitted = table_plan.on_level(observation, look.frame.camera, look.T_base_camera,
                                                            table, level, c)
                if refitted:
                    rospy.loginfo('table_task: the %s %s at (%.0f, %.0f) px, off level %d by its polygon\'s pose, is '
                                  'on it by its %s' % (d.colour, d.shape, *d.centroid_px, level,
                                                       'silhouette' if estimate.method == 'silhouette' else 'top face'))
            if estimate is None:
                continue
            T_base_block = look.T_base_camera @ estimate.T_camera_object
            if level is not None and estimate.method not in perception.ON_THE_TABLE_METHODS:
                T_base_block = table_plan.on_height(T_base_block, look.T_base_camera[:3, 3],
                                                    table.z_at(T_base_block[:2, 3]) + level * c.block_height)
            distance = float(np.linalg.norm(T_base_block[:2, 3] - np.asarray(near_xy)))
            if distance <= best_distance:
                sighting = table_map.sightings_from_look([observation], look.T_base_camera, look.frame.camera)[0]
                if level is not None:
                    sighting = table_map.Sighting(shape, colour, T_base_block,
                                                  table_map.lateral_std(estimate, look.frame.camera))
                best, best_distance = (T_base_block, sighting), distance
        return best if best is not None else (None, None)

    @staticmethod
    def described(look):
        """What a look saw, for a warning: each posed block's colour, shape, position (mm in base), residual (px)."""
        return '; '.join('%s %s at %s mm, residual %.1f px' % (
            o.detection.colour, o.detection.shape,
            np.round(1000 * (look.T_base_camera @ o.pose.T_camera_object)[:3, 3], 1).tolist(), o.pose.residual_px)
            for o in look.observations if o.pose is not None) or 'nothing'

    def block_pose_at(self, xy, level):
        """4x4 pose (base, m) of a block standing at ``xy`` on stack ``level``, yaw 0."""
        return make_transform(None, (xy[0], xy[1], self.session.table.z_at(xy) + level * self.config.block_height))

    def placeable(self, xy):
        """True when ``xy`` (m) is on the table area and the arm reaches the hover pose over a block there."""
        if not (self.area.x_min <= xy[0] <= self.area.x_max and self.area.y_min <= xy[1] <= self.area.y_max):
            return False
        return self.picker.reachable(pick.hover_pose(self.block_pose_at(xy, 1), self.config,
                                                     self.session.limb.endpoint_pose()))

    # ================================================================================ one move
    def move_block(self, move, block_id):
        """Pick map block ``block_id`` and put it as ``move`` says; verified by a look, tried again from where
        the block is found. Returns the StepResult (appended to the result)."""
        c = self.config
        step = StepResult(move.to_json())
        self.result.steps.append(step)
        T_hint = self.map.block(block_id).T_base_block
        rospy.loginfo('table_task: step %d: the %s %s from (%.3f, %.3f) to (%.3f, %.3f) m, level %d'
                      % (len(self.result.steps), move.colour, move.shape, *T_hint[:2, 3], *move.to_xy, move.level))
        for attempt in range(1, c.step_retries + 2):
            step.attempts = attempt
            try:
                self.picker.retarget(move.shape, move.colour, T_hint)
                self.look_from_view(T_hint, 'the %s %s' % (move.colour, move.shape))
                self.session.run_resuming(self.picker.pick)
                xy = move.to_xy if move.level == 1 else self.guide_over(move)
                self.picker.put_down(xy, self.session.table.z_at(xy) + (move.level - 1) * c.block_height,
                                     'the %s %s' % (move.colour, move.shape))
                T_seen, sighting = self.verify(move, xy, step)
                if step.verified:
                    self.map.moved(block_id, sighting, rospy.get_time())
                    if self.task == 'stack':
                        self.tower_top = (move.shape, move.colour, T_seen)
                    break
                T_hint = T_seen
            except Exception as error:      # noqa: BLE001 - robot faults end the attempt; bugs raise
                reason = failure_reason(error)
                if reason is None or reason in FATAL_REASONS or reason == 'timeout':
                    raise
                step.failure_reason = reason
                rospy.logwarn('table_task: step %d attempt %d failed (%s): %s'
                              % (len(self.result.steps), attempt, reason, error))
                self.motion.retreat(reason)
                T_hint = None
            if attempt <= c.step_retries:
                T_hint, block_id = self.find(move, T_hint, block_id)
                if T_hint is None:
                    step.failure_reason = 'block_lost'
                    break
        step.time_s = self.session.elapsed()
        return step

    def verify(self, move, xy, step):
        """The look after putting down: the block on its level within the tolerance of ``xy`` (m) sets
        ``step.verified`` and ``error_mm``. Returns (T_base_block seen, its ``table_map.Sighting``) or (None, None)."""
        c = self.config
        look = self.look_from_view(self.block_pose_at(xy, move.level), 'where it was put')
        T_seen, sighting = self.seen(look, move.shape, move.colour, move.level, xy)
        if T_seen is None:
            rospy.logwarn('table_task: the look does not find the %s %s on level %d at (%.3f, %.3f) m (it saw: %s)'
                          % (move.colour, move.shape, move.level, *xy, self.described(look)))
            return None, None
        step.error_mm = 1000 * float(np.linalg.norm(T_seen[:2, 3] - np.asarray(xy)))
        tolerance = c.place_tolerance if move.level == 1 else c.stack_tolerance
        step.verified = step.error_mm <= 1000 * tolerance
        (rospy.loginfo if step.verified else rospy.logwarn)(
            'table_task: the %s %s is seen %.1f mm from its place on level %d: %s'
            % (move.colour, move.shape, step.error_mm, move.level, 'verified' if step.verified else 'NOT verified'))
        return T_seen, sighting

    def guide_over(self, move):
        """Stacking: a look at the top face of the block below from its view pose (the held block does not hide
        it there); returns its xy (m), where the held block goes (its last verified xy if not seen)."""
        shape, colour, T_below = self.tower_top
        look = self.look_from_view(T_below, 'the %s %s below' % (colour, shape))
        T_seen, _ = self.seen(look, shape, colour, move.level - 1, T_below[:2, 3])
        if T_seen is None:
            rospy.logwarn('table_task: the %s %s below is not seen (the look saw: %s): the held block goes where it '
                          'was last seen' % (colour, shape, self.described(look)))
            return tuple(T_below[:2, 3])
        rospy.loginfo('table_task: the %s %s below is seen %.1f mm from its last pose: the held block goes over it'
                      % (colour, shape, 1000 * np.linalg.norm(T_seen[:2, 3] - T_below[:2, 3])))
        self.tower_top = (shape, colour, T_seen)
        return tuple(T_seen[:2, 3])

    def find(self, move, T_hint, block_id):
        """Where the block of a failed attempt is: the look's pose ``T_hint`` if it saw it, else a look from above
        where it was believed, else a new survey (the nearest block of its shape and colour not at its place).
        Returns (T_base_block or None, its map id)."""
        if T_hint is not None:
            return T_hint, block_id
        believed = self.map.block(block_id).T_base_block
        T_seen, _ = self.seen(self.look_from_view(believed, 'where the block was'), move.shape, move.colour, None,
                              believed[:2, 3])
        if T_seen is not None:
            return T_seen, block_id
        rospy.logwarn('table_task: the %s %s is not where it was: surveying the table' % (move.colour, move.shape))
        self.survey_table()
        candidates = [b for b in self.map.blocks() if (b.shape, b.colour) == (move.shape, move.colour)
                      and np.linalg.norm(b.position[:2] - np.asarray(move.to_xy)) > self.config.place_tolerance]
        if not candidates:
            return None, block_id
        block = min(candidates, key=lambda b: float(np.linalg.norm(b.position[:2] - believed[:2, 3])))
        return block.T_base_block, block.id

    # ================================================================================ the tasks
    def plan_options(self):
        c = self.config
        return dict(spacing=c.slot_spacing, clearance=c.clearance, direction=c.row_direction,
                    placeable=self.placeable, in_place=c.place_tolerance)

    def area_plan(self, blocks, fixed=()):
        """The sort's or the clear's moves (``table_plan``) for ``blocks``, leaving the ``fixed`` ids alone."""
        o = self.options
        if self.task == 'sort':
            return table_plan.plan_sort(blocks, o['bins'], o['shape'], fixed=fixed, **self.plan_options())
        return table_plan.plan_clear(blocks, o['to'], o['shape'], per_row=self.config.clear_per_row, fixed=fixed,
                                     **self.plan_options())

    def named(self, block):
        """True if a sort or a clear moves ``block`` (a ``MapBlock``) to an area: its colour has a bin (a clear:
        any colour) and it has the ``--shape`` (if given)."""
        o = self.options
        return ((self.task == 'clear' or block.colour in o['bins'])
                and (o['shape'] is None or block.shape == o['shape']))

    def run_areas(self):
        """Sort or clear: move the planned blocks one at a time, re-planning from the updated map after each move
        (a block found astray by a look is planned again; one whose step failed is left where it is)."""
        given_up = []           # (shape, colour, xy) of blocks whose step failed
        for _ in range(2 * len(self.map) + 2):
            self.session.check_deadline()
            fixed = {b.id for b in self.map.blocks() for shape, colour, xy in given_up
                     if (b.shape, b.colour) == (shape, colour) and np.linalg.norm(b.position[:2] - xy) < SEEN_NEAR}
            moves = self.area_plan(self.map.blocks(), fixed)
            if not moves:
                return
            move = moves[0]
            if not self.move_block(move, move.block_id).verified:
                given_up.append((move.shape, move.colour, np.array(self.believed_xy(move))))

    def believed_xy(self, move):
        """Where the map believes ``move``'s block is (its from_xy when the map forgot it)."""
        try:
            return self.map.block(move.block_id).position[:2]
        except KeyError:
            return move.from_xy

    def run_stack(self):
        """The tower's moves, bottom first; a level that does not verify ends the tower."""
        o, c = self.options, self.config
        moves = table_plan.plan_stack(self.map.blocks(), o['at'], o['order'], o['shape'], c.clearance,
                                      self.placeable, c.place_tolerance)
        if moves and moves[0].level == 1:
            first = moves.pop(0)
            if not self.move_block(first, first.block_id).verified:
                return
        else:
            bottom = min((b for b in self.map.blocks() if b.colour == o['order'][0]
                          and (o['shape'] is None or b.shape == o['shape'])),
                         key=lambda b: float(np.linalg.norm(b.position[:2] - np.asarray(o['at']))))
            rospy.loginfo('table_task: the %s %s already stands at (%.3f, %.3f) m' % (bottom.colour, bottom.shape,
                                                                                     *bottom.position[:2]))
            self.tower_top = (bottom.shape, bottom.colour, bottom.T_base_block)
            self.in_place_ids = {bottom.id}
        for move in moves:
            self.session.check_deadline()
            if not self.move_block(move, move.block_id).verified:
                return

    def final_survey(self, initial):
        """The final survey: what ended where; the blocks no step moved and that are no longer where they were
        (``disturbed``); the blocks not at their place (``not_in_place``: a sort's or a clear's plan still has
        moves; a stack's top block is not on its level). A sort or a clear with blocks not in place gets one
        more round."""
        r, c = self.result, self.config
        for round_ in range(1, ROUNDS + 1):
            self.survey_table()
            moved = {b.id for b in initial for s in r.steps
                     if (b.shape, b.colour) == (s.move['shape'], s.move['colour'])
                     and np.linalg.norm(b.position[:2] - s.move['from_xy']) < SEEN_NEAR}
            if self.task == 'stack':
                r.not_in_place = self.tower_not_standing()
                part_of_task = self.in_place_ids        # the tower's bottom, if it stood there: now under the tower
            else:
                r.not_in_place = [m.to_json() for m in self.area_plan(self.map.blocks())]
                part_of_task = {b.id for b in initial if self.named(b)}     # their places: the plan's check
            r.disturbed = [b.to_json() for b in table_plan.displaced(
                [b for b in initial if b.id not in part_of_task], self.map.blocks(), moved, c.place_tolerance)
                if not self.still_there(b.shape, b.colour, 1, b.T_base_block, c.place_tolerance)]
            for block in r.disturbed:
                rospy.logwarn('table_task: the %s %s at (%.3f, %.3f) m was moved by accident'
                              % (block['colour'], block['shape'], *block['position_m'][:2]))
            if not r.not_in_place or self.task == 'stack' or round_ == ROUNDS:
                break
            rospy.logwarn('table_task: %d block(s) not at their place after the moves: one more round'
                          % len(r.not_in_place))
            self.run_areas()
        r.final_map = [b.to_json() for b in self.map.blocks()]

    def still_there(self, shape, colour, level, T_base_block, tolerance):
        """True if a look from its view pose sees the ``shape`` ``colour`` block on ``level`` within ``tolerance``
        (m, xy) of ``T_base_block``: a block the survey missed (at the edge of a view, behind a finger, on top of
        a tower, so nearer the camera than the table the views were planned for) is not taken for gone."""
        T_seen, _ = self.seen(self.look_from_view(T_base_block, 'the %s %s again' % (colour, shape)), shape, colour,
                              level, T_base_block[:2, 3])
        found = T_seen is not None and np.linalg.norm(T_seen[:2, 3] - T_base_block[:2, 3]) <= tolerance
        rospy.loginfo('table_task: the survey missed the %s %s on level %d at (%.3f, %.3f) m; a closer look %s'
                      % (colour, shape, level, *T_base_block[:2, 3], 'finds it there' if found else 'does not'))
        return found

    def tower_not_standing(self):
        """[] when the final map (or else a closer look) has the tower's top block on its level within
        ``stack_tolerance`` of where its step saw it, else [a description]."""
        if self.tower_top is None:
            return [{'detail': 'no tower was built'}]
        shape, colour, T_top = self.tower_top
        levels = len(self.options['order'])
        for block in self.map.blocks():
            level = table_plan.level_of(block.position[2], self.session.table.z_at(block.position[:2]),
                                        self.config.block_height, self.config.level_tolerance)
            if ((block.shape, block.colour) == (shape, colour) and level == levels
                    and np.linalg.norm(block.position[:2] - T_top[:2, 3]) <= self.config.stack_tolerance):
                return []
        if self.still_there(shape, colour, levels, T_top, self.config.stack_tolerance):
            return []
        return [{'detail': 'the %s %s is not seen on level %d at (%.3f, %.3f) m' % (colour, shape, levels,
                                                                                 *T_top[:2, 3])}]


# ==================================================================================== entry point
def parse_args(argv):
    common = argparse.ArgumentParser(add_help=False)
    common.add_argument('--mode', choices=pick.MODES, help='servo law of each pick')
    common.add_argument('--shape', help='only blocks of this shape (triangle, square, pentagon, hexagon)')
    common.add_argument('--side-length', type=float, help='block side (m)')
    common.add_argument('--start-pose', help='start pose name in config/start_poses.yaml (down, angled)')
    common.add_argument('--estimator', choices=['sqp', 'ippe', 'sqpnp'])
    cli.add_session_arguments(common, DEFAULT_CONFIG)
    parser = argparse.ArgumentParser(prog='table_task.py', description=command_summary(__doc__))
    tasks = parser.add_subparsers(dest='task', metavar='TASK', required=True)
    tasks.add_parser('survey', parents=[common], help='survey the table: print the map, write table_map.json')
    sort = tasks.add_parser('sort', parents=[common], help='every block of a named colour (and shape) to its bin')
    sort.add_argument('--bin', action='append', required=True, metavar='COLOUR:X,Y',
                      help="a colour's bin: its blocks go in a row starting at X,Y (base, m); repeat per colour")
    stack = tasks.add_parser('stack', parents=[common], help='a tower at X,Y, colours bottom first')
    stack.add_argument('--at', required=True, metavar='X,Y', help='where the tower stands (base, m)')
    stack.add_argument('--order', required=True, metavar='C1,C2,...', help='colours, bottom first')
    clear = tasks.add_parser('clear', parents=[common], help='every block to one area')
    clear.add_argument('--to', required=True, metavar='X,Y', help="the area's first place (base, m)")
    return parser.parse_args(argv)


TASK_KEYS = ('mode', 'side_length', 'start_pose', 'estimator')


def task_options(args, colour_names):
    """The subcommand's options: {'shape', 'bins' | 'at', 'order' | 'to'}; ParameterError / PlanError name a bad
    one."""
    from baxter_pnp.models import SHAPES
    if args.shape is not None and args.shape not in SHAPES:
        raise ParameterError('--shape', 'must be one of %s, got %r' % (', '.join(SHAPES), args.shape))
    options = {'shape': args.shape}
    if args.task == 'sort':
        options['bins'] = dict(table_plan.parse_bin(text) for text in args.bin)
        if len(options['bins']) != len(args.bin):
            raise ParameterError('--bin', 'one bin per colour')
        colours = list(options['bins'])
    elif args.task == 'stack':
        options['at'] = table_plan.parse_xy(args.at, '--at')
        options['order'] = colours = table_plan.parse_order(args.order)
    else:
        options['to'] = table_plan.parse_xy(args.to, '--to') if args.task == 'clear' else None
        colours = []
    unknown = [colour for colour in colours if colour not in colour_names]
    if unknown:
        raise ParameterError('colour', '%s not in the vision configuration (known: %s)'
                             % (', '.join(unknown), ', '.join(colour_names)))
    return options


def build_run(args):
    """(TableTaskConfig, SessionConfig, VisionConfig, options) of the command line; ParameterError or PlanError
    names a bad value."""
    config, session_config = cli.read_configs(TableTaskConfig, args, TASK_KEYS)
    vision_config = vision.VisionConfig.from_yaml(args.vision_config)
    return config, session_config, vision_config, task_options(args, vision_config.colour_names())


def main(argv=None):
    args, configs = cli.start('table_task', argv, parse_args, build_run)
    if configs is None:
        return 2
    config, session_config, vision_config, options = configs
    application = TableTaskApplication(args.task, options, config, session_config, vision_config, args.output_dir,
                                       args.result_json)
    started = time.monotonic()
    result = application.run()
    rospy.loginfo('table_task: wall time %.1f s' % (time.monotonic() - started))
    sys.stdout.flush()
    return 0 if result.success else 1
