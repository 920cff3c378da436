"""Tests of aia/rng/streams.py: every purpose and stream number, declared once and apart from the others."""

from __future__ import annotations

import inspect
from enum import IntEnum

import torch

from aia import rng
from aia.rng import streams


def _families() -> list[type[IntEnum]]:
    return [cls for _, cls in inspect.getmembers(streams, inspect.isclass)
            if issubclass(cls, IntEnum) and cls.__module__ == streams.__name__]


def test_no_two_numbers_of_one_family_collide():
    families = _families()
    assert {family.__name__ for family in families} >= {"Purpose", "WorldStream", "ExplorationStream", "ReplayStream"}
    for family in families:
        values = [member.value for member in family.__members__.values()]
        assert len(values) == len(set(values)), family.__name__  # no alias: two names of one number
        assert all(value >= 0 for value in values), family.__name__


def test_the_purposes_keys_are_apart_from_each_other_and_from_the_world_keys():
    seeds = list(range(20))
    keys = [rng.seed_keys(seeds, purpose) for purpose in rng.Purpose]
    everything = torch.cat(keys + [torch.stack([rng.world_keys(seed, 1)[0] for seed in seeds])])
    assert torch.unique(everything).numel() == everything.numel()
