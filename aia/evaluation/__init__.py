"""Evaluation: what a policy scores and how it is played.

``scores`` (an episode's score, SPEC 9, belief errors, an evaluation's summary and log scalars, a run's search
objective), ``rollouts`` (one episode in every world of a batched env), ``in_training`` (:class:`Evaluator`: the
training loop's evaluations of every member, several per batched rollout), ``standalone`` (policies scored
outside training: a checkpoint's, the planner's, scripted ones; ``aia-eval`` and ``aia-rollout``),
``checkpoints`` (a checkpoint as ``aia-eval`` reads it, and its observation layout's guard).

Every name loads on first use, so that the apps import ``standalone`` and ``checkpoints`` (whose functions load
torch when called) before their config is valid.
"""

from typing import TYPE_CHECKING

from aia.runtime.lazy import lazy_names

if TYPE_CHECKING:
    from aia.evaluation.in_training import EvaluationPoint, Evaluator
    from aia.evaluation.rollouts import run_episodes
    from aia.evaluation.scores import (
        belief_errors,
        episode_scores,
        evaluation_summary,
        log_score_summary,
        score_summary,
        search_objective,
    )

__getattr__ = lazy_names(__name__, {
    "EvaluationPoint": "aia.evaluation.in_training", "Evaluator": "aia.evaluation.in_training",
    "run_episodes": "aia.evaluation.rollouts", "belief_errors": "aia.evaluation.scores",
    "episode_scores": "aia.evaluation.scores", "evaluation_summary": "aia.evaluation.scores",
    "log_score_summary": "aia.evaluation.scores", "score_summary": "aia.evaluation.scores",
    "search_objective": "aia.evaluation.scores"})

__all__ = ["EvaluationPoint", "Evaluator", "belief_errors", "episode_scores", "evaluation_summary",
           "log_score_summary", "run_episodes", "score_summary", "search_objective"]
