"""Run logs: the MCAP logger, the episode recorder, Foxglove scenes, and reading logs back.

Reading needs no torch: the writers (``MCAPLogger``, ``SceneRecorder``) are imported on first use, so that a
reader of logs (``aia-log``) starts without loading torch and TorchRL: ``aia-log summary`` of a run log took
0.21-0.24 s against 4.0-4.2 s when this package imported them (2026-12-04, the 2-core VM).
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING

from aia.logging.reader import RunLog, RunLogError, find_runs, read_run

if TYPE_CHECKING:
    from aia.logging.mcap_logger import MCAPLogger
    from aia.logging.recorder import SceneRecorder

_WRITERS = {"MCAPLogger": "aia.logging.mcap_logger", "SceneRecorder": "aia.logging.recorder"}

__all__ = ["MCAPLogger", "RunLog", "RunLogError", "SceneRecorder", "find_runs", "read_run"]


def __getattr__(name: str) -> object:
    """The writers, imported when first asked for (they import torch)."""
    if name in _WRITERS:
        return getattr(importlib.import_module(_WRITERS[name]), name)
    raise AttributeError(f"module 'aia.logging' has no attribute {name!r}")
