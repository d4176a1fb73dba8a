"""The task layer every task composes (pick, and the ones to come: survey, sort, stack, calibrate).

- ``settings``: ``SessionConfig`` (arm, camera mode, table, timeouts, outputs) and ``load_configs`` (defaults <-
  YAML <- ``~private`` ROS parameters <- command line, into the task's config and the session's);
- ``session``: ``RobotSession`` (connect, check the robot, e-stop, wait for a restarted robot and resume, the
  run's clock), ``TaskFailure`` and ``failure_reason``;
- ``motion``: ``Motion`` (the gripper to a pose through IK, straight Cartesian paths, safety-checked joint
  moves, retreat after a failure);
- ``eye``: ``Eye`` (a look: frame + endpoint pose at its stamp + hand-eye -> blocks in ``base``; debug image,
  target pose, tf ``block``; what the fingers hide);
- ``target``: pure rules of which observation is the block (``choose_target``), re-centre and search poses;
- ``outputs``: result JSON, output files, plots.

ROS lives in session, motion, eye and outputs; ``settings`` and ``target`` are pure. docs/ARCHITECTURE.md,
"Adding a task", shows a task composed of these in a few lines.
"""
