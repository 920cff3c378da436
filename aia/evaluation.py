"""Episode scores (SPEC 9) from rollout tensordicts."""

from __future__ import annotations

from collections.abc import Callable

import torch
from tensordict import TensorDictBase
from torch import Tensor
from torchrl.envs import EnvBase
from torchrl.record.loggers import Logger


def episode_scores(rollout: TensorDictBase) -> Tensor:
    """``[B]`` scores of a ``[B, T]`` rollout that covers one episode per world: the sum over steps of
    ``-mean_i log det Sigma_i`` (SPEC 9; the mean over targets is the reference's convention)."""
    return -rollout.get(("next", "logdet_cov")).mean(-1).sum(-1)


def score_summary(scores: Tensor) -> dict:
    """``score_mean``, ``score_std`` (population std, as the learning curves' band) and the ``scores`` of a
    batch of episodes, as Python numbers."""
    return {"score_mean": scores.mean().item(), "score_std": scores.std(correction=0).item(),
            "scores": scores.tolist()}


def log_score_summary(logger: Logger, summary: dict, frame: int) -> None:
    """An evaluation's ``eval/score`` (mean) and ``eval/score_std`` at step ``frame``."""
    logger.log_scalar("eval/score", summary["score_mean"], step=frame)
    logger.log_scalar("eval/score_std", summary["score_std"], step=frame)


def run_episodes(env: EnvBase, policy: Callable[[TensorDictBase], TensorDictBase], seed: int | None = None
                 ) -> TensorDictBase:
    """One episode in every world of ``env`` under ``policy``: a ``[B, T]`` rollout from a fresh reset."""
    if seed is not None:
        env.set_seed(seed)
    max_steps = env.base_env.config.max_steps if hasattr(env, "base_env") else env.config.max_steps
    with torch.no_grad():
        return env.rollout(max_steps, policy=policy, break_when_any_done=False)
