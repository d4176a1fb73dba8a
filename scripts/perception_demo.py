#!/usr/bin/python3
"""Perception demo: render hand-camera views, detect the blocks, print pose estimates beside the truth."""
from baxter_pnp.runtime import use_project_venv
use_project_venv(__file__)

import sys  # noqa: E402

from baxter_pnp.perception_demo import main  # noqa: E402

sys.exit(main())
