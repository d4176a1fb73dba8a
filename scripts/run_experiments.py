#!/usr/bin/python3
"""Reproduce the thesis's chapter 5 experiments (depth, reach) on the fake Baxter (see docs/experiments.md)."""
from baxter_pnp.runtime import use_project_venv
use_project_venv(__file__)

import sys  # noqa: E402

from baxter_pnp.experiments import main  # noqa: E402

sys.exit(main())
