"""aia.objective: the objective a run returns to a sweeper."""

from __future__ import annotations

import math

import pytest

from aia.objective import search_objective


@pytest.mark.parametrize("scores, expected", [
    ([5.0], 5.0),                              # a single evaluation is its own tail
    ([1.0, 2.0, 3.0], 3.0),                    # under 10 evaluations: the last one
    (list(range(20)), 18.5),                   # 20 evaluations: the mean of the last 2
    ([0.0] * 90 + [10.0] * 9 + [-80.0], 1.0),  # 100 evaluations: the last 10, a late drop included
])
def test_the_objective_is_the_mean_of_the_last_tenth(scores, expected):
    assert search_objective(scores) == pytest.approx(expected)


def test_a_run_without_evaluations_has_no_objective():
    assert math.isnan(search_objective([]))
