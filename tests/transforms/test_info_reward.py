"""InfoReward: both reward forms and every term against hand computation, and inside the env."""

from __future__ import annotations

import pytest
import torch

from aia.envs import make_env
from aia.envs.config import RewardConfig
from aia.transforms import info_reward

LOGDET = torch.tensor([[1.0, 3.0]])  # mean 2, population std 1
OBSERVED = torch.tensor([[True, False]])  # mean 0.5


def _reward(distance, collision=False, **fields):
    return info_reward(LOGDET, OBSERVED, torch.tensor([distance]), torch.tensor([collision]), 10.0,
                       RewardConfig(**fields)).item()


def test_2019_form_every_term():
    assert _reward(10.0) == pytest.approx(-0.2 - 0.1 + 0.5)  # no obstacle in view
    assert _reward(2.0) == pytest.approx(-0.3 - 0.25 / 4 + 0.5)  # m^2 / o_r^2
    assert _reward(0.4) == pytest.approx(-0.3 - 1.0 + 0.5)  # capped at kappa_o when o_r < m


def test_paper_form_every_term():
    paper = dict(target_aggregate="sum", obstacle_form="paper", observed_bonus=0.0)
    assert _reward(2.0, **paper) == pytest.approx(-0.1 * 4 - 0.1 * 1 - 1 / 4)
    assert _reward(10.0, **paper) == pytest.approx(-0.5)
    assert _reward(2.0, **paper, kappa_o=3.0, kappa_d=0.0, kappa_m=1.0) == pytest.approx(-4 - 3 / 4)


def test_collision_penalty_of_the_later_rewrite():
    assert _reward(10.0, collision=True, collision_penalty=1.0) == pytest.approx(-1.0)  # min(0, 0.2) - 1
    assert _reward(0.4, collision=True, collision_penalty=1.0) == pytest.approx(-1.8)
    assert _reward(0.4, collision=False, collision_penalty=1.0) == pytest.approx(-0.8)


def test_single_target_std_term_vanishes():
    r = info_reward(torch.tensor([[5.0]]), torch.tensor([[True]]), torch.tensor([10.0]), torch.tensor([False]),
                    10.0, RewardConfig())
    assert r.item() == pytest.approx(-0.5 + 1.0)


def test_transform_writes_the_shaped_reward():
    env = make_env("obstacles1", batch_size=16, seed=4)
    td = env.rollout(40, break_when_any_done=False)
    nxt = td["next"]
    expected = info_reward(nxt["logdet_cov"], nxt["observed"], nxt["obstacle_polar"][..., 0], nxt["collision"], 10.0,
                           env.base_env.config.reward)
    assert torch.allclose(nxt["reward"].squeeze(-1), expected)
    raw = make_env("obstacles1", batch_size=16, seed=4, transforms=False).rollout(40, break_when_any_done=False)
    # the raw env's reward is the score increment -mean_i log det Sigma_i
    assert torch.allclose(raw["next", "reward"].squeeze(-1), -raw["next", "logdet_cov"].mean(-1))
    # some steps saw an obstacle, so the obstacle term was exercised
    assert (nxt["obstacle_polar"][..., 0] < 10.0).any()
