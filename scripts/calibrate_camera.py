#!/usr/bin/python3
"""Calibrate a camera from chessboard images and write its YAML (see baxter_pnp.calibration)."""
from baxter_pnp.runtime import use_project_venv
use_project_venv(__file__)

import sys  # noqa: E402

from baxter_pnp.calibration import main  # noqa: E402

sys.exit(main())
