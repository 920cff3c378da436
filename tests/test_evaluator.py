"""Evaluator: evaluations played several per rollout equal the same evaluations played one by one."""

from __future__ import annotations

import pytest
import torch

from aia.envs import make_env
from aia.evaluator import Evaluator
from aia.modules import make_q_network

E = 3  # episodes per evaluation


def _evaluate(per_rollout: int, indices: range = range(5)) -> list:
    """Evaluations ``indices`` of a network that changes between them, ``per_rollout`` at a time."""
    torch.manual_seed(0)
    env = make_env("obstacles1", batch_size=E * per_rollout, overrides=["max_steps=25"])
    network = make_q_network(env.observation_spec["observation"].shape[-1], 12, (16, 16))
    base = [param.detach().clone() for param in network.parameters()]
    evaluator = Evaluator(env, network, 12, E, epsilon=0.2, seed=7, noise_seed=100, first_index=indices[0])
    results = []
    for n in indices:
        generator = torch.Generator().manual_seed(n)
        with torch.no_grad():  # the network of evaluation n
            for param, start in zip(network.parameters(), base, strict=True):
                param.copy_(start + 0.3 * torch.randn(param.shape, generator=generator))
        evaluator.add(episode=2 * n + 2, frame=50 * n + 50)
        if evaluator.full:
            results += evaluator.flush()
    results += evaluator.flush()
    assert evaluator.flush() == []
    return results


def _same(a: dict, b: dict) -> bool:
    return a["scores"] == pytest.approx(b["scores"], rel=1e-5) and a["belief_error"] == pytest.approx(
        b["belief_error"], rel=1e-5)


def test_evaluations_do_not_depend_on_how_many_share_a_rollout():
    alone, together = _evaluate(1), _evaluate(3)  # 3 + 2 (the second rollout padded)
    assert [p.index for p, _ in together] == [0, 1, 2, 3, 4]
    assert [(p.episode, p.frame) for p, _ in together] == [(2 * n + 2, 50 * n + 50) for n in range(5)]
    assert all(_same(one, grouped) for (_, one), (_, grouped) in zip(alone, together, strict=True))
    assert len({round(s["score_mean"], 3) for _, s in alone}) == 5  # five different evaluations


def test_more_pending_than_per_rollout_play_in_several_rollouts():
    torch.manual_seed(0)
    env = make_env("empty1", batch_size=2 * E, overrides=["max_steps=5"])
    evaluator = Evaluator(env, make_q_network(8, 12, (8,)), 12, E, epsilon=0.05, seed=0, noise_seed=0)
    for n in range(5):  # e.g. several worlds of a batched collector ending their episodes at once
        evaluator.add(episode=n + 1, frame=5 * n + 5)
    assert [p.index for p, _ in evaluator.flush()] == [0, 1, 2, 3, 4]


def test_a_resumed_run_continues_with_the_next_evaluations_worlds_and_noise():
    run, resumed = _evaluate(2), _evaluate(2, range(2, 5))
    assert [p.index for p, _ in resumed] == [2, 3, 4]
    assert all(_same(a, b) for (_, a), (_, b) in zip(run[2:], resumed, strict=True))


def test_env_that_does_not_split_into_evaluations_is_named():
    env = make_env("empty1", batch_size=5)
    network = make_q_network(8, 12, (8,))
    with pytest.raises(ValueError, match="5 worlds do not split into groups of episodes=2"):
        Evaluator(env, network, 12, 2, epsilon=0.05, seed=0, noise_seed=0)
