"""Episode scores (SPEC 9)."""

from __future__ import annotations

import math

import pytest
import torch
from tensordict import TensorDict

from aia.envs import make_env
from aia.evaluation import belief_errors, episode_scores, evaluation_summary, run_episodes, score_summary
from aia.policies import RandomPolicy


def test_episode_score_is_the_sum_of_minus_mean_logdet():
    logdet = torch.tensor([[[1.0, 3.0], [2.0, 2.0], [0.0, -4.0]]])  # [B=1, T=3, N=2]
    td = TensorDict({"next": {"logdet_cov": logdet}}, batch_size=[1, 3])
    assert episode_scores(td).tolist() == [-(2.0 + 2.0 - 2.0)]


def test_run_episodes_covers_one_episode_per_world_and_is_seeded():
    env = make_env("empty1", batch_size=3, seed=0, overrides=["max_steps=25"])
    first = run_episodes(env, RandomPolicy(12, seed=1), seed=5)
    again = run_episodes(env, RandomPolicy(12, seed=1), seed=5)
    assert first.shape == (3, 25)
    assert first["next", "truncated"][:, -1].all() and not first["next", "truncated"][:, :-1].any()
    assert torch.equal(episode_scores(first), episode_scores(again))


def test_score_summary_is_the_mean_and_population_std():
    summary = score_summary(torch.tensor([1.0, 3.0, 8.0]))
    assert summary == {"score_mean": 4.0, "score_std": pytest.approx(math.sqrt(26 / 3)), "scores": [1.0, 3.0, 8.0]}


def test_belief_error_is_the_mean_distance_of_belief_to_target():
    # B=1, T=2, N=2 targets: distances 5 and 0 at the first step, 1 and 2 at the second
    mean = torch.tensor([[[[3.0, 4.0, 9.0, 9.0], [1.0, 1.0, 0.0, 0.0]], [[0.0, 1.0, 0.0, 0.0], [2.0, 0.0, 0.0, 0.0]]]])
    truth = torch.tensor([[[[0.0, 0.0, 0.0, 0.0], [1.0, 1.0, 5.0, 5.0]], [[0.0, 0.0, 0.0, 0.0], [0.0, 0.0, 0.0, 0.0]]]])
    td = TensorDict({"next": {"belief_mean": mean, "target_state": truth, "logdet_cov": torch.zeros(1, 2, 2)}},
                    batch_size=[1, 2])
    assert belief_errors(td).tolist() == [2.0]
    summary = evaluation_summary(td)
    assert summary["belief_error"] == 2.0 and summary["scores"] == [0.0]


def test_belief_error_of_a_real_rollout_is_finite_and_positive():
    env = make_env("empty1", batch_size=2, seed=0, overrides=["max_steps=10"])
    errors = belief_errors(run_episodes(env, RandomPolicy(12, seed=1), seed=3))
    assert errors.shape == (2,) and torch.isfinite(errors).all() and (errors > 0).all()
