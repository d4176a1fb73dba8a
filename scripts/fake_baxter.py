#!/usr/bin/python3
"""Fake Baxter ROS node (PyBullet) serving the robot's SDK topics and services; see docs/fake_baxter.md."""
from baxter_pnp.runtime import use_project_venv
use_project_venv(__file__)

from baxter_pnp.sim.node import main  # noqa: E402

main()
