"""Exploration: the linear epsilon schedule, batched epsilon-greedy and the config check.

(Thompson sampling is tested with :class:`~aia.modules.PopulationQPolicy`, which does it.)
"""

from __future__ import annotations

import math

import pytest
import torch
from tensordict import TensorDict
from torchrl.envs.utils import ExplorationType, set_exploration_type

from aia.modules import EpsilonGreedy, LinearEpsilon, check_exploration

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
    td = _greedy((1000,))
    greedy = td["action"].clone()
    with set_exploration_type(ExplorationType.DETERMINISTIC):
        assert torch.equal(egreedy(td)["action"], greedy)
    assert not torch.equal(egreedy(td.clone())["action"], greedy)  # epsilon 1 does explore otherwise


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
