#!/usr/bin/python3
"""Tasks with every block on the table: survey, sort, stack, clear (see baxter_pnp.table_task_app)."""
import os
import sys

sys.path.insert(0, os.path.join(os.path.dirname(os.path.realpath(__file__)), os.pardir, 'src'))  # a checkout
from baxter_pnp.runtime import use_project_venv  # noqa: E402
use_project_venv(__file__)

from baxter_pnp.table_task_app import main  # noqa: E402

sys.exit(main())
