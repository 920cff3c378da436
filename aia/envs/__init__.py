"""The batched target-tracking environment, its maps and its configuration.

Every name loads on first use: :mod:`aia.transforms` builds on this package's modules (importing the composing
names, ``make_env`` and the rest of :mod:`aia.envs.factory`, here would make ``import aia.transforms`` before
``import aia.envs`` a circular import), and the apps read the env's schema (:mod:`aia.envs.config`) without
loading torch, so that their ``--help`` and their refusals answer in about a second.
"""

from typing import TYPE_CHECKING

from aia.runtime.lazy import lazy_names

if TYPE_CHECKING:
    from aia.envs.config import TrackingConfig
    from aia.envs.factory import available_settings, load_env_config, make_env, make_transforms
    from aia.envs.maps import GridMap, available_maps, load_map
    from aia.envs.tracking import TargetTrackingEnv
    from aia.envs.transformed import TrackingTransformedEnv

__getattr__ = lazy_names(__name__, {
    "TrackingConfig": "aia.envs.config", "GridMap": "aia.envs.maps", "available_maps": "aia.envs.maps",
    "load_map": "aia.envs.maps", "TargetTrackingEnv": "aia.envs.tracking", "available_settings": "aia.envs.factory",
    "load_env_config": "aia.envs.factory", "make_env": "aia.envs.factory", "make_transforms": "aia.envs.factory",
    "TrackingTransformedEnv": "aia.envs.transformed"})

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
