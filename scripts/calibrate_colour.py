#!/usr/bin/python3
"""Learn a colour class from a view of one block (see baxter_pnp.colour_calibration)."""
import os
import sys

sys.path.insert(0, os.path.join(os.path.dirname(os.path.realpath(__file__)), os.pardir, 'src'))  # a checkout
from baxter_pnp.runtime import use_project_venv  # noqa: E402
use_project_venv(__file__)

from baxter_pnp.colour_calibration import main  # noqa: E402

sys.exit(main())
