"""Session-wide settings of the test run.

The suite runs in two pytest-xdist workers (``-n 2`` in pyproject's ``addopts``) on the 2-core machine: each
worker, and every process a test starts, computes on one thread, so the two workers do not contend for the
cores (two workers at two threads each were slower than one worker).
"""

from __future__ import annotations

import os

import torch

if os.environ.get("PYTEST_XDIST_WORKER"):
    os.environ["OMP_NUM_THREADS"] = "1"  # inherited by the apps' subprocesses
    torch.set_num_threads(1)
