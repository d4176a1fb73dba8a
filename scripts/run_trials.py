#!/usr/bin/python3
"""Batch pick trials on the fake Baxter: random scenes, every mode, ground-truth scores (see docs/trials.md)."""
from baxter_pnp.runtime import use_project_venv
use_project_venv(__file__)

import sys  # noqa: E402

from baxter_pnp.trials import main  # noqa: E402

sys.exit(main())
