#!/usr/bin/python3
"""The whole system headless: rosmaster, fake Baxter and pick_square.py on the default scene."""
import os
import sys

sys.path.insert(0, os.path.join(os.path.dirname(os.path.realpath(__file__)), os.pardir, 'src'))  # a checkout
from baxter_pnp.runtime import use_project_venv  # noqa: E402
use_project_venv(__file__)

from baxter_pnp.bench.demo import main  # noqa: E402

sys.exit(main())
