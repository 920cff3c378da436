"""The objective an ``aia-train`` run returns to a Hydra sweeper (optuna search: ``hydra/sweeper=``).

A run's objective is the mean of the last 10 % of its evaluation scores (at least the last one): the level
the policy has reached at the end of training, less noisy than the final evaluation alone. It is the same
"end of training" level that ``aia-log plot`` tables report (:func:`aia.logging.curves.tail_mean`). Higher
is better, so a search maximises it (``hydra.sweeper.direction=maximize``, set by ``hydra/sweeper=paper_search``).
"""

from __future__ import annotations

from collections.abc import Sequence

from aia.logging.curves import tail_mean


def search_objective(eval_scores: Sequence[float]) -> float:
    """Mean of the last 10 % of ``eval_scores`` (at least one); NaN for a run that never evaluated, which
    optuna records as a failed trial rather than a score."""
    return tail_mean(list(eval_scores))
