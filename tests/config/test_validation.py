"""aia.config.validation accepts every shipped preset and refuses cross-field mistakes by name."""

from __future__ import annotations

import pytest
from hydra import compose, initialize_config_module

from aia.apps.hydra_app import group_options
from aia.config.errors import ConfigError
from aia.config.schemas import EvalConfig, RolloutConfig, TrainConfig
from aia.config.validation import check_known_keys, validate_eval_config, validate_rollout_config, validate_train_config

PRESETS = [[], ["experiment=paper_obstacles1", "method=adfq_ts"], ["experiment=paper_small3", "method=ddqn"],
           ["env=small2_2019", "algo=adfq", "logger=csv"], ["logger=none", "eval.per_rollout=50"]]


def _compose(name: str, overrides: list[str]):
    with initialize_config_module(config_module="aia.conf", version_base="1.3"):
        return compose(config_name=name, overrides=overrides)


@pytest.mark.parametrize("overrides", PRESETS, ids=[" ".join(p) or "default" for p in PRESETS])
def test_shipped_train_presets_are_valid(overrides):
    validate_train_config(_compose("train", overrides))


def test_eval_and_rollout_defaults_are_valid(tmp_path):
    validate_eval_config(_compose("eval", ["policy=arvi", "env=obstacles1"]), ["policy=arvi", "env=obstacles1"])
    validate_rollout_config(_compose("rollout", ["env=small3_2019"]))


def test_cross_field_rules_name_both_fields():
    cfg = _compose("train", ["algo=adfq", "algo.sd_max=1e-6"])
    with pytest.raises(ConfigError, match=r"algo.sd_max=1e-06: expected a value whose square exceeds algo.var_min"):
        validate_train_config(cfg)
    cfg = _compose("train", ["exploration.eps_end=2"])
    with pytest.raises(ConfigError, match=r"exploration.eps_end=2: expected a number >= 0 and <= 1"):
        validate_train_config(cfg)
    error = ConfigError("lr", -1.0, "a number > 0", source="conf.yaml")
    assert str(error) == "conf.yaml: lr=-1.0: expected a number > 0" and error.key == "lr"


def test_every_shipped_preset_has_only_the_schemas_keys_and_is_valid():
    # the check that refuses a key added with + must not refuse a key a shipped preset sets (the algo,
    # exploration and logger options: through the methods and test_shipped_train_presets_are_valid), and every
    # preset passes the app's whole validation
    for group in ("env", "experiment", "method"):
        for option in group_options(group).split(", "):
            cfg = _compose("train", [f"{group}={option}"])
            check_known_keys(cfg, TrainConfig)
            validate_train_config(cfg)
    check_known_keys(_compose("eval", ["policy=arvi", "env=ttenv_v5"]), EvalConfig)
    check_known_keys(_compose("rollout", ["env=random_obstacles"]), RolloutConfig)


def test_a_key_added_with_plus_is_refused_with_the_keys_there():
    with pytest.raises(ConfigError, match=r"^exploration.eps_ennd=0.1: expected one of exploration's keys "
                                          r"\(did you mean exploration.eps_end\?\): name, "):
        validate_train_config(_compose("train", ["+exploration.eps_ennd=0.1"]))
    with pytest.raises(ConfigError, match=r"^env.random_map.nope=1: expected one of env.random_map's keys: "):
        validate_rollout_config(_compose("rollout", ["+env.random_map.nope=1"]))
