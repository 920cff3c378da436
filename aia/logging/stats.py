"""Statistics over runs through ``rliable`` (Agarwal et al., "Deep RL at the Edge of the Statistical Precipice",
NeurIPS 2021): per group of runs, the interquartile mean (IQM) and the mean of the runs' final levels with
stratified-bootstrap confidence intervals, the probability of improvement over a baseline, a verdict
(above / below / undecided) decided from a confidence interval, the first x at which the group's curve reaches
the baseline, and confidence bands of learning curves.

A run's *level* is the mean of its last 10 % of values (``curves.TAIL_FRACTION``, as ``aia-log plot``'s table):
an end-of-training level that one lucky evaluation does not decide. A baseline run (``aia-eval policy=arvi``)
logs one value, which is its level.

Every interval is ``rliable.library.get_interval_estimates`` (its stratified bootstrap, percentile intervals).
rliable draws its resamples from numpy's global generator, so each call here seeds it with ``StatsConfig.seed``
and puts the caller's state back: an interval depends only on its data and the config, not on what ran before.
numpy's generator, scipy and rliable are imported on first use: ``aia-log``'s other commands load none of them.

The statistics inside the bootstrap are computed here in numpy instead of with rliable's metric functions, which
call scipy (``aggregate_iqm``: ``scipy.stats.trim_mean``; ``probability_of_improvement``: the Mann-Whitney U
test), whose argument handling costs 0.2-0.5 ms a call: 2,000 resamples of 4 groups and a baseline took 11 s
with them. tests/logging/test_stats.py checks them equal to rliable's functions, and the intervals equal to
``get_interval_estimates`` called with rliable's functions.
"""

from __future__ import annotations

import contextlib
import math
from collections.abc import Callable, Iterator, Sequence
from dataclasses import asdict, dataclass, field

import numpy as np

from aia.logging.curves import TAIL_FRACTION, group_label, moving_average, run_x, tail_mean
from aia.logging.reader import RunLog

STATISTICS = ("iqm", "mean")          # the aggregate over runs that verdicts, curves and first-reaching use
VERDICT_BY = ("poi", "difference")    # what a verdict is read from: the probability of improvement or the difference
VERDICTS = ("above", "below", "undecided")
# Fewest runs per group (and per baseline) each statistic needs: the IQM trims a quarter of the runs at each end,
# which removes a run only from 4 runs on (with fewer it is the mean); a bootstrap interval needs 2 runs.
MIN_RUNS = {"iqm": 4, "mean": 2}
IQM_CUT = 0.25                        # rliable's IQM: the 25 % trimmed mean


@dataclass(frozen=True)
class StatsConfig:
    """How the statistics are computed; the defaults are ``aia-log stats``'s and are documented in docs/logging.md.

    statistic: ``iqm`` (interquartile mean over runs, rliable's recommendation) or ``mean``; the verdict's
        difference, the curves' centre line and band, and first-reaching use it.
    reps: bootstrap resamples per interval (2,000: rliable's count for the probability of improvement).
    ci_level: coverage of every interval (0.95).
    seed: numpy's global seed before each interval (rliable resamples with it).
    verdict_by: ``poi``: the interval of the probability of improvement over the baseline against
        ``poi_threshold``; ``difference``: the interval of statistic(group) - statistic(baseline) against
        ``difference_threshold``. Above when the interval lies wholly above the threshold, below when wholly
        below, undecided when it contains it.
    """

    statistic: str = "iqm"
    reps: int = 2000
    ci_level: float = 0.95
    seed: int = 0
    verdict_by: str = "poi"
    poi_threshold: float = 0.5
    difference_threshold: float = 0.0

    def __post_init__(self) -> None:
        for name, value, allowed in (("statistic", self.statistic, STATISTICS),
                                     ("verdict_by", self.verdict_by, VERDICT_BY)):
            if value not in allowed:
                raise ValueError(f"{_option(name)} {value!r}: expected one of {', '.join(allowed)}")
        if not isinstance(self.reps, int) or self.reps < 10:
            raise ValueError(f"{_option('reps')} {self.reps!r}: expected an integer >= 10")
        if not 0 < self.ci_level < 1:
            raise ValueError(f"{_option('ci_level')} {self.ci_level!r}: expected a number in (0, 1), e.g. 0.95")
        if not 0 <= self.poi_threshold <= 1:
            raise ValueError(f"{_option('poi_threshold')} {self.poi_threshold!r}: expected a probability in [0, 1]")
        if not math.isfinite(self.difference_threshold):
            raise ValueError(f"{_option('difference_threshold')} {self.difference_threshold!r}: expected a finite "
                             "number")

    @property
    def statistic_name(self) -> str:
        """The statistic as tables and legends name it: ``IQM`` or ``mean``."""
        return "IQM" if self.statistic == "iqm" else self.statistic

    @property
    def threshold(self) -> float:
        """The verdict's threshold (that of ``verdict_by``)."""
        return self.poi_threshold if self.verdict_by == "poi" else self.difference_threshold


def _option(name: str) -> str:
    return "--" + name.replace("_", "-")


@dataclass
class Estimate:
    """A point estimate and its confidence interval ``[low, high]``."""

    value: float
    low: float
    high: float

    def text(self, digits: int = 1) -> str:
        return f"{self.value:.{digits}f} [{self.low:.{digits}f}, {self.high:.{digits}f}]"


@dataclass
class Reaching:
    """The first x at which a group's statistic curve reaches a baseline's statistic, and its interval; None
    stands for "never" (not within the curve)."""

    value: float | None
    low: float | None
    high: float | None

    def text(self) -> str:
        def fmt(x: float | None) -> str:
            return "never" if x is None else f"{x:.0f}"
        return f"{fmt(self.value)} [{fmt(self.low)}, {fmt(self.high)}]"


@dataclass
class Comparison:
    """A group against one baseline."""

    baseline: str
    poi: Estimate               # P(a run of the group > a run of the baseline), ties counting half
    difference: Estimate        # statistic(group) - statistic(baseline)
    verdict: str                # above / below / undecided
    reaching: Reaching | None   # None where the runs hold one evaluation each (aia-eval's): no curve to reach along


@dataclass
class GroupStats:
    """A group's (or a baseline's) runs, their levels and the aggregates with their intervals."""

    label: str
    runs: int
    levels: np.ndarray
    iqm: Estimate | None        # None for fewer runs than the IQM needs (MIN_RUNS)
    mean: Estimate
    comparisons: list[Comparison] = field(default_factory=list)


# --- numbers ------------------------------------------------------------------------------------------------

def probability_of_improvement(scores_x: np.ndarray, scores_y: np.ndarray) -> float:
    """rliable's ``metrics.probability_of_improvement`` (``[runs, tasks]`` each): P(X > Y) + P(X = Y) / 2 per task,
    averaged over tasks; the Mann-Whitney U statistic over ``runs_x * runs_y``, counted directly."""
    x, y = scores_x[:, None, :], scores_y[None, :, :]
    pairs = scores_x.shape[0] * scores_y.shape[0]
    return float(np.mean(((x > y).sum((0, 1)) + 0.5 * (x == y).sum((0, 1))) / pairs))


def iqm(scores: np.ndarray, axis: int | None = None) -> np.ndarray | float:
    """The interquartile mean: rliable's ``metrics.aggregate_iqm`` (scipy's 25 % trimmed mean: ``int(n / 4)``
    values cut at each end) over all values (``axis=None``) or along ``axis``."""
    values = np.asarray(scores, dtype=float)
    if axis is None:
        values, axis = values.reshape(-1), 0
    count = values.shape[axis]
    cut = int(IQM_CUT * count)
    return np.sort(values, axis=axis).take(np.arange(cut, count - cut), axis=axis).mean(axis=axis)


def aggregate(statistic: str) -> Callable[[np.ndarray], float]:
    """The statistic of a ``[runs, tasks]`` score matrix: rliable's ``aggregate_iqm`` or ``aggregate_mean``."""
    if statistic == "iqm":
        return iqm
    return lambda scores: float(np.mean(np.mean(scores, axis=0)))


def column_statistic(statistic: str) -> Callable[[np.ndarray], np.ndarray]:
    """The statistic over runs (axis 0) of every column of a ``[runs, points]`` matrix: per column, what
    :func:`aggregate` gives for that column alone."""
    if statistic == "iqm":
        return lambda scores: iqm(scores, axis=0)
    return lambda scores: np.mean(scores, axis=0)


@contextlib.contextmanager
def _seeded(seed: int) -> Iterator[None]:
    """numpy's global generator seeded with ``seed``, the caller's state restored after."""
    state = np.random.get_state()
    np.random.seed(seed)
    try:
        yield
    finally:
        np.random.set_state(state)


def rliable_modules():
    """``(rliable.library, rliable.metrics)``, imported on first use.

    rliable imports ``absl.logging``, whose handler keeps the ``sys.stderr`` of its import and closes it when
    ``logging`` shuts its handlers down (as Hydra's logging setup does): in a process that swaps ``sys.stderr``
    (pytest's capture, a notebook) that closes someone else's stream. The handler is pointed at the process's
    own stderr, which absl never closes.
    """
    import sys

    from absl import logging as absl_logging
    from rliable import library, metrics

    absl_logging.get_absl_handler().python_handler.stream = sys.__stderr__
    return library, metrics


def interval(scores: np.ndarray | list[np.ndarray], func: Callable[..., np.ndarray], config: StatsConfig
             ) -> tuple[np.ndarray, np.ndarray]:
    """``rliable.library.get_interval_estimates`` of ``func`` on one score matrix (or a list of matrices,
    resampled independently), seeded: the point estimates and the ``[2, ...]`` interval."""
    library, _ = rliable_modules()

    with _seeded(config.seed):
        points, intervals = library.get_interval_estimates(
            {"x": scores}, func, reps=config.reps, confidence_interval_size=config.ci_level)
    return np.asarray(points["x"], dtype=float), np.asarray(intervals["x"], dtype=float)


def level_estimates(levels: np.ndarray, config: StatsConfig) -> tuple[Estimate | None, Estimate]:
    """The IQM and the mean of ``levels`` (one per run) with their stratified-bootstrap intervals; no IQM (None)
    for fewer runs than it needs (``MIN_RUNS``): it would trim nothing, and be the mean under another name."""
    names = [name for name in STATISTICS if len(levels) >= MIN_RUNS[name]]
    functions = [aggregate(name) for name in names]
    points, cis = interval(levels[:, None], lambda s: np.array([f(s) for f in functions]), config)
    estimates = {name: Estimate(points[k], cis[0, k], cis[1, k]) for k, name in enumerate(names)}
    return estimates.get("iqm"), estimates["mean"]


def verdict(estimate: Estimate, threshold: float) -> str:
    """``above`` when the interval lies wholly above ``threshold``, ``below`` when wholly below, else
    ``undecided``."""
    if estimate.low > threshold:
        return "above"
    if estimate.high < threshold:
        return "below"
    return "undecided"


def first_index(curve: np.ndarray, level: float, lower_better: bool) -> int:
    """The first index at which ``curve`` reaches ``level`` (rises to it, or falls to it when ``lower_better``);
    ``len(curve)`` when it never does."""
    reached = np.flatnonzero(curve <= level if lower_better else curve >= level)
    return int(reached[0]) if reached.size else len(curve)


def compare(label: str, levels: np.ndarray, curves: np.ndarray, x: np.ndarray, baseline: str,
            baseline_levels: np.ndarray, config: StatsConfig, lower_better: bool = False) -> Comparison:
    """A group (``levels [runs]``, smoothed ``curves [runs, points]`` at ``x [points]``) against a baseline's
    levels: the probability of improvement, the difference of the statistic, the verdict, and the first x at which
    the group's statistic curve reaches the baseline's statistic. One independent stratified bootstrap of the
    group's runs (whole runs: a run's curve stays together) and the baseline's runs gives all intervals."""
    statistic, per_point = aggregate(config.statistic), column_statistic(config.statistic)

    def func(group_ids: np.ndarray, baseline_ids: np.ndarray) -> np.ndarray:
        x_levels, y_levels = levels[group_ids[:, 0]][:, None], baseline_levels[baseline_ids[:, 0]][:, None]
        level = statistic(y_levels)
        return np.array([probability_of_improvement(x_levels, y_levels), statistic(x_levels) - level,
                         first_index(per_point(curves[group_ids[:, 0]]), level, lower_better)], dtype=float)

    # the bootstrap resamples run indices (rliable draws them exactly as it would draw the levels themselves)
    points, cis = interval([np.arange(len(levels))[:, None], np.arange(len(baseline_levels))[:, None]], func, config)
    poi = Estimate(points[0], cis[0, 0], cis[1, 0])
    difference = Estimate(points[1], cis[0, 1], cis[1, 1])
    decided = poi if config.verdict_by == "poi" else difference
    end = len(x)

    def at(index: float) -> float | None:
        return None if index >= end else float(x[int(index)])

    reaching = Reaching(at(points[2]), at(math.floor(cis[0, 2])), at(math.ceil(cis[1, 2]))) if end > 1 else None
    return Comparison(baseline, poi, difference, verdict(decided, config.threshold), reaching)


def curve_band(curves: np.ndarray, config: StatsConfig) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The statistic over runs at each point of ``curves [runs, points]`` and its pointwise stratified-bootstrap
    interval (each point's runs resampled, as rliable's sample-efficiency curves): centre, low, high."""
    points, cis = interval(curves, column_statistic(config.statistic), config)
    return points, cis[0], cis[1]


# --- runs ---------------------------------------------------------------------------------------------------

def levels_of(runs: Sequence[RunLog], metric: str) -> np.ndarray:
    """Each run's level: the mean of its last 10 % of ``metric`` values."""
    return np.array([tail_mean(run.scalars(metric).values, TAIL_FRACTION) for run in runs])


def curves_of(runs: Sequence[RunLog], metric: str, window: int = 1, x_axis: str = "frame"
              ) -> tuple[np.ndarray, np.ndarray]:
    """The runs' curves, each smoothed by a trailing moving average of ``window``, aligned by evaluation index
    and cut to the shortest run: x (the mean over runs at each index) ``[points]`` and values ``[runs, points]``."""
    series = [run.scalars(metric) for run in runs]
    length = min(len(s.values) for s in series)
    values = np.stack([moving_average(s.values, window)[:length] for s in series])
    xs = np.stack([run_x(run, s.frames, x_axis)[:length] for run, s in zip(runs, series, strict=True)])
    return np.nanmean(xs, axis=0) if np.isfinite(xs).any() else np.arange(1.0, length + 1), values


def group_runs(runs: Sequence[RunLog], group_by: Sequence[str]) -> dict[str, list[RunLog]]:
    """The runs per group label (config values at ``group_by``), sorted by label."""
    groups: dict[str, list[RunLog]] = {}
    for run in runs:
        groups.setdefault(group_label(run, group_by), []).append(run)
    return {label: groups[label] for label in sorted(groups)}


def check_runs(label: str, count: int, config: StatsConfig) -> None:
    """ValueError when a group has fewer runs than the statistic needs."""
    need = MIN_RUNS[config.statistic]
    if count < need:
        allowed = ", ".join(f"{name} needs {n}" for name, n in MIN_RUNS.items())
        raise ValueError(f"{label!r} has {count} run{'s' * (count != 1)}: --statistic {config.statistic} needs at "
                         f"least {need} ({allowed})")


def group_stats(runs: Sequence[RunLog], metric: str, group_by: Sequence[str] = (),
                baselines: Sequence[tuple[str, Sequence[RunLog]]] = (), config: StatsConfig | None = None,
                window: int = 1, x_axis: str = "frame", lower_better: bool = False
                ) -> tuple[list[GroupStats], list[GroupStats]]:
    """Per group of ``runs`` (by the config values at ``group_by``): its levels' IQM and mean with intervals and
    its comparison with each of ``baselines`` (label, runs); and the same statistics of each baseline."""
    config = config or StatsConfig()
    groups = group_runs(runs, group_by)
    for label, members in [*groups.items(), *baselines]:
        check_runs(label, len(members), config)
    baseline_stats = []
    for label, members in baselines:
        levels = levels_of(members, metric)
        baseline_stats.append(GroupStats(label, len(members), levels, *level_estimates(levels, config)))
    results = []
    for label, members in groups.items():
        levels = levels_of(members, metric)
        stats = GroupStats(label, len(members), levels, *level_estimates(levels, config))
        if baseline_stats:
            x, curves = curves_of(members, metric, window, x_axis)
            stats.comparisons = [compare(label, levels, curves, x, base.label, base.levels, config, lower_better)
                                 for base in baseline_stats]
        results.append(stats)
    return results, baseline_stats


@dataclass
class Band:
    """A group's learning curve as the statistic over its runs at each evaluation index, with its pointwise
    interval (up to the shortest run's length)."""

    label: str
    runs: int
    x: np.ndarray
    centre: np.ndarray
    low: np.ndarray
    high: np.ndarray


def curve_bands(runs: Sequence[RunLog], metric: str, group_by: Sequence[str] = (), window: int = 1,
                x_axis: str = "frame", config: StatsConfig | None = None) -> list[Band]:
    """Per group of ``runs``: the statistic of the smoothed curves at each evaluation index and its
    stratified-bootstrap interval (``aia-log plot --ci bootstrap``)."""
    config = config or StatsConfig()
    bands = []
    for label, members in group_runs(runs, group_by).items():
        check_runs(label, len(members), config)
        x, curves = curves_of(members, metric, window, x_axis)
        bands.append(Band(label, len(members), x, *curve_band(curves, config)))
    return bands


# --- output -------------------------------------------------------------------------------------------------

def stats_table(groups: Sequence[GroupStats], baselines: Sequence[GroupStats], metric: str, config: StatsConfig,
                x_label: str = "training frames", lower_better: bool = False) -> str:
    """A markdown table: per group, runs, IQM and mean of the levels, and per baseline the probability of
    improvement, the difference of the statistic, the verdict and the x at which the group reaches the
    baseline, each with its interval; then one row per baseline."""
    level = f"{config.ci_level:.0%} CI"
    header = f"| group | runs | IQM [{level}] | mean [{level}] |"
    rule = "|---|---:|---:|---:|"
    verb = "fall to" if lower_better else "reach"
    statistic = config.statistic_name
    # the column of the x reaching each baseline, unless no group has a curve (one evaluation per run)
    reaching = any(c.reaching is not None for group in groups for c in group.comparisons)
    for base in baselines:
        header += f" P(above {base.label}) [{level}] | {statistic} - {base.label} [{level}] | vs {base.label} |"
        rule += "---:|---:|---|"
        if reaching:
            header += f" {x_label} to {verb} {base.label} [{level}] |"
            rule += "---:|"
    rows = [header, rule]
    for group in groups:
        row = f"| {group.label} | {group.runs} | {_iqm_text(group)} | {group.mean.text()} |"
        for comparison in group.comparisons:
            row += f" {comparison.poi.text(2)} | {comparison.difference.text()} | {comparison.verdict} |"
            if reaching:
                row += f" {comparison.reaching.text() if comparison.reaching else ''} |"
        rows.append(row)
    for base in baselines:
        rows.append(f"| {base.label} (baseline) | {base.runs} | {_iqm_text(base)} | {base.mean.text()} |"
                    + " |" * ((3 + reaching) * len(baselines)))
    return "\n".join(rows)


def _iqm_text(group: GroupStats) -> str:
    return group.iqm.text() if group.iqm else f"(needs {MIN_RUNS['iqm']} runs)"


def describe(metric: str, config: StatsConfig) -> str:
    """The line above ``stats_table``: what a level is, how the intervals were drawn and what decides a verdict."""
    rule = (f"P(improvement) interval against {config.poi_threshold:g}" if config.verdict_by == "poi" else
            f"{config.statistic} difference interval against {config.difference_threshold:g}")
    return (f"{metric}: each run's level is its mean over the last {TAIL_FRACTION:.0%} of evaluations; "
            f"{config.ci_level:.0%} stratified-bootstrap CIs (rliable, {config.reps} resamples, seed {config.seed}); "
            f"verdict: {rule}")


def stats_json(groups: Sequence[GroupStats], baselines: Sequence[GroupStats], metric: str, config: StatsConfig
               ) -> dict:
    """The same as :func:`stats_table` as plain data: the config, one object per group and per baseline."""
    def estimate(e: Estimate) -> dict:
        return {"estimate": e.value, "ci": [e.low, e.high]}

    def group(g: GroupStats) -> dict:
        data = {"group": g.label, "runs": g.runs, "levels": g.levels.tolist(), "iqm": g.iqm and estimate(g.iqm),
                "mean": estimate(g.mean)}
        if g.comparisons:
            data["comparisons"] = [
                {"baseline": c.baseline, "probability_of_improvement": estimate(c.poi),
                 "difference": estimate(c.difference), "verdict": c.verdict,
                 "first_reaching": c.reaching and {"estimate": c.reaching.value,
                                                   "ci": [c.reaching.low, c.reaching.high]}}
                for c in g.comparisons]
        return data

    return {"metric": metric, "level": f"mean of each run's last {TAIL_FRACTION:.0%} of values",
            "config": asdict(config), "groups": [group(g) for g in groups], "baselines": [group(b) for b in baselines]}
