"""Learning curves across runs: moving averages, grouping by config keys, mean and std over seeds."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from aia.logging.reader import RunLog


@dataclass
class Curve:
    """A group's learning curve: the mean and the std over its runs at each evaluation index."""

    label: str
    x: np.ndarray       # mean over the runs of the x value (frame) at each index
    mean: np.ndarray
    std: np.ndarray     # population std (ddof 0) over the runs present at that index
    runs: np.ndarray    # how many runs reach each index
    tails: np.ndarray   # per run: the mean of its raw (unsmoothed) values over the last TAIL_FRACTION of them


TAIL_FRACTION = 0.1  # the "end of training" level of a run: its last 10 % of evaluations (at least one)


def tail_mean(values: np.ndarray, fraction: float = TAIL_FRACTION) -> float:
    """Mean of the last ``fraction`` of ``values`` (at least the last one); NaN for no values."""
    values = np.asarray(values, dtype=float)
    if values.size == 0:
        return float("nan")
    return float(values[-max(1, round(fraction * values.size)):].mean())


def moving_average(values: np.ndarray, window: int) -> np.ndarray:
    """Trailing mean over the last ``window`` values (fewer at the start); ``window=1`` is the identity."""
    if window < 1:
        raise ValueError(f"window={window} must be >= 1")
    values = np.asarray(values, dtype=float)
    sums = np.cumsum(np.concatenate(([0.0], values)))
    ends = np.arange(1, len(values) + 1)
    starts = np.maximum(0, ends - window)
    return (sums[ends] - sums[starts]) / (ends - starts)


def aggregate(label: str, series: Sequence[tuple[np.ndarray, np.ndarray]], window: int = 1) -> Curve:
    """Align runs ``(x, values)`` by index (the k-th evaluation of every run), smooth each run with
    :func:`moving_average`, and take the mean and std over the runs that reach each index."""
    if not series:
        raise ValueError(f"group {label!r} has no runs")
    length = max(len(values) for _, values in series)
    xs = np.full((len(series), length), np.nan)
    ys = np.full((len(series), length), np.nan)
    for i, (x, values) in enumerate(series):
        xs[i, : len(x)] = x
        ys[i, : len(values)] = moving_average(values, window)
    present = np.isfinite(ys)
    counts = present.sum(0)
    mean = np.where(present, ys, 0.0).sum(0) / counts
    std = np.sqrt(np.where(present, (ys - mean) ** 2, 0.0).sum(0) / counts)
    x_mean = np.nanmean(np.where(np.isfinite(xs), xs, np.nan), axis=0)
    tails = np.array([tail_mean(values) for _, values in series])
    return Curve(label, x_mean, mean, std, counts, tails)


def group_label(run: RunLog, keys: Sequence[str]) -> str:
    """``"algo=adfq, exploration=thompson"`` for ``keys=["algo", "exploration"]`` (``"all"`` without keys)."""
    return ", ".join(f"{key}={run.config_value(key)}" for key in keys) or "all"


X_AXES = ("frame", "episode", "evaluation")


def run_x(run: RunLog, frames: np.ndarray, x_axis: str) -> np.ndarray:
    """The x values of a run's evaluations: training frames, training episodes (frames over the episode
    length ``env.max_steps``: episodes end only at the time limit) or the evaluation's index (1, 2, ...)."""
    if x_axis == "frame":
        return frames
    if x_axis == "evaluation":
        return np.arange(1, len(frames) + 1, dtype=float)
    if x_axis == "episode":
        length = run.config_value("env.max_steps")
        if not isinstance(length, int) or length < 1:
            raise ValueError(f"{run.path}: no env.max_steps in its config, so no episode axis; use --x frame")
        return frames / length
    raise ValueError(f"x axis {x_axis!r} is not one of {list(X_AXES)}")


def select_runs(runs: Sequence[RunLog], where: Sequence[str]) -> list[RunLog]:
    """The runs whose config matches every ``KEY=VALUE`` of ``where`` (values compared as text)."""
    conditions = []
    for condition in where:
        key, sep, value = condition.partition("=")
        if not sep or not key:
            raise ValueError(f"--where {condition!r} must look like KEY=VALUE, e.g. env.num_targets=2")
        conditions.append((key, value))
    return [run for run in runs if all(str(run.config_value(k)) == v for k, v in conditions)]


def learning_curves(runs: Sequence[RunLog], metric: str, group_by: Sequence[str] = (), window: int = 1,
                    x_axis: str = "frame") -> list[Curve]:
    """One :class:`Curve` of ``metric`` per group of ``runs`` (grouped by the config values at
    ``group_by``), sorted by label."""
    groups: dict[str, list[tuple[np.ndarray, np.ndarray]]] = {}
    for run in runs:
        series = run.scalars(metric)
        groups.setdefault(group_label(run, group_by), []).append((run_x(run, series.frames, x_axis), series.values))
    return [aggregate(label, groups[label], window) for label in sorted(groups)]


def baseline_level(runs: Sequence[RunLog], metric: str) -> tuple[float, float, int]:
    """Mean and std (ddof 0) of every ``metric`` value of ``runs`` (e.g. ARVI's score over its seeds), and
    how many values there are."""
    values = np.concatenate([run.scalars(metric).values for run in runs])
    values = values[np.isfinite(values)]
    if values.size == 0:
        raise ValueError(f"the baseline runs have no finite {metric!r} values")
    return float(values.mean()), float(values.std()), int(values.size)


def lower_is_better(metric: str) -> bool:
    """Whether ``metric`` improves downwards: its last name part mentions an error or a loss
    (``eval/belief_error``, ``train/loss``); scores, returns and rates improve upwards."""
    name = metric.rsplit("/", 1)[-1]
    return any(word in name for word in ("error", "loss"))


def first_reaching(curve: Curve, level: float, lower_better: bool = False) -> float | None:
    """The first x at which the curve's mean reaches ``level``: rises to it or, when ``lower_better``, falls
    to it (None if it never does)."""
    reached = np.flatnonzero(curve.mean <= level if lower_better else curve.mean >= level)
    return float(curve.x[reached[0]]) if reached.size else None
