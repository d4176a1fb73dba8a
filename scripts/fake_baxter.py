#!/usr/bin/python3
"""Fake Baxter ROS node (PyBullet) serving the robot's SDK topics and services; see docs/fake_baxter.md."""
import os
import sys

sys.path.insert(0, os.path.join(os.path.dirname(os.path.realpath(__file__)), os.pardir, 'src'))  # a checkout
from baxter_pnp.runtime import use_project_venv  # noqa: E402
use_project_venv(__file__)

from baxter_pnp.sim.node import main  # noqa: E402

main()
