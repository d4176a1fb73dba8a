#!/usr/bin/python3
"""rviz on a headless X server after a table survey on the fake Baxter, saved as docs/images/rviz.png."""
import os
import sys

sys.path.insert(0, os.path.join(os.path.dirname(os.path.realpath(__file__)), os.pardir, 'src'))  # a checkout
from baxter_pnp.runtime import use_project_venv  # noqa: E402
use_project_venv(__file__)

from baxter_pnp.bench.rviz_screenshot import main  # noqa: E402

sys.exit(main())
