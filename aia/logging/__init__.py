"""Run logs: the MCAP logger, the episode recorder, Foxglove scenes, and reading logs back.

Reading needs no torch: the writers (``MCAPLogger``, ``SceneRecorder``) are imported on first use, so that a
reader of logs (``aia-log``) starts without loading torch and TorchRL: ``aia-log summary`` of a run log took
0.21-0.24 s against 4.0-4.2 s when this package imported them (2026-12-04, the 2-core VM).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from aia.logging.reader import RunLog, RunLogError, find_runs, read_run
from aia.runtime.lazy import lazy_names

if TYPE_CHECKING:
    from aia.logging.mcap_logger import MCAPLogger
    from aia.logging.recorder import SceneRecorder

# the writers import torch
__getattr__ = lazy_names(__name__, {"MCAPLogger": "aia.logging.mcap_logger", "SceneRecorder": "aia.logging.recorder"})

__all__ = ["MCAPLogger", "RunLog", "RunLogError", "SceneRecorder", "find_runs", "read_run"]
