#!/usr/bin/python3
"""Vision-guided pick (and place) of a coloured block with Baxter's hand camera (see baxter_pnp.application)."""
from baxter_pnp.runtime import use_project_venv
use_project_venv(__file__)

import sys  # noqa: E402

from baxter_pnp.application import main  # noqa: E402

sys.exit(main())
