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


def load_resumable(path: Path, cfg: DictConfig, map_location: str) -> dict:
    """The checkpoint at ``path``, refused with one line if it is unreadable or from an incompatible run."""
    try:
        checkpoint = torch.load(path, weights_only=False, map_location=map_location)
    except Exception as err:  # torch raises several types for a missing or foreign file
        raise ConfigError("resume", str(path), f"a readable aia-train checkpoint ({type(err).__name__})") from None
    if not isinstance(checkpoint, dict) or not {"config", "online", "state"} <= checkpoint.keys():
        raise ConfigError("resume", str(path), "a checkpoint written by aia-train (no 'config'/'online'/'state')")
    saved = OmegaConf.create(checkpoint["config"])
    differences = [f"{key} ({_get(saved, key)!r} in the checkpoint, {_get(cfg, key)!r} now)"
                   for key in _leaves(saved, cfg) if _get(saved, key) != _get(cfg, key)]
    if differences:
        raise ConfigError("resume", str(path), "a checkpoint of the same run; it differs in "
                          + ", ".join(differences))
    return checkpoint


def _leaves(a: DictConfig, b: DictConfig) -> list[str]:
    """The dotted keys under :data:`RESUME_KEYS` in either config."""
    keys = []
    for key in RESUME_KEYS:
        for cfg in (a, b):
            node = OmegaConf.select(cfg, key)
            if isinstance(node, DictConfig):
                keys += [f"{key}.{leaf}" for leaf in _flatten(OmegaConf.to_container(node, resolve=True))]
            else:
                keys.append(key)
    return list(dict.fromkeys(keys))


def _flatten(node: dict, prefix: str = "") -> list[str]:
    out = []
    for key, value in node.items():
        out += _flatten(value, f"{prefix}{key}.") if isinstance(value, dict) else [f"{prefix}{key}"]
    return out


def _get(cfg: DictConfig, key: str) -> object:
    value = OmegaConf.select(cfg, key)
    return OmegaConf.to_container(value, resolve=True) if OmegaConf.is_config(value) else value
