"""Which runs form one population: they may differ only in MEMBER_KEYS (algo.name only within its family), and the
first other difference is named."""

from __future__ import annotations

import pytest
from hydra import compose, initialize_config_module
from omegaconf import DictConfig, OmegaConf

from aia.training.members import (
    MEMBER_KEYS,
    PopulationError,
    check_population,
    first_difference,
    population_signature,
)


def _cfg(**changes: object) -> DictConfig:
    """A small train-like config; ``changes`` by dotted key (``exploration__eps_end`` for ``exploration.eps_end``)."""
    cfg = OmegaConf.create({
        "seed": 0, "lr": 1e-3, "resume": None, "batch_size": 64, "hidden": [32, 32], "frames": "${batch_size}",
        "method": "dqn", "algo": {"name": "dqn"},
        "exploration": {"name": "egreedy", "eps_init": 1.0, "eps_end": 0.01, "annealing_fraction": 0.1},
        "env": {"name": "empty1", "seed": 0, "sensor": {"range": 10.0}},
    })
    for key, value in changes.items():
        OmegaConf.update(cfg, key.replace("__", "."), value, force_add=True)
    return cfg


MEMBER_CHANGES = {"seed": 4, "lr": 5e-4, "method": "ddqn", "algo.name": "ddqn", "exploration.name": "thompson",
                  "exploration.eps_init": 0.5, "exploration.eps_end": 0.1, "exploration.annealing_fraction": 0.3,
                  "resume": "run/last.pt"}
SHARED_CHANGES = {"batch_size": 32, "hidden": [32, 64], "algo.name": "adfq", "env.seed": 4,
                  "env.sensor.range": 12.0, "env.extra": 1}


def test_the_member_keys_are_the_ones_tested_here():
    assert set(MEMBER_KEYS) == set(MEMBER_CHANGES)


def test_signature_is_equal_exactly_when_only_member_keys_differ():
    base = population_signature(_cfg())
    for key, value in MEMBER_CHANGES.items():
        assert population_signature(_cfg(**{key: value})) == base, key
    assert population_signature(_cfg(**{k.replace(".", "__"): v for k, v in MEMBER_CHANGES.items()})) == base
    for key, value in SHARED_CHANGES.items():  # incl. env.seed: only the top-level seed is a member's own
        assert population_signature(_cfg(**{key: value})) != base, key
        assert population_signature(_cfg(**{key: value, "seed": 9})) != base, key


def test_signature_compares_resolved_values():
    # frames interpolates batch_size: equal when resolved equal, different when the resolved value differs
    assert population_signature(_cfg(frames=64)) == population_signature(_cfg())
    assert population_signature(_cfg(frames=65)) != population_signature(_cfg())


def test_signature_of_the_train_config_ignores_a_members_seed_and_learning_rate():
    with initialize_config_module(config_module="aia.conf", version_base="1.3"):
        a = compose(config_name="train", overrides=["seed=0", "lr=1e-3"])
        b = compose(config_name="train", overrides=["seed=7", "lr=5e-4", "exploration.eps_end=0.05"])
        c = compose(config_name="train", overrides=["seed=7", "env=small2"])
    assert population_signature(a) == population_signature(b) != population_signature(c)
    assert first_difference(a, c)[0].startswith("env.")


def test_first_difference_names_the_key_and_both_values():
    assert first_difference(_cfg(), _cfg(**MEMBER_CHANGES)) is None
    assert first_difference(_cfg(), _cfg(hidden=[32, 64])) == ("hidden", [32, 32], [32, 64])
    assert first_difference(_cfg(**{"env.sensor.range": 12.0}), _cfg()) == ("env.sensor.range", 12.0, 10.0)
    # alphabetically first of several differences; a key only one side has meets None
    assert first_difference(_cfg(batch_size=32, hidden=[1]), _cfg()) == ("batch_size", 32, 64)
    assert first_difference(_cfg(), _cfg(**{"env.extra": 1})) == ("env.extra", None, 1)
    # a key of a family: the members' own values, not their families
    assert first_difference(_cfg(**{"algo.name": "ddqn"}), _cfg(**{"algo.name": "adfq"})) == ("algo.name", "ddqn",
                                                                                                "adfq")


def test_check_population_message():
    check_population([_cfg(), _cfg(seed=1, lr=0.1), _cfg(**MEMBER_CHANGES)])
    check_population([_cfg()])
    message = (r"members 0 and 2 differ in env.name \('empty1' vs 'small2'\); a population may differ only in "
               r"seed, lr, method, algo.name, exploration.name, exploration.eps_init, exploration.eps_end, "
               r"exploration.annealing_fraction, resume \(algo.name only between dqn and ddqn\)$")
    with pytest.raises(PopulationError, match=message):
        check_population([_cfg(), _cfg(seed=1), _cfg(**{"env.name": "small2"})])
    with pytest.raises(PopulationError, match="at least one member"):
        check_population([])
    assert issubclass(PopulationError, ValueError)
