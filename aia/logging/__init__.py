"""Run logs: the MCAP logger, the episode recorder, Foxglove scenes, and reading logs back."""

from aia.logging.mcap_logger import MCAPLogger
from aia.logging.reader import RunLog, RunLogError, find_runs, read_run
from aia.logging.recorder import SceneRecorder

__all__ = ["MCAPLogger", "RunLog", "RunLogError", "SceneRecorder", "find_runs", "read_run"]
