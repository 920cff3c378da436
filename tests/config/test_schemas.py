"""The typed schemas' metadata is honoured: every field of TrainConfig that a population may vary leaves one
population, every other field splits it with a line naming the key; every field a resume must match refuses a
checkpoint that differs in it with one line, every other field may change. A value of the wrong type is refused
while composing in the words of its declared check."""

from __future__ import annotations

import pytest
import torch
from hydra import compose, initialize_config_module
from hydra.errors import ConfigCompositionException
from omegaconf import DictConfig, OmegaConf

from aia.apps.hydra_app import composition_message
from aia.config.errors import ConfigError
from aia.config.schemas import TrainConfig, settings
from aia.training.members import FAMILIES, MEMBER_KEYS, PopulationError, check_population, population_signature
from aia.training.resuming import RESUME_KEYS, load_resumable

# A leaf of the env (every key under `env` is one field for populations and resumes).
ENV_LEAF = "env.sensor.range"


def _compose(*overrides: str) -> DictConfig:
    with initialize_config_module(config_module="aia.conf", version_base="1.3"):
        return compose(config_name="train", overrides=list(overrides))


@pytest.fixture(scope="module")
def bases() -> list[DictConfig]:
    """The default config, then ADFQ's (its algo fields): together they hold every field of TrainConfig; their
    env cut to one leaf, as every key under ``env`` is handled alike (and copying the whole env is slow)."""
    cfgs = [_compose(), _compose("algo=adfq")]
    for cfg in cfgs:
        cfg.env = {"sensor": {"range": 10.0}}
    return cfgs


def _leaves() -> list[str]:
    return [ENV_LEAF if key == "env" else key for key, _ in settings(TrainConfig)]


def _base_with(bases: list[DictConfig], key: str) -> DictConfig:
    return next(cfg for cfg in bases if OmegaConf.select(cfg, key, default="absent") != "absent")


def _changed(cfg: DictConfig, key: str) -> DictConfig:
    """``cfg`` with another value at ``key`` of the same type (a member's ``algo.name``: within its family)."""
    value = OmegaConf.select(cfg, key)
    family = {v for v, f in FAMILIES.get(key, {}).items() if f == FAMILIES[key].get(value)} - {value}
    if family:
        new = sorted(family)[0]
    elif isinstance(value, bool):
        new = not value
    elif isinstance(value, (int, float)):
        new = value + 1
    elif isinstance(value, str):
        new = value + "x"
    elif value is None:
        new = 2 if key == "threads" else "x"
    else:  # a list: one more of its last entry
        new = [*value, value[-1]]
    other = cfg.copy()
    OmegaConf.update(other, key, new)
    return other


def test_every_field_is_in_a_shipped_config_and_the_env_is_one_field(bases):
    for key in _leaves():
        _base_with(bases, key)
    assert "env" in RESUME_KEYS and "env" not in MEMBER_KEYS


def test_a_population_may_vary_exactly_its_member_fields(bases):
    signatures = [population_signature(cfg) for cfg in bases]
    for key in _leaves():
        base = _base_with(bases, key)
        other = _changed(base, key)
        if key in MEMBER_KEYS:
            assert population_signature(other) == signatures[bases.index(base)], key
        else:
            with pytest.raises(PopulationError, match=rf"^members 0 and 1 differ in {key} \("):
                check_population([base, other])


def test_a_resume_must_match_exactly_its_resume_fields(bases, tmp_path):
    paths = [tmp_path / f"{index}.pt" for index in range(len(bases))]
    for cfg, path in zip(bases, paths, strict=True):
        torch.save({"config": OmegaConf.to_container(cfg, resolve=True), "online": {}, "state": {}}, path)
    for key in _leaves():
        base = _base_with(bases, key)
        path, now = paths[bases.index(base)], _changed(base, key)
        if key.split(".")[0] == "env" or key in RESUME_KEYS:
            with pytest.raises(ConfigError, match=rf"it differs in {key} \(") as info:
                load_resumable(path, now, "cpu")
            assert "\n" not in str(info.value) and info.value.key == "resume"
        else:
            load_resumable(path, now, "cpu")


WRONG_TYPES = [("frames=abc", "frames='abc': expected an integer >= 1"),
               ("logger.chunk_size=1.5", "logger.chunk_size=1.5: expected an integer >= 1"),
               ("hidden=[a]", "hidden[0]='a': expected a non-empty list of layer widths")]


@pytest.mark.parametrize("override, line", WRONG_TYPES)
def test_a_value_of_the_wrong_type_is_worded_by_its_declared_check(override, line):
    with pytest.raises(ConfigCompositionException) as info:
        _compose(override)
    assert composition_message(info.value, TrainConfig).startswith(line)
