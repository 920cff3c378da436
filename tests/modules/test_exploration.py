"""Exploration: the linear epsilon schedule, batched epsilon-greedy, Thompson sampling and the config check."""

from __future__ import annotations

import math

import pytest
import torch
from tensordict import TensorDict
from torchrl.envs.utils import ExplorationType, set_exploration_type

from aia.modules import EpsilonGreedy, LinearEpsilon, ThompsonSampling, check_exploration

CHI2_11_DOF_P001 = 31.26  # 99.9% quantile of chi-square with 11 degrees of freedom


def _chi2_uniform(action: torch.Tensor, num_actions: int = 12) -> float:
    counts = torch.bincount(action.flatten(), minlength=num_actions).double()
    expected = action.numel() / num_actions
    return float(((counts - expected) ** 2 / expected).sum())


def test_linear_epsilon_values():
    schedule = LinearEpsilon(1.0, 0.01, 1000)
    assert schedule.value(0) == 1.0
    assert math.isclose(schedule.value(500), 0.505)
    assert math.isclose(schedule.value(1000), 0.01)
    assert math.isclose(schedule.value(10_000), 0.01)
    with pytest.raises(ValueError, match="annealing_frames"):
        LinearEpsilon(annealing_frames=0)


def test_epsilon_greedy_step_follows_the_schedule():
    module = EpsilonGreedy(12, eps_init=1.0, eps_end=0.01, annealing_frames=1000)
    assert module.epsilon == 1.0
    module.step(250)
    module.step(250)
    assert module.frames == 500 and math.isclose(module.epsilon, 0.505)
    module.step(5000)
    assert math.isclose(module.epsilon, 0.01)


def _greedy(shape=(120_000,)) -> TensorDict:
    action = torch.randint(0, 12, shape, generator=torch.Generator().manual_seed(123))
    return TensorDict({"action": action}, batch_size=shape)


def test_epsilon_one_is_uniform():
    module = EpsilonGreedy(12, seed=0)
    module.epsilon = 1.0
    td = TensorDict({"action": torch.zeros(120_000, dtype=torch.int64)}, batch_size=[120_000])
    action = module(td)["action"]
    assert action.dtype == torch.int64 and action.min() == 0 and action.max() == 11
    assert _chi2_uniform(action) < CHI2_11_DOF_P001


def test_epsilon_zero_keeps_the_greedy_action():
    module = EpsilonGreedy(12, seed=0)
    module.epsilon = 0.0
    td = _greedy()
    greedy = td["action"].clone()
    assert torch.equal(module(td)["action"], greedy)


def test_epsilon_fraction_changed():
    module = EpsilonGreedy(12, seed=0)
    module.epsilon = 0.3
    td = _greedy()
    greedy = td["action"].clone()
    changed = (module(td)["action"] != greedy).double().mean().item()
    # A random action equals the greedy one with probability 1/12; binomial sd ~ 0.0013.
    assert abs(changed - 0.3 * 11 / 12) < 0.006


def test_epsilon_greedy_is_seeded_and_batch_shape_agnostic():
    def draw(seed: int) -> torch.Tensor:
        module = EpsilonGreedy(12, seed=seed)
        module.epsilon = 0.5
        return module(_greedy((4, 5, 6)))["action"]

    a, b, c = draw(7), draw(7), draw(8)
    assert a.shape == (4, 5, 6)
    assert torch.equal(a, b) and not torch.equal(a, c)
    # Successive calls of one module draw fresh noise.
    module = EpsilonGreedy(12, seed=7)
    assert not torch.equal(module(_greedy((1000,)))["action"], module(_greedy((1000,)))["action"])


def test_exploration_is_off_under_deterministic_exploration_type():
    egreedy = EpsilonGreedy(12, seed=0)
    thompson = ThompsonSampling(seed=0)
    td = _greedy((1000,))
    td["action_value"] = torch.zeros(1000, 12)
    td["action_log_sd"] = torch.zeros(1000, 12)
    greedy = td["action"].clone()
    with set_exploration_type(ExplorationType.DETERMINISTIC):
        assert torch.equal(thompson(egreedy(td))["action"], greedy)
    assert td.get("action_sample", None) is None


def _values(mean: torch.Tensor, log_sd: torch.Tensor) -> TensorDict:
    return TensorDict({"action_value": mean, "action_log_sd": log_sd}, batch_size=mean.shape[:-1])


def test_thompson_with_tiny_sds_is_greedy():
    mean = torch.randn(1000, 12, generator=torch.Generator().manual_seed(0))
    td = ThompsonSampling(seed=0)(_values(mean, torch.full((1000, 12), math.log(1e-5))))
    assert torch.equal(td["action"], mean.argmax(-1))
    assert td["action"].dtype == torch.int64
    assert td["action_sample"].shape == (1000, 12)


def test_thompson_with_equal_beliefs_is_uniform():
    td = ThompsonSampling(seed=0)(_values(torch.ones(120_000, 12), torch.full((120_000, 12), math.log(10.0))))
    assert _chi2_uniform(td["action"]) < CHI2_11_DOF_P001


def test_thompson_choice_probability_matches_the_normal_cdf():
    n = 100_000
    mean = torch.tensor([0.0, 1.0]).expand(n, 2)
    td = ThompsonSampling(seed=0)(_values(mean, torch.zeros(n, 2)))
    # P(q1 > q0) with q1 - q0 ~ N(1, 2) is Phi(1 / sqrt(2)) ~ 0.760; binomial sd ~ 0.0014.
    expected = 0.5 * (1 + math.erf(0.5))
    assert math.isclose(expected, 0.7602, abs_tol=1e-4)
    assert abs(td["action"].double().mean().item() - expected) < 0.006


def test_thompson_is_seeded():
    def draw(seed: int) -> torch.Tensor:
        return ThompsonSampling(seed=seed)(_values(torch.zeros(500, 12), torch.zeros(500, 12)))["action"]

    assert torch.equal(draw(3), draw(3)) and not torch.equal(draw(3), draw(4))


def test_check_exploration():
    for algo in ("dqn", "ddqn", "adfq"):
        check_exploration(algo, "egreedy")
    check_exploration("adfq", "thompson")
    for algo in ("dqn", "ddqn"):
        with pytest.raises(ValueError, match=rf"exploration='thompson'.*algo='adfq'.*algo='{algo}'"):
            check_exploration(algo, "thompson")
    with pytest.raises(ValueError, match="algo must be one of"):
        check_exploration("sarsa", "egreedy")
    with pytest.raises(ValueError, match="exploration must be one of"):
        check_exploration("dqn", "boltzmann")
