"""PopulationQPolicy: each member explores on its own seed and schedule, as a population of one would."""

from __future__ import annotations

import math

import pytest
import torch
from tensordict import TensorDict
from torchrl.envs.utils import ExplorationType, set_exploration_type

from aia.modules import ADFQNetwork, PopulationQPolicy, StackedQNetwork, make_q_network

A = 12  # actions
CHI2_11_DOF_P001 = 31.26  # 99.9% quantile of chi-square with 11 degrees of freedom


def _chi2_uniform(action: torch.Tensor, num_actions: int = A) -> float:
    counts = torch.bincount(action.flatten(), minlength=num_actions).double()
    expected = action.numel() / num_actions
    return float(((counts - expected) ** 2 / expected).sum())


def _mlp(seed: int) -> torch.nn.Module:
    torch.manual_seed(seed)
    return make_q_network(8, A, (16,))


def _adfq(seed: int, num_actions: int = A) -> ADFQNetwork:
    torch.manual_seed(seed)
    network = ADFQNetwork(8, num_actions, (16,))
    with torch.no_grad():  # distinct means and sds per observation (the init's head is constant)
        network.mlp[-1].weight.normal_(std=0.5)
    return network


def _policy(networks, worlds: int, seeds, thompson: bool = False, eps_init=None, eps_end=None, annealing=None,
            warmup: int = 0) -> PopulationQPolicy:
    P = len(networks)
    return PopulationQPolicy(StackedQNetwork.stack(networks), A, worlds, seeds, thompson,
                             eps_init=eps_init or [1.0] * P, eps_end=eps_end or [0.05] * P,
                             annealing_frames=annealing or [100] * P, warmup_frames=warmup)


def _act(policy: PopulationQPolicy, obs: torch.Tensor) -> torch.Tensor:
    """Actions ``[N]`` for ``obs`` ``[N, 8]``."""
    return policy(TensorDict(observation=obs, batch_size=obs.shape[:1]))["action"]


def _obs(step: int, count: int) -> torch.Tensor:
    return torch.randn(count, 8, generator=torch.Generator().manual_seed(1000 + step))


@pytest.mark.parametrize("thompson", [False, True])
def test_a_member_acts_as_a_population_of_one_with_its_seed_whatever_the_others(thompson):
    W = 4
    make = _adfq if thompson else _mlp
    schedule = dict(eps_init=[0.9, 0.6, 0.3], eps_end=[0.2, 0.1, 0.0], annealing=[40, 60, 80], warmup=12)
    population = _policy([make(0), make(1), make(2)], W, [5, 6, 7], thompson, **schedule)
    # a different population around the same member 1: other networks, seeds and schedules
    others = _policy([make(8), make(1), make(9)], W, [50, 6, 70], thompson, eps_init=[0.1, 0.6, 1.0],
                     eps_end=[0.1, 0.1, 1.0], annealing=[1, 60, 5], warmup=12)
    solo = _policy([make(1)], W, [6], thompson, eps_init=[0.6], eps_end=[0.1], annealing=[60], warmup=12)
    differs = 0
    for step in range(30):  # 3 warm-up steps, then the schedule
        obs = _obs(step, 3 * W)
        member = obs[W:2 * W]
        action = _act(population, obs)
        assert action.shape == (3 * W,) and action.dtype == torch.int64
        expected = _act(solo, member)
        assert torch.equal(action[W:2 * W], expected), step
        assert torch.equal(_act(others, torch.cat([_obs(step + 99, W), member, _obs(step + 77, W)]))[W:2 * W],
                           expected), step
        out = solo.network(member.unsqueeze(0))
        differs += int((expected != (out[0] if thompson else out)[0].argmax(-1)).sum())
    assert int(population.steps) == int(solo.steps) == 30
    assert differs > 10  # exploration changed actions away from the greedy ones


def test_members_that_sample_and_members_that_are_epsilon_greedy_act_as_their_solo_runs():
    W = 4
    # member 0 epsilon-greedy, member 1 sampling, member 2 epsilon-greedy (a sampling member's schedule: unused)
    mixed = _policy([_adfq(0), _adfq(1), _adfq(2)], W, [5, 6, 7], [False, True, False], eps_init=[0.9, 0.5, 0.3],
                    eps_end=[0.2, 0.5, 0.0], annealing=[40, 1, 80], warmup=8)
    solos = [_policy([_adfq(0)], W, [5], False, eps_init=[0.9], eps_end=[0.2], annealing=[40], warmup=8),
             _policy([_adfq(1)], W, [6], True, warmup=8),
             _policy([_adfq(2)], W, [7], False, eps_init=[0.3], eps_end=[0.0], annealing=[80], warmup=8)]
    assert mixed.egreedy_members == [0, 2]
    for step in range(25):  # 2 warm-up steps, then each member's own exploration
        obs = _obs(step, 3 * W)
        action = _act(mixed, obs)
        for k, solo in enumerate(solos):
            assert torch.equal(action[k * W:(k + 1) * W], _act(solo, obs[k * W:(k + 1) * W])), (step, k)
    with pytest.raises(ValueError, match="2 exploration kinds for 3 members"):
        _policy([_adfq(0), _adfq(1), _adfq(2)], W, [5, 6, 7], [False, True])


def test_warmup_frames_are_uniformly_random_then_the_schedule_takes_over():
    network = _mlp(0)
    with torch.no_grad():  # the greedy action is 3 wherever the world is
        network[-1].bias[3] = 1e4
    W = 1200
    policy = _policy([network], W, [11], eps_init=[0.0], eps_end=[0.0], annealing=[1], warmup=10 * W)
    warm = torch.stack([_act(policy, _obs(step, W)) for step in range(10)])
    assert _chi2_uniform(warm) < CHI2_11_DOF_P001
    assert (torch.bincount(warm.flatten(), minlength=A) > 0.9 * warm.numel() / A).all()
    assert int(policy.frames) == 10 * W
    for step in range(10, 13):  # frame 10 W onwards: no longer warm, epsilon 0, greedy
        assert torch.equal(_act(policy, _obs(step, W)), torch.full((W,), 3))


def test_thompson_warmup_is_uniform_too():
    network = _adfq(0)
    with torch.no_grad():  # tiny sds and a clear best action: Thompson is greedy after the warm-up
        network.mlp[-1].weight.zero_()
        network.mlp[-1].bias[:A] = torch.arange(A, dtype=torch.float32)
        network.mlp[-1].bias[A:] = -100.0
    W = 1200
    policy = _policy([network], W, [2], thompson=True, warmup=5 * W)
    warm = torch.stack([_act(policy, _obs(step, W)) for step in range(5)])
    assert _chi2_uniform(warm) < CHI2_11_DOF_P001
    assert torch.equal(_act(policy, _obs(5, W)), torch.full((W,), A - 1))


def test_epsilon_follows_each_members_own_linear_schedule():
    W = 2
    policy = _policy([_mlp(0), _mlp(1), _mlp(2)], W, [1, 2, 3], eps_init=[1.0, 0.5, 0.2], eps_end=[0.1, 0.0, 0.2],
                     annealing=[10, 40, 4])
    # frames = 2 * steps: epsilon = init + min(frames / annealing, 1) * (end - init), per member
    expected = {0: [1.0, 0.5, 0.2], 2: [0.64, 0.45, 0.2], 5: [0.1, 0.375, 0.2], 20: [0.1, 0.0, 0.2],
                50: [0.1, 0.0, 0.2]}
    for step in range(51):
        if step in expected:
            assert int(policy.frames) == W * step
            torch.testing.assert_close(policy.epsilon(), torch.tensor(expected[step], dtype=torch.float64))
        _act(policy, _obs(step, 3 * W))


def test_each_member_explores_with_its_own_epsilon():
    network = _mlp(0)
    W = 20_000
    policy = _policy([network, network], W, [4, 5], eps_init=[0.3, 0.7], eps_end=[0.3, 0.7], annealing=[1, 1])
    obs = _obs(0, 2 * W)
    greedy = network(obs).argmax(-1)
    changed = (_act(policy, obs) != greedy).double().reshape(2, W).mean(-1)
    # a random action equals the greedy one with probability 1/12; binomial sd <= 0.0035
    torch.testing.assert_close(changed, torch.tensor([0.3, 0.7], dtype=torch.float64) * 11 / 12, atol=0.015,
                               rtol=0)


@pytest.mark.parametrize("thompson", [False, True])
def test_greedy_and_no_step_under_deterministic_exploration(thompson):
    networks = [_adfq(0), _adfq(1)] if thompson else [_mlp(0), _mlp(1)]
    W = 50
    policy = _policy(networks, W, [1, 2], thompson, eps_init=[1.0, 1.0], eps_end=[1.0, 1.0], warmup=10 * W)
    obs = _obs(0, 2 * W)
    with set_exploration_type(ExplorationType.DETERMINISTIC):
        for _ in range(3):
            action = _act(policy, obs)
            for k, network in enumerate(networks):
                out = network(obs[k * W:(k + 1) * W])
                assert torch.equal(action[k * W:(k + 1) * W], (out[0] if thompson else out).argmax(-1))
    assert int(policy.steps) == 0 and int(policy.frames) == 0
    # exploration types RANDOM and unset do explore and count the step
    with set_exploration_type(ExplorationType.RANDOM):
        assert not torch.equal(_act(policy, obs), action)
    assert not torch.equal(_act(policy, obs), action)
    assert int(policy.steps) == 2


def _thompson(mean_bias: torch.Tensor, log_sd_bias: torch.Tensor, worlds: int, seed: int = 0) -> PopulationQPolicy:
    """A one-member Thompson policy whose beliefs are ``N(mean_bias, exp(log_sd_bias)^2)`` for every input."""
    num_actions = mean_bias.numel()
    network = ADFQNetwork(8, num_actions, (4,))
    with torch.no_grad():
        network.mlp[-1].bias.copy_(torch.cat([mean_bias, log_sd_bias]))
    return PopulationQPolicy(StackedQNetwork.stack([network]), num_actions, worlds, [seed], thompson=True,
                             eps_init=[0.0], eps_end=[0.0], annealing_frames=[1], warmup_frames=0)


def test_thompson_with_tiny_sds_is_greedy():
    networks = [_adfq(0), _adfq(1)]
    for network in networks:
        with torch.no_grad():
            network.mlp[-1].bias[A:] = -100.0  # log sd clamped to log 1e-5
    W = 500
    policy = _policy(networks, W, [0, 1], thompson=True)
    obs = _obs(0, 2 * W)
    action = _act(policy, obs)
    for k, network in enumerate(networks):
        assert torch.equal(action[k * W:(k + 1) * W], network(obs[k * W:(k + 1) * W])[0].argmax(-1))
    assert len(action.unique()) > 3  # the means do vary (greedy is not one constant action)


def test_thompson_with_equal_beliefs_is_uniform():
    policy = _thompson(torch.ones(A), torch.full((A,), math.log(10.0)), worlds=20_000)
    action = torch.stack([_act(policy, torch.zeros(20_000, 8)) for _ in range(6)])
    assert _chi2_uniform(action) < CHI2_11_DOF_P001


def test_thompson_choice_probability_matches_the_normal_cdf():
    n = 25_000
    policy = _thompson(torch.tensor([0.0, 1.0]), torch.zeros(2), worlds=n)
    action = torch.stack([_act(policy, torch.zeros(n, 8)) for _ in range(4)])
    # P(q1 > q0) with q1 - q0 ~ N(1, 2) is Phi(1 / sqrt(2)) ~ 0.760; binomial sd ~ 0.0014.
    expected = 0.5 * (1 + math.erf(0.5))
    assert math.isclose(expected, 0.7602, abs_tol=1e-4)
    assert abs(action.double().mean().item() - expected) < 0.006


def test_thompson_is_seeded():
    def draw(seed: int, steps: int = 1) -> torch.Tensor:
        policy = _thompson(torch.zeros(A), torch.zeros(A), worlds=500, seed=seed)
        return torch.stack([_act(policy, torch.zeros(500, 8)) for _ in range(steps)])

    assert torch.equal(draw(3), draw(3)) and not torch.equal(draw(3), draw(4))
    two = draw(3, steps=2)
    assert not torch.equal(two[0], two[1])  # each step draws fresh noise


def test_bad_construction_is_named():
    stacked = StackedQNetwork.stack([_mlp(0), _mlp(1)])
    with pytest.raises(ValueError, match="3 seeds for a network of 2 members"):
        PopulationQPolicy(stacked, A, 4, [1, 2, 3], False, [1.0] * 3, [0.1] * 3, [10] * 3, 0)
    with pytest.raises(TypeError, match="Thompson sampling needs.*ADFQ"):
        PopulationQPolicy(stacked, A, 4, [1, 2], True, [1.0] * 2, [0.1] * 2, [10] * 2, 0)
