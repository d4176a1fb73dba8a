"""The fake Baxter: ``scene`` (scene YAML), ``world`` (PyBullet world, no ROS), ``gripper`` (end-effector
protocol state machine) and ``node`` (the ROS node). Import the submodules explicitly."""
