"""What a sweep's launcher reads of training: the population launcher's one entry into :mod:`aia.training`.

``hydra_plugins/aia_population_launcher`` groups a sweep's jobs into populations, orders them, resumes SLURM
tasks and stops its workers with these, and imports nothing else of :mod:`aia.training` (it imports this module
on first use: Hydra's plugin scan imports the launcher for every app's start).
"""

from __future__ import annotations

from pathlib import Path

from aia.runtime.stopping import StopOnSignals, interrupting
from aia.training.checkpoint_names import CHECKPOINT_NAME, PREVIOUS_CHECKPOINT_NAME
from aia.training.members import first_difference, population_signature, population_work
from aia.training.progress import forwarding
from aia.training.resuming import resume_point

__all__ = ["StopOnSignals", "first_difference", "forwarding", "has_checkpoint", "interrupting", "population_signature",
           "population_work", "resume_point"]


def has_checkpoint(out_dir: str | Path) -> bool:
    """Whether a job's folder holds a checkpoint (``last.pt`` or ``previous.pt``): a run of it with
    ``resume=auto`` continues from there."""
    return any((Path(out_dir) / name).is_file() for name in (CHECKPOINT_NAME, PREVIOUS_CHECKPOINT_NAME))
