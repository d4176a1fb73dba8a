#!/usr/bin/python3
"""Perception benchmark: detection rate, vertex, pose, depth and orientation error and time per frame, per estimator,
on the project renderer's datasets and on an independent renderer's (``--datasets``)."""
import os
import sys

os.environ.setdefault('OMP_NUM_THREADS', '1')  # timing on one core, before numpy is imported (OpenBLAS: runtime)
sys.path.insert(0, os.path.join(os.path.dirname(os.path.realpath(__file__)), os.pardir, 'src'))  # a checkout
from baxter_pnp.runtime import use_project_venv  # noqa: E402
use_project_venv(__file__)

from baxter_pnp.bench.perception_bench import main  # noqa: E402

sys.exit(main())
