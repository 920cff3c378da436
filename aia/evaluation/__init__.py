"""Evaluation: what a policy scores and how it is played.

``scores`` (an episode's score, SPEC 9, belief errors, an evaluation's summary and log scalars, a run's search
objective), ``rollouts`` (one episode in every world of a batched env), ``in_training`` (:class:`Evaluator`: the
training loop's evaluations of every member, several per batched rollout).
"""

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

__all__ = ["EvaluationPoint", "Evaluator", "belief_errors", "episode_scores", "evaluation_summary",
           "log_score_summary", "run_episodes", "score_summary", "search_objective"]
