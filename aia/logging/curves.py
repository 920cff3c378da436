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
    return Curve(label, x_mean, mean, std, counts)


def group_label(run: RunLog, keys: Sequence[str]) -> str:
    """``"algo=adfq, exploration=thompson"`` for ``keys=["algo", "exploration"]`` (``"all"`` without keys)."""
    return ", ".join(f"{key}={run.config_value(key)}" for key in keys) or "all"


def learning_curves(runs: Sequence[RunLog], metric: str, group_by: Sequence[str] = (), window: int = 1
                    ) -> list[Curve]:
    """One :class:`Curve` of ``metric`` per group of ``runs`` (grouped by the config values at
    ``group_by``), sorted by label."""
    groups: dict[str, list[tuple[np.ndarray, np.ndarray]]] = {}
    for run in runs:
        series = run.scalars(metric)
        groups.setdefault(group_label(run, group_by), []).append((series.frames, series.values))
    return [aggregate(label, groups[label], window) for label in sorted(groups)]
