"""Where a run resumes from, and whether its checkpoint is one it may continue.

``resume=<path>`` continues from that checkpoint; ``resume=auto`` from the newest undamaged checkpoint in the
run's own folder (``checkpoints/last.pt``, else ``checkpoints/previous.pt``, saying why) if there is one, else
the run starts fresh (what a requeued cluster job needs: the same command in the same folder); without
``resume``, a folder that holds a run already is refused (its checkpoint and log are kept). A checkpoint
whose records fail their CRC-32 check (:func:`~aia.training.checkpoint_files.checkpoint_damage`) is refused. A
checkpoint of a run that differs in a setting that shapes what is learned (:data:`RESUME_KEYS`, the fields of
:class:`~aia.config.schemas.TrainConfig` declared ``resume``: the env, the algorithm, the network, the
exploration, the seed, the worlds and the replay) is refused, naming every differing key with both values;
budgets (``frames``), logging and compile switches may change. A setting added to aia after the checkpoint was
written matches when the run leaves it at its default, so that a run continues across versions of the code.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass
from pathlib import Path

import torch
from omegaconf import DictConfig, OmegaConf

from aia.config.composing import compose_config
from aia.config.errors import ConfigError
from aia.config.schemas import TrainConfig, keys_where
from aia.training.checkpoint_files import checkpoint_damage
from aia.training.checkpoint_names import CHECKPOINT_NAME, PREVIOUS_CHECKPOINT_NAME
from aia.training.members import flat_settings

RESUME_KEYS = keys_where(TrainConfig, "resume")


@dataclass(frozen=True)
class ResumeSource:
    """The checkpoint a run continues from, and the newer one ``resume=auto`` passed over as damaged (a line
    saying so), if any."""

    path: Path
    passed_over: str | None = None


def resume_path(cfg: DictConfig, out_dir: Path) -> ResumeSource | None:
    """The checkpoint this run continues from, or None for a fresh start; refused with a :class:`ConfigError`:
    ``resume=auto`` with no undamaged checkpoint in the folder (but a damaged one), and a fresh start
    (``resume=null``) in a folder that holds a run (a checkpoint or the run log), whose checkpoint it would
    replace and whose log's history it would hide behind its own."""
    if "resume" not in cfg:  # not a training run's config (the population launcher groups aia-eval's jobs too)
        return None
    resume = cfg.resume
    if resume is None:
        log = cfg.logger.get("file")
        held = [path for path in (out_dir / CHECKPOINT_NAME, out_dir / PREVIOUS_CHECKPOINT_NAME,
                                  out_dir / str(log) if log else None) if path is not None and path.exists()]
        if held:
            raise ConfigError("resume", None, f"auto to continue the run in {out_dir} ({held[0]} is there), or "
                              "another run folder (hydra.run.dir) for a fresh run: it would replace that run's "
                              "checkpoint and hide its log")
        return None
    if str(resume) != "auto":
        return ResumeSource(Path(str(resume)))
    damaged: list[str] = []
    for path in (out_dir / CHECKPOINT_NAME, out_dir / PREVIOUS_CHECKPOINT_NAME):
        if not path.is_file():
            continue
        problem = checkpoint_damage(path)
        if problem is None:
            return ResumeSource(path, f"{'; '.join(damaged)}: resuming from the checkpoint before it, {path}"
                                if damaged else None)
        damaged.append(f"{path} is damaged: {problem}")
    if damaged:
        raise ConfigError("resume", "auto", f"an undamaged checkpoint in the run folder, but {'; '.join(damaged)} "
                          f"(move {out_dir / 'checkpoints'} away to start afresh)")
    return None


def checkpoint_point(checkpoint: dict) -> tuple[int, int, int, int]:
    """Where a checkpoint's run stands: its frames, updates, episodes and evaluations (the members of a resumed
    population must all stand at one point)."""
    state = checkpoint["state"]
    return state["frames"], state["updates"], state["episodes"], state["evaluations"]


def resume_point(cfg: DictConfig, out_dir: Path) -> tuple[int, int, int, int] | str | None:
    """Where this run continues from, to group runs into populations: its checkpoint's :func:`checkpoint_point`,
    ``None`` for a fresh start, or the path of a checkpoint it cannot read or may not start over (that run then
    fails alone, with :func:`resume_path`'s or :func:`load_resumable`'s line). Reads only the checkpoint's
    counters (its tensors are mapped, not loaded)."""
    try:
        source = resume_path(cfg, out_dir)
    except ConfigError:  # resume=auto and only damaged checkpoints, or a fresh start over a run
        return str(out_dir / CHECKPOINT_NAME)
    if source is None:
        return None
    if checkpoint_damage(source.path) is not None:
        return str(source.path)
    try:
        return checkpoint_point(torch.load(source.path, weights_only=False, map_location="cpu", mmap=True))
    except Exception:  # unreadable, or not a checkpoint of aia-train
        return str(source.path)


def load_resumable(path: Path, cfg: DictConfig, map_location: str) -> dict:
    """The checkpoint at ``path``, refused with one line if it is damaged, unreadable or from an incompatible
    run."""
    problem = checkpoint_damage(path)
    if problem is not None:
        previous = path.parent / Path(PREVIOUS_CHECKPOINT_NAME).name
        fallback = f"resume={previous} (the one before)" if previous != path and previous.is_file() else None
        raise ConfigError("resume", str(path), f"an undamaged checkpoint, but {problem}: continue from "
                          f"{fallback or 'another checkpoint'} or start afresh")
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
                   for key in keys if saved.get(key) != now.get(key) and not _introduced_at_default(key, saved, now)]
    if differences:
        raise ConfigError("resume", str(path), "a checkpoint of the same run; it differs in "
                          + ", ".join(differences))
    return checkpoint


def _introduced_at_default(key: str, saved: dict[str, object], now: dict[str, object]) -> bool:
    """Whether ``key`` is a setting added after the checkpoint was written (absent from its config) that this run
    leaves at its default, the behaviour the code had before the setting existed (a new setting's default keeps
    the old behaviour: e.g. ``env.features.local_map=none``)."""
    if key in saved or key not in now:
        return False
    default = _default_settings().get(key, _NO_DEFAULT)
    return default is not _NO_DEFAULT and default == now[key]


_NO_DEFAULT = object()


@functools.cache
def _default_settings() -> dict[str, object]:
    """``{"dotted.key": default}`` of ``aia-train``'s config: conf/train.yaml as composed without overrides, the
    env's keys from the env schema (:class:`~aia.envs.config.TrackingConfig`) rather than the default preset."""
    from aia.envs.config import TrackingConfig

    defaults = {k: v for k, v in flat_settings(compose_config("train")).items() if not k.startswith("env.")}
    env = flat_settings(OmegaConf.structured(TrackingConfig))
    return defaults | {f"env.{key}": value for key, value in env.items()}


def _resume_key(key: str) -> int | None:
    """The position in :data:`RESUME_KEYS` of the entry that dotted ``key`` is (or lies under), else None."""
    return next((i for i, root in enumerate(RESUME_KEYS) if key == root or key.startswith(root + ".")), None)
