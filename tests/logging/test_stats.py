"""Statistics over runs (aia/logging/stats.py): equal to rliable called directly, and the verdict rule."""

from __future__ import annotations

import numpy as np
import pytest

from aia.logging.stats import (
    Estimate,
    StatsConfig,
    compare,
    curve_band,
    first_index,
    iqm,
    level_estimates,
    probability_of_improvement,
    rliable_modules,
    verdict,
)

library, metrics = rliable_modules()

REPS = 300  # small: every interval below is checked against rliable with the same resamples, not for its coverage


def _rliable(scores, func, seed, reps=REPS):
    """rliable's interval of ``func``, numpy's global generator seeded as aia.logging.stats does."""
    np.random.seed(seed)
    points, intervals = library.get_interval_estimates({"x": scores}, func, reps=reps)
    return points["x"], intervals["x"]


def test_the_numpy_statistics_equal_rliables_functions():
    rng = np.random.default_rng(0)
    for runs in (3, 4, 5, 7, 20):
        scores = rng.normal(size=(runs, 1)).round(1)  # rounded: ties
        other = rng.normal(size=(runs + 2, 1)).round(1)
        assert iqm(scores) == pytest.approx(metrics.aggregate_iqm(scores), rel=1e-12)
        assert probability_of_improvement(scores, other) == pytest.approx(
            metrics.probability_of_improvement(scores, other), rel=1e-12)
    assert probability_of_improvement(scores, scores) == 0.5
    curves = rng.normal(size=(9, 30))
    per_point = [metrics.aggregate_iqm(curves[:, [k]]) for k in range(30)]
    assert iqm(curves, axis=0) == pytest.approx(per_point, rel=1e-12)


def test_level_intervals_equal_rliable_on_the_same_score_matrix():
    levels = np.random.default_rng(1).normal(1000.0, 300.0, size=12)
    config = StatsConfig(reps=REPS, seed=7)
    state = np.random.get_state()
    iqm_estimate, mean_estimate = level_estimates(levels, config)
    assert all(np.array_equal(a, b) for a, b in zip(np.random.get_state(), state, strict=True))  # caller's state kept
    points, cis = _rliable(levels[:, None], lambda s: np.array([metrics.aggregate_iqm(s), metrics.aggregate_mean(s)]),
                           seed=7)
    assert [iqm_estimate.value, iqm_estimate.low, iqm_estimate.high] == pytest.approx(
        [points[0], cis[0, 0], cis[1, 0]], rel=1e-12)
    assert [mean_estimate.value, mean_estimate.low, mean_estimate.high] == pytest.approx(
        [points[1], cis[0, 1], cis[1, 1]], rel=1e-12)
    assert level_estimates(levels, StatsConfig(reps=REPS, seed=8))[0].low != iqm_estimate.low  # the seed matters


@pytest.mark.parametrize("statistic", ["iqm", "mean"])
def test_comparison_intervals_equal_rliable_on_the_same_score_matrices(statistic):
    rng = np.random.default_rng(2)
    levels, baseline = rng.normal(1100.0, 200.0, size=8), rng.normal(1000.0, 300.0, size=6)
    curves = np.cumsum(rng.normal(100.0, 50.0, size=(8, 15)), axis=1)
    config = StatsConfig(statistic=statistic, reps=REPS, seed=3)
    comparison = compare("g", levels, curves, np.arange(1.0, 16.0), "base", baseline, config)
    aggregate = metrics.aggregate_iqm if statistic == "iqm" else metrics.aggregate_mean

    def func(x, y):
        return np.array([metrics.probability_of_improvement(x, y), aggregate(x) - aggregate(y)])

    points, cis = _rliable([levels[:, None], baseline[:, None]], func, seed=3)
    assert [comparison.poi.value, comparison.poi.low, comparison.poi.high] == pytest.approx(
        [points[0], cis[0, 0], cis[1, 0]], rel=1e-12)
    assert [comparison.difference.value, comparison.difference.low, comparison.difference.high] == pytest.approx(
        [points[1], cis[0, 1], cis[1, 1]], rel=1e-12)


def test_curve_band_equals_rliable_per_point():
    curves = np.random.default_rng(4).normal(size=(6, 10))
    centre, low, high = curve_band(curves, StatsConfig(reps=REPS, seed=0))
    points, cis = _rliable(curves, lambda s: np.array([metrics.aggregate_iqm(s[:, [k]]) for k in range(10)]), seed=0)
    assert centre == pytest.approx(points, rel=1e-12)
    assert low == pytest.approx(cis[0], rel=1e-12) and high == pytest.approx(cis[1], rel=1e-12)
    assert (low <= centre).all() and (centre <= high).all()


def test_the_verdict_rule():
    assert verdict(Estimate(0.8, 0.6, 0.95), 0.5) == "above"
    assert verdict(Estimate(0.2, 0.05, 0.45), 0.5) == "below"
    assert verdict(Estimate(0.55, 0.3, 0.8), 0.5) == "undecided"
    assert verdict(Estimate(0.7, 0.5, 0.9), 0.5) == "undecided"  # an interval touching the threshold decides nothing


def _verdicts(levels, baseline, **config):
    flat = np.zeros((len(levels), 3))
    comparison = compare("g", np.asarray(levels, float), flat, np.arange(3.0), "base", np.asarray(baseline, float),
                         StatsConfig(reps=REPS, **config))
    return comparison.verdict


def test_hand_made_score_sets_come_out_above_below_and_undecided():
    rng = np.random.default_rng(5)
    baseline = 1000.0 + 50.0 * rng.standard_normal(10)
    above = 1300.0 + 50.0 * rng.standard_normal(10)      # every run above every baseline run
    below = 700.0 + 50.0 * rng.standard_normal(10)
    level = 1000.0 + 50.0 * rng.standard_normal(10)      # the same distribution as the baseline
    for by in ("poi", "difference"):
        assert _verdicts(above, baseline, verdict_by=by) == "above"
        assert _verdicts(below, baseline, verdict_by=by) == "below"
        assert _verdicts(level, baseline, verdict_by=by) == "undecided"
    # the threshold is config: 300 above the baseline is "below" a required margin of 400, undecided at 300
    assert _verdicts(above, baseline, verdict_by="difference", difference_threshold=400.0) == "below"
    assert _verdicts(above, baseline, verdict_by="difference", difference_threshold=300.0) == "undecided"


def test_first_reaching_and_its_interval():
    assert first_index(np.array([1.0, 3.0, 5.0]), 3.0, lower_better=False) == 1
    assert first_index(np.array([1.0, 3.0, 5.0]), 9.0, lower_better=False) == 3  # never: one past the end
    assert first_index(np.array([5.0, 3.0, 1.0]), 2.0, lower_better=True) == 2
    # every run rises by 1 per evaluation from its own start: 0, 1, ..., 7; the baseline sits at 10
    curves = np.arange(20.0)[None, :] + np.arange(8.0)[:, None]
    x = 2.0 * np.arange(1, 21)  # training episodes 2, 4, ...
    comparison = compare("g", curves[:, -1], curves, x, "base", np.full(5, 10.0), StatsConfig(reps=REPS))
    # IQM of the starts (2..5, mean 3.5) reaches 10 at index 7 (10.5), i.e. episode 16
    assert comparison.reaching.value == 16.0
    assert comparison.reaching.low <= 16.0 <= comparison.reaching.high
    never = compare("g", curves[:, -1], curves, x, "base", np.full(5, 99.0), StatsConfig(reps=REPS))
    assert never.reaching.value is None and never.reaching.text() == "never [never, never]"


def test_bad_config_values_are_named_with_the_allowed_ones():
    with pytest.raises(ValueError, match="--statistic 'median': expected one of iqm, mean"):
        StatsConfig(statistic="median")
    with pytest.raises(ValueError, match="--verdict-by 'ci': expected one of poi, difference"):
        StatsConfig(verdict_by="ci")
    with pytest.raises(ValueError, match="--ci-level 95: expected a number in"):
        StatsConfig(ci_level=95)
    with pytest.raises(ValueError, match="--reps 1: expected an integer >= 10"):
        StatsConfig(reps=1)
