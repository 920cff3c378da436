"""The batched target-tracking environment, its maps and its configuration."""

from aia.envs.config import TrackingConfig
from aia.envs.factory import available_settings, load_env_config, make_env, make_transforms
from aia.envs.maps import GridMap, available_maps, load_map
from aia.envs.tracking import TargetTrackingEnv
from aia.envs.transformed import TrackingTransformedEnv

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
