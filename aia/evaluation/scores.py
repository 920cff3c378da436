"""Scores: an episode's (SPEC 9) from a rollout tensordict, an evaluation's summary, and a run's search objective."""

from __future__ import annotations

from collections.abc import Sequence

import torch
from tensordict import TensorDictBase
from torch import Tensor
from torchrl.record.loggers import Logger

from aia.logging.curves import tail_mean


def episode_scores(rollout: TensorDictBase) -> Tensor:
    """``[B]`` scores of a ``[B, T]`` rollout that covers one episode per world: the sum over steps of
    ``-mean_i log det Sigma_i`` (SPEC 9; the mean over targets is the reference's convention)."""
    return -rollout.get(("next", "logdet_cov")).mean(-1).sum(-1)


def belief_errors(rollout: TensorDictBase) -> Tensor:
    """``[B]`` mean distance (m) between the belief means and the true target positions of a ``[B, T]``
    rollout, over its steps and targets: what the score (confidence, not accuracy) does not measure."""
    mean = rollout.get(("next", "belief_mean"))[..., :2]
    truth = rollout.get(("next", "target_state"))[..., :2]
    return torch.linalg.vector_norm(mean - truth, dim=-1).mean((-1, -2))


def score_summary(scores: Tensor, errors: Tensor | None = None) -> dict:
    """``score_mean``, ``score_std`` (population std, as the learning curves' band) and the ``scores`` of a
    batch of episodes, as Python numbers; with the episodes' :func:`belief_errors`, also their mean
    ``belief_error``."""
    summary = {"score_mean": scores.mean().item(), "score_std": scores.std(correction=0).item(),
               "scores": scores.tolist()}
    if errors is not None:
        summary["belief_error"] = errors.mean().item()
    return summary


def evaluation_summary(rollout: TensorDictBase) -> dict:
    """:func:`score_summary` of a rollout that covers one episode per world, with its belief error."""
    return score_summary(episode_scores(rollout), belief_errors(rollout))


def log_score_summary(logger: Logger, summary: dict, frame: int) -> None:
    """An evaluation's ``eval/score`` (mean), ``eval/score_std`` and, when summarised, ``eval/belief_error``
    (metres) at step ``frame``."""
    logger.log_scalar("eval/score", summary["score_mean"], step=frame)
    logger.log_scalar("eval/score_std", summary["score_std"], step=frame)
    if "belief_error" in summary:
        logger.log_scalar("eval/belief_error", summary["belief_error"], step=frame)


def search_objective(eval_scores: Sequence[float]) -> float | None:
    """What an ``aia-train`` run returns to a Hydra sweeper (optuna search: ``hydra/sweeper=``): the mean of the
    last 10 % of ``eval_scores`` (at least one), the level the policy has reached at the end of training, less
    noisy than the final evaluation alone and the same "end of training" level that ``aia-log plot`` tables
    report (:func:`aia.logging.curves.tail_mean`). Higher is better, so a search maximises it
    (``hydra/sweeper=paper_search``). ``None`` for a run that never evaluated: the optuna sweeper records it as a
    failed trial and goes on (NaN made hydra-optuna-sweeper 1.3.0 with optuna 2.10 end the search with a
    traceback: optuna fails the trial, and the sweeper then tells it again with its value)."""
    return tail_mean(list(eval_scores)) if len(eval_scores) else None
