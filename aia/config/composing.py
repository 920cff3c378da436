"""Composing a config of ``pkg://aia.conf`` from code, inside a running Hydra app or outside one."""

from __future__ import annotations

from collections.abc import Sequence
from contextlib import nullcontext

from hydra import compose, initialize_config_module
from hydra.core.global_hydra import GlobalHydra
from omegaconf import DictConfig


def compose_config(config_name: str, overrides: Sequence[str] = ()) -> DictConfig:
    """``config_name`` (``conf/<name>.yaml``) composed with Hydra-style ``overrides``: in the running app's Hydra
    when there is one (an app's job), else in a Hydra context of its own. Hydra's and OmegaConf's errors pass
    through to the caller."""
    context = (nullcontext() if GlobalHydra.instance().is_initialized()
               else initialize_config_module(config_module="aia.conf", version_base="1.3"))
    with context:
        return compose(config_name=config_name, overrides=list(overrides))
