"""A checkpoint as ``aia-eval`` plays it: verified and read once per state of its file, and the guard that a setting's
observation has the layout the checkpoint's network was trained on (the same belief features and map image, on
any map). torch loads inside the functions: the app imports this module before its config is valid."""

from __future__ import annotations

import functools
from pathlib import Path

from omegaconf import DictConfig, OmegaConf

from aia.config.errors import ConfigError, one_line
from aia.config.validation import check_checkpoint_file
from aia.envs.config import to_tracking_config


def load_checkpoint(path: str | Path) -> dict:
    """A checkpoint written by ``aia-train``, or a :class:`ConfigError` (a ValueError) naming the path and what is
    wrong: missing, damaged (:func:`~aia.training.checkpoint_files.checkpoint_damage`), unreadable or foreign.
    Checked and read once per state of the file (its size and modification time): the validation, the layout
    guard and the evaluation each ask for it. Callers must not change what it returns."""
    path = Path(path)
    if not path.is_file():
        check_checkpoint_file("checkpoint", path)  # its one line
    stat = path.stat()
    return _read_checkpoint(path, stat.st_mtime_ns, stat.st_size)


@functools.lru_cache(maxsize=1)
def _read_checkpoint(path: Path, mtime_ns: int, size: int) -> dict:
    """:func:`load_checkpoint` of the file at ``path`` in the state ``(mtime_ns, size)``."""
    check_checkpoint_file("checkpoint", path)
    import torch

    try:
        checkpoint = torch.load(path, weights_only=False, map_location="cpu")
    except Exception as err:  # torch raises several types for a file that is not a checkpoint
        raise ConfigError("checkpoint", str(path), f"a readable torch checkpoint ({one_line(err)})") from None
    if not isinstance(checkpoint, dict) or not {"config", "actor"} <= checkpoint.keys():
        raise ConfigError("checkpoint", str(path), "a checkpoint written by aia-train (no 'config'/'actor' entries)")
    return checkpoint


def check_setting(path: str | Path, setting: DictConfig) -> None:
    """Refuse, with one line naming both layouts, to evaluate the checkpoint at ``path`` in ``setting`` (an env
    config) if its observation's layout differs from the setting the checkpoint was trained in."""
    trained = OmegaConf.create(load_checkpoint(path)["config"]).env
    check_layout(path, setting, trained)


def _layout(setting: DictConfig) -> str:
    """The observation layout of ``setting``'s env (:func:`~aia.training.components.observation_layout`)."""
    return _layout_of(OmegaConf.to_yaml(setting, resolve=True))


@functools.cache
def _layout_of(setting: str) -> str:
    """:func:`_layout` of a setting's YAML, from a one-world env built once per setting: a population's jobs
    and the evaluation's own guard then ask again for free."""
    from aia.envs import make_env
    from aia.training.components import observation_layout

    return observation_layout(make_env(to_tracking_config(OmegaConf.create(setting)), batch_size=1).observation_spec)


# the env keys that shape the observation, named first when a setting's layout differs from a checkpoint's
_LAYOUT_KEYS = ("num_targets", "features.local_map", "features.im_size", "features.relative_velocity", "target.model")


def check_layout(path: str | Path, setting: DictConfig, trained: DictConfig) -> None:
    """A :class:`ConfigError` on ``env`` unless ``setting``'s observation layout is that of ``trained`` (the
    checkpoint's env), naming the layouts and the keys in which the settings differ (those that shape the
    observation first, three at most)."""
    layout, expected = _layout(setting), _layout(trained)
    if layout == expected:
        return
    from aia.training.members import flat_settings

    ours, theirs = (flat_settings(OmegaConf.structured(to_tracking_config(s))) for s in (setting, trained))
    rank = {key: i for i, key in enumerate(_LAYOUT_KEYS)}
    differing = sorted((key for key in ours if ours[key] != theirs.get(key)),
                       key=lambda key: (rank.get(key, len(rank)), key))
    named = ", ".join(f"env.{key}={ours[key]!r} ({theirs.get(key)!r} there)" for key in differing[:3])
    more = f" and {len(differing) - 3} more" if len(differing) > 3 else ""
    raise ConfigError("env", layout, f"the observation layout of the setting {path} was trained in, {expected} (the "
                      f"same belief features and map image; the map itself may differ); this setting differs from "
                      f"it in {named}{more}")
