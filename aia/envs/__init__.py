"""The batched target-tracking environment, its maps and its configuration.

The names that compose the env with its transforms (``make_env`` and the rest of :mod:`aia.envs.factory`,
:class:`TrackingTransformedEnv`) load on first use: :mod:`aia.transforms` builds on this package's modules, so
importing them here would make ``import aia.transforms`` before ``import aia.envs`` a circular import.
"""

from importlib import import_module
from typing import TYPE_CHECKING

from aia.envs.config import TrackingConfig
from aia.envs.maps import GridMap, available_maps, load_map
from aia.envs.tracking import TargetTrackingEnv

if TYPE_CHECKING:
    from aia.envs.factory import available_settings, load_env_config, make_env, make_transforms
    from aia.envs.transformed import TrackingTransformedEnv

_COMPOSING = {"available_settings": "aia.envs.factory", "load_env_config": "aia.envs.factory",
              "make_env": "aia.envs.factory", "make_transforms": "aia.envs.factory",
              "TrackingTransformedEnv": "aia.envs.transformed"}


def __getattr__(name: str):
    """The composing names of ``__all__``, imported when first asked for."""
    if name in _COMPOSING:
        return getattr(import_module(_COMPOSING[name]), name)
    raise AttributeError(f"module 'aia.envs' has no attribute {name!r}")


__all__ = [
    "GridMap",
    "TargetTrackingEnv",
    "TrackingConfig",
    "TrackingTransformedEnv",
    "available_maps",
    "available_settings",
    "load_env_config",
    "load_map",
    "make_env",
    "make_transforms",
]
