"""baxter_pnp: vision-guided pick and place for the Baxter robot, with a PyBullet fake Baxter.

Layout (feature -> task -> robot, as in ViSP):

- ``camera``, ``calibration``: camera model (intrinsics, plumb-bob distortion) and chessboard calibration.
- ``vision``: the thesis's colour pipeline, image in -> polygon vertices out.
- ``models``, ``pose``: object models and the model-based (SQP) and OpenCV pose estimators.
- ``servo``: visual-servo laws (PBVS look-and-move, IBVS, 2.5D), pose in -> next arm target out.
- ``robot``: thin clients of the Baxter SDK's topics and services (limb, gripper, camera).
- ``sim``: the fake Baxter (PyBullet) that serves the robot's ROS interfaces.

This ``__init__`` imports nothing heavy, so that scripts can find the project's virtual
environment (``baxter_pnp.runtime``) before numpy, OpenCV or rospy are imported.
"""
