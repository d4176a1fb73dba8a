#!/usr/bin/python3
"""Detect coloured blocks in image files and print their 3D pose (see baxter_pnp.detect_cli)."""
from baxter_pnp.runtime import use_project_venv
use_project_venv(__file__)

import sys  # noqa: E402

from baxter_pnp.detect_cli import main  # noqa: E402

sys.exit(main())
