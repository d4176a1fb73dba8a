#!/usr/bin/python3
"""Detect coloured blocks in image files and recorded runs (rosbags) and print their 3D pose (see
baxter_pnp.detect_cli; replaying a bag: docs/perception.md)."""
import os
import sys

sys.path.insert(0, os.path.join(os.path.dirname(os.path.realpath(__file__)), os.pardir, 'src'))  # a checkout
from baxter_pnp.runtime import use_project_venv  # noqa: E402
use_project_venv(__file__)

from baxter_pnp.detect_cli import main  # noqa: E402

sys.exit(main())
