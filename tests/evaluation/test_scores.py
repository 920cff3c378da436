"""aia.evaluation.scores: episode scores (SPEC 9), belief errors, summaries and the search objective."""

from __future__ import annotations

import math

import pytest
import torch
from tensordict import TensorDict

from aia.envs import make_env
from aia.evaluation import (
    belief_errors,
    episode_scores,
    evaluation_summary,
    run_episodes,
    score_summary,
    search_objective,
)
from aia.policies import RandomPolicy


def test_episode_score_is_the_sum_of_minus_mean_logdet():
    logdet = torch.tensor([[[1.0, 3.0], [2.0, 2.0], [0.0, -4.0]]])  # [B=1, T=3, N=2]
    td = TensorDict({"next": {"logdet_cov": logdet}}, batch_size=[1, 3])
    assert episode_scores(td).tolist() == [-(2.0 + 2.0 - 2.0)]


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


# ------------------------------------------------ the objective a run returns to a sweeper
@pytest.mark.parametrize("scores, expected", [
    ([5.0], 5.0),                              # a single evaluation is its own tail
    ([1.0, 2.0, 3.0], 3.0),                    # under 10 evaluations: the last one
    (list(range(20)), 18.5),                   # 20 evaluations: the mean of the last 2
    ([0.0] * 90 + [10.0] * 9 + [-80.0], 1.0),  # 100 evaluations: the last 10, a late drop included
])
def test_the_objective_is_the_mean_of_the_last_tenth(scores, expected):
    assert search_objective(scores) == pytest.approx(expected)


def test_a_run_without_evaluations_has_no_objective():
    assert search_objective([]) is None  # a failed trial to the optuna sweeper
