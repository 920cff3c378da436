"""Learning curves: moving averages and the mean and std over runs."""

from __future__ import annotations

import numpy as np
import pytest

from aia.logging.curves import aggregate, first_reaching, lower_is_better, moving_average, tail_mean


def test_moving_average_is_trailing_with_a_short_start():
    assert moving_average(np.array([1.0, 2.0, 3.0, 4.0, 10.0]), 2).tolist() == [1.0, 1.5, 2.5, 3.5, 7.0]
    assert moving_average(np.array([1.0, 5.0]), 1).tolist() == [1.0, 5.0]
    with pytest.raises(ValueError, match="window=0"):
        moving_average(np.ones(3), 0)


def test_aggregate_three_runs_of_different_lengths():
    runs = [(np.array([10.0, 20.0, 30.0]), np.array([1.0, 2.0, 3.0])),
            (np.array([10.0, 20.0, 30.0]), np.array([3.0, 4.0, 8.0])),
            (np.array([12.0, 22.0]), np.array([5.0, 9.0]))]
    curve = aggregate("dqn", runs)
    assert curve.runs.tolist() == [3, 3, 2]
    assert curve.mean.tolist() == pytest.approx([3.0, 5.0, 5.5])
    assert curve.std.tolist() == pytest.approx([np.std([1, 3, 5]), np.std([2, 4, 9]), np.std([3, 8])])
    assert curve.x.tolist() == pytest.approx([32 / 3, 62 / 3, 30.0])
    assert curve.tails.tolist() == [3.0, 8.0, 9.0]  # 10 % of 2-3 values: the last one
    smoothed = aggregate("dqn", runs, window=2)
    assert smoothed.tails.tolist() == curve.tails.tolist()  # raw values, not smoothed
    assert smoothed.mean[1] == pytest.approx(np.mean([1.5, 3.5, 7.0]))


def test_tail_mean_is_over_the_last_tenth():
    assert tail_mean(np.arange(20.0)) == pytest.approx(18.5)  # the last 2 of 20
    assert tail_mean(np.arange(200.0)) == pytest.approx(np.mean(np.arange(180.0, 200.0)))
    assert tail_mean(np.array([4.0])) == 4.0
    assert np.isnan(tail_mean(np.array([])))


def test_first_reaching_rises_or_falls_to_the_level():
    curve = aggregate("adfq", [(np.array([10.0, 20.0, 30.0, 40.0]), np.array([9.0, 4.0, 6.0, 2.0]))])
    assert first_reaching(curve, 5.0) == 10.0            # higher is better: 9 >= 5 at once
    assert first_reaching(curve, 7.0, lower_better=True) == 20.0   # 4 <= 7 first at x = 20
    assert first_reaching(curve, 3.0, lower_better=True) == 40.0
    assert first_reaching(curve, 1.0, lower_better=True) is None
    assert first_reaching(curve, 10.0) is None


def test_errors_and_losses_improve_downwards():
    assert lower_is_better("eval/belief_error") and lower_is_better("train/loss") and lower_is_better("td_error")
    assert not lower_is_better("eval/score") and not lower_is_better("train/frames_per_s")
    assert not lower_is_better("error_rate/score")  # only the last part of the name counts
