#!/usr/bin/python3
"""Real and rendered hand-camera frames side by side: the statistics the fake's appearance is matched on."""
import os
import sys

sys.path.insert(0, os.path.join(os.path.dirname(os.path.realpath(__file__)), os.pardir, 'src'))  # a checkout
from baxter_pnp.runtime import use_project_venv  # noqa: E402
use_project_venv(__file__)

from baxter_pnp.bench.appearance_stats import main  # noqa: E402

sys.exit(main())
