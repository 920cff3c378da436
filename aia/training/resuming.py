"""Where a run resumes from, and whether its checkpoint is one it may continue.

``resume=<path>`` continues from that checkpoint; ``resume=auto`` from the newest checkpoint in the run's own
folder if there is one, else the run starts fresh (what a requeued cluster job needs: the same command in the
same folder). A checkpoint of a run that differs in a setting that shapes what is learned (:data:`RESUME_KEYS`:
the env, the algorithm, the network, the exploration, the seed, the worlds and the replay) is refused, naming
every differing key with both values; budgets (``frames``), logging and compile switches may change.
"""

from __future__ import annotations

from pathlib import Path

import torch
from omegaconf import DictConfig, OmegaConf

from aia.errors import ConfigError
from aia.training.checkpoint import CHECKPOINT_NAME
from aia.training.members import flat_settings

RESUME_KEYS = ("env", "algo", "exploration.name", "hidden", "seed", "collector.num_envs", "buffer_size",
               "batch_size", "gamma", "target_update_interval", "warmup_frames", "updates_per_frame")


def resume_path(cfg: DictConfig, out_dir: Path) -> Path | None:
    """The checkpoint this run continues from, or None for a fresh start."""
    resume = cfg.get("resume")
    if resume is None:
        return None
    if str(resume) == "auto":
        newest = out_dir / CHECKPOINT_NAME
        return newest if newest.is_file() else None
    return Path(str(resume))


def checkpoint_point(checkpoint: dict) -> tuple[int, int, int, int]:
    """Where a checkpoint's run stands: its frames, updates, episodes and evaluations (the members of a resumed
    population must all stand at one point)."""
    state = checkpoint["state"]
    return state["frames"], state["updates"], state["episodes"], state["evaluations"]


def resume_point(cfg: DictConfig, out_dir: Path) -> tuple[int, int, int, int] | str | None:
    """Where this run continues from, to group runs into populations: its checkpoint's :func:`checkpoint_point`,
    ``None`` for a fresh start, or the path of a checkpoint it cannot read (that run then fails alone, with
    :func:`load_resumable`'s line). Reads only the checkpoint's counters (its tensors are mapped, not loaded)."""
    path = resume_path(cfg, out_dir)
    if path is None:
        return None
    try:
        return checkpoint_point(torch.load(path, weights_only=False, map_location="cpu", mmap=True))
    except Exception:  # unreadable, or not a checkpoint of aia-train
        return str(path)


def load_resumable(path: Path, cfg: DictConfig, map_location: str) -> dict:
    """The checkpoint at ``path``, refused with one line if it is unreadable or from an incompatible run."""
    try:
        checkpoint = torch.load(path, weights_only=False, map_location=map_location)
    except Exception as err:  # torch raises several types for a missing or foreign file
        raise ConfigError("resume", str(path), f"a readable aia-train checkpoint ({type(err).__name__})") from None
    if not isinstance(checkpoint, dict) or not {"config", "online", "state"} <= checkpoint.keys():
        raise ConfigError("resume", str(path), "a checkpoint written by aia-train (no 'config'/'online'/'state')")
    saved, now = flat_settings(OmegaConf.create(checkpoint["config"])), flat_settings(cfg)
    keys = sorted((k for k in saved.keys() | now.keys() if _resume_key(k) is not None),
                  key=lambda k: (_resume_key(k), k))
    differences = [f"{key} ({saved.get(key)!r} in the checkpoint, {now.get(key)!r} now)"
                   for key in keys if saved.get(key) != now.get(key)]
    if differences:
        raise ConfigError("resume", str(path), "a checkpoint of the same run; it differs in "
                          + ", ".join(differences))
    return checkpoint


def _resume_key(key: str) -> int | None:
    """The position in :data:`RESUME_KEYS` of the entry that dotted ``key`` is (or lies under), else None."""
    return next((i for i, root in enumerate(RESUME_KEYS) if key == root or key.startswith(root + ".")), None)
