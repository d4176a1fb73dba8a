#!/usr/bin/python3
"""Batch pick trials on the fake Baxter: random scenes, every mode, ground-truth scores (see docs/trials.md)."""
import os
import sys

sys.path.insert(0, os.path.join(os.path.dirname(os.path.realpath(__file__)), os.pardir, 'src'))  # a checkout
from baxter_pnp.runtime import use_project_venv  # noqa: E402
use_project_venv(__file__)

from baxter_pnp.bench.trials import main  # noqa: E402

sys.exit(main())
