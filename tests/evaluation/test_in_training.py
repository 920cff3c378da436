"""Evaluator: a member's evaluations do not depend on how many share a rollout nor on the other members."""

from __future__ import annotations

import pytest
import torch

from aia.envs import make_env
from aia.evaluation import Evaluator
from aia.modules import StackedQNetwork, make_q_network

E = 3  # episodes per evaluation
SEEDS, NOISE_SEEDS = [7, 8, 9], [100, 200, 300]  # of members 0, 1, 2


def _network(members: list[int]) -> StackedQNetwork:
    """The stacked network of ``members`` (member ``k``'s initial weights come from seed ``k``)."""
    networks = []
    for k in members:
        torch.manual_seed(k)
        networks.append(make_q_network(8, 12, (16, 16)))
    return StackedQNetwork.stack(networks)


def _evaluate(per_rollout: int, indices: range = range(4), members: tuple[int, ...] = (0, 1)) -> list:
    """Evaluations ``indices`` of ``members``' networks, which change between evaluations, ``per_rollout`` at
    a time; each result is ``(point, [summary of each member])``."""
    members = list(members)
    env = make_env("obstacles1", batch_size=E * len(members) * per_rollout, overrides=["max_steps=20"])
    network = _network(members)
    base = {name: param.detach().clone() for name, param in network.named_parameters()}
    evaluator = Evaluator(env, network, 12, E, epsilon=0.2, seeds=[SEEDS[k] for k in members],
                          noise_seeds=[NOISE_SEEDS[k] for k in members], first_index=indices[0])
    assert evaluator.per_rollout == per_rollout
    results = []
    for n in indices:
        with torch.no_grad():  # the network of evaluation n: member k's change depends on (k, n) only
            for name, param in network.named_parameters():
                for row, k in enumerate(members):
                    generator = torch.Generator().manual_seed(1000 * k + n)
                    param[row] = base[name][row] + 0.3 * torch.randn(param.shape[1:], generator=generator)
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
    alone, together = _evaluate(1), _evaluate(3)  # 3 + 1 (the second rollout padded)
    assert [p.index for p, _ in together] == [0, 1, 2, 3]
    assert [(p.episode, p.frame) for p, _ in together] == [(2 * n + 2, 50 * n + 50) for n in range(4)]
    for (_, one), (_, grouped) in zip(alone, together, strict=True):
        assert len(one) == len(grouped) == 2
        assert all(_same(a, b) for a, b in zip(one, grouped, strict=True))
    # four different evaluations, and the two members' differ
    assert len({round(s[0]["score_mean"], 3) for _, s in alone}) == 4
    assert any(not _same(s[0], s[1]) for _, s in alone)


def test_a_members_evaluations_do_not_depend_on_the_members_beside_it():
    population = _evaluate(2, members=(0, 1, 2))
    for k in range(3):
        solo = _evaluate(2, members=(k,))
        assert all(_same(s[0], p[k]) for (_, s), (_, p) in zip(solo, population, strict=True)), k


def test_more_pending_than_per_rollout_play_in_several_rollouts():
    env = make_env("empty1", batch_size=2 * 2 * E, overrides=["max_steps=5"])
    evaluator = Evaluator(env, _network([0, 1]), 12, E, epsilon=0.05, seeds=[0, 1], noise_seeds=[0, 1])
    for n in range(5):  # e.g. several worlds of a batched collector ending their episodes at once
        evaluator.add(episode=n + 1, frame=5 * n + 5)
    results = evaluator.flush()
    assert [p.index for p, _ in results] == [0, 1, 2, 3, 4]
    assert all(len(summaries) == 2 for _, summaries in results)


def test_a_resumed_run_continues_with_the_next_evaluations_worlds_and_noise():
    run, resumed = _evaluate(2), _evaluate(2, range(2, 4))
    assert [p.index for p, _ in resumed] == [2, 3]
    for (_, a), (_, b) in zip(run[2:], resumed, strict=True):
        assert all(_same(x, y) for x, y in zip(a, b, strict=True))
    assert not _same(run[0][1][0], run[2][1][0])  # evaluation 2 is not evaluation 0 again


def test_env_that_does_not_split_into_evaluations_is_named():
    network = _network([0, 1])
    with pytest.raises(ValueError, match="5 worlds do not split into groups of 2 members x episodes=2"):
        Evaluator(make_env("empty1", batch_size=5), network, 12, 2, epsilon=0.05, seeds=[0, 1], noise_seeds=[0, 1])
    env = make_env("empty1", batch_size=8)
    with pytest.raises(ValueError, match=r"one seed and one noise seed per member \(2\), got \[0\] and \[0, 1\]"):
        Evaluator(env, network, 12, 2, epsilon=0.05, seeds=[0], noise_seeds=[0, 1])
    with pytest.raises(ValueError, match="2 evaluations per rollout.*at most record_every=1"):
        Evaluator(env, network, 12, 2, epsilon=0.05, seeds=[0, 1], noise_seeds=[0, 1], recorders=[object()] * 2,
                  record_every=1)
