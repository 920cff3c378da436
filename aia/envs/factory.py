"""Build tracking envs from the Hydra presets in ``conf/env/`` (or from a config object)."""

from __future__ import annotations

from collections.abc import Sequence
from importlib import resources
from pathlib import Path

import torch
from hydra.errors import HydraException
from omegaconf import DictConfig
from omegaconf.errors import OmegaConfBaseException
from torchrl.envs import Compose

from aia.config.checks import check_choice
from aia.config.composing import compose_config, composition_error
from aia.config.errors import ConfigError, one_line
from aia.config.schemas import SCHEMAS
from aia.envs.config import TrackingConfig, to_tracking_config
from aia.envs.sensing import Geometry
from aia.envs.tracking import TargetTrackingEnv
from aia.envs.transformed import TrackingTransformedEnv
from aia.transforms import BeliefFeatures, InfoReward, LocalMap


def available_settings() -> list[str]:
    """Names of the env presets in ``conf/env/`` (the four paper settings and their ``_2019`` twins)."""
    folder = Path(str(resources.files("aia.conf") / "env"))
    return sorted(p.stem for p in folder.glob("*.yaml"))


def load_env_config(setting: str = "empty1", overrides: Sequence[str] = ()) -> TrackingConfig:
    """Compose the preset ``setting`` with Hydra-style ``overrides`` of its fields (``"sensor.range=12"``, or as
    the apps write them, ``"env.sensor.range=12"``) into a config; a key the env does not have, or a value of the
    wrong type, is a :class:`~aia.config.errors.ConfigError` naming it."""
    check_choice("env", setting, available_settings())
    hydra_overrides = [f"env={setting}", *(f"env.{o.removeprefix('env.')}" for o in overrides)]
    try:
        cfg = compose_config("env_setting", hydra_overrides)
    except (HydraException, OmegaConfBaseException) as err:
        error = composition_error(err, SCHEMAS["env_setting"])
        raise error or ConfigError("overrides", list(overrides), f"overrides of env fields ({one_line(err)})") from None
    return to_tracking_config(cfg.env)


def make_transforms(config: TrackingConfig, compile: bool = False, geometry: Geometry | None = None) -> Compose:
    """The feature and reward transforms of a setting (SPEC 6 and 7), and the map image (``features.local_map``)
    around the robot read from the env's ``geometry``."""
    transforms = [BeliefFeatures(config.features.relative_velocity, compile=compile)]
    if config.features.local_map != "none":
        if geometry is None:
            raise ValueError(f"features.local_map={config.features.local_map!r} needs the env's geometry")
        transforms.append(LocalMap(geometry, config.features.local_map, config.features.im_size, config.dt,
                                   config.sensor.obstacle_ray_spacing, compile=compile))
    return Compose(*transforms, InfoReward(config.reward, compile=compile))


def make_env(
    setting: str | TrackingConfig | DictConfig = "empty1",
    batch_size: int = 1,
    device: torch.device | str = "cpu",
    seed: int | None = None,
    overrides: Sequence[str] = (),
    transforms: bool = True,
    validate_actions: bool = True,
    compile: bool = False,
) -> TrackingTransformedEnv | TargetTrackingEnv:
    """A batched tracking env for a preset name (``"obstacles1"``) or a config, with the belief-feature and
    reward transforms composed on (``transforms=False`` returns the raw env). ``compile=True`` runs the
    step and the transforms through ``torch.compile``."""
    if isinstance(setting, str):
        config = load_env_config(setting, overrides)
    elif overrides:
        raise ConfigError("overrides", list(overrides), "none with a config object (they apply to a preset name; "
                          "edit the config object instead)")
    else:
        config = to_tracking_config(setting)
    env = TargetTrackingEnv(
        config, batch_size=batch_size, device=device, seed=seed, validate_actions=validate_actions, compile_step=compile
    )
    return TrackingTransformedEnv(env, make_transforms(config, compile, env.geometry)) if transforms else env
