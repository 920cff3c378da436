"""Learning curves across runs as a figure, and their markdown table: what ``aia-log plot`` draws and prints."""

from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING

from aia.logging.curves import TAIL_FRACTION, Curve, baseline_level, first_reaching, learning_curves
from aia.logging.reader import RunLog
from aia.logging.stats import STATISTICS, StatsConfig, check_runs, curve_bands, level_estimates, levels_of

if TYPE_CHECKING:
    from matplotlib.figure import Figure

X_LABELS = {"frame": "training frames", "episode": "training episodes", "evaluation": "evaluation"}
BASELINE_STYLES = ("--", ":", "-.")

Baseline = tuple[str, float, float, int]  # label, mean, std, number of values


def curves_figure(runs: Sequence[RunLog], metric: str, group_by: Sequence[str], window: int, x_axis: str,
                  title: str | None = None, baselines: Sequence[tuple[str, Sequence[RunLog]]] = (),
                  bootstrap: StatsConfig | None = None) -> tuple[Figure, list[Curve]]:
    """The learning curves (mean line, +-1 std band; with ``bootstrap``, the config's statistic and its
    stratified-bootstrap CI band) of ``runs`` grouped by ``group_by``, with each of ``baselines`` (label, runs)
    as a horizontal line and band: the mean and +-1 std of all its values, or with ``bootstrap`` the statistic
    of its runs' levels and its CI (as ``aia-log stats`` gives them). Returns the figure (no pyplot state: the
    caller saves it) and the curves."""
    from matplotlib.figure import Figure

    curves = learning_curves(runs, metric, group_by, window, x_axis)
    bands = curve_bands(runs, metric, group_by, window, x_axis, bootstrap) if bootstrap else []
    figure = Figure(figsize=(7, 4.5), dpi=120)
    axes = figure.subplots()
    for band in bands:
        line, = axes.plot(band.x, band.centre, label=f"{band.label} ({band.runs} runs, {bootstrap.statistic_name} "
                                                     f"and {bootstrap.ci_level:.0%} CI)")
        axes.fill_between(band.x, band.low, band.high, color=line.get_color(), alpha=0.2)
    for curve in curves if not bands else ():
        line, = axes.plot(curve.x, curve.mean, label=f"{curve.label} ({int(curve.runs.max())} runs)")
        axes.fill_between(curve.x, curve.mean - curve.std, curve.mean + curve.std, color=line.get_color(), alpha=0.2)
    for k, (label, members) in enumerate(baselines):
        style = BASELINE_STYLES[k % len(BASELINE_STYLES)]
        if bootstrap:
            check_runs(label, len(members), bootstrap)
            estimate = level_estimates(levels_of(members, metric), bootstrap)[STATISTICS.index(bootstrap.statistic)]
            centre, low, high = estimate.value, estimate.low, estimate.high
            label = f"{label} ({len(members)} runs, {bootstrap.statistic_name} and {bootstrap.ci_level:.0%} CI)"
        else:
            mean, std, count = baseline_level(members, metric)
            centre, low, high, label = mean, mean - std, mean + std, f"{label} ({count} values)"
        axes.axhline(centre, color="black", linestyle=style, label=label)
        axes.axhspan(low, high, color="black", alpha=0.08)
    axes.set_xlabel(X_LABELS[x_axis])
    axes.set_ylabel(metric + (f" (moving average of {window})" if window > 1 else ""))
    axes.set_title(title or metric)
    axes.grid(alpha=0.3)
    axes.legend(fontsize="small")
    figure.tight_layout()
    return figure, curves


def results_table(curves: Sequence[Curve], metric: str, x_axis: str, baselines: Sequence[Baseline] = (),
                  lower_better: bool = False) -> str:
    """A markdown table: per group, its runs, the final mean and std of the (smoothed) ``metric``, the mean
    and std over runs of each run's last 10 % of values and, per baseline, where the mean first reaches the
    baseline's mean (rises to it, or falls to it when ``lower_better``)."""
    header = (f"| group | runs | final {metric} (mean +- std over runs) "
              f"| last {TAIL_FRACTION:.0%} of evaluations (mean +- std over runs) |")
    rule = "|---|---:|---:|---:|"
    verb = "fall to" if lower_better else "reach"
    for label, mean, std, _ in baselines:
        header += f" {X_LABELS[x_axis]} to {verb} {label} ({mean:.1f} +- {std:.1f}) |"
        rule += "---:|"
    rows = [header, rule]
    for curve in curves:
        row = (f"| {curve.label} | {int(curve.runs.max())} | {curve.mean[-1]:.1f} +- {curve.std[-1]:.1f} "
               f"| {curve.tails.mean():.1f} +- {curve.tails.std():.1f} |")
        for _, mean, _, _ in baselines:
            reached = first_reaching(curve, mean, lower_better)
            row += f" {'never' if reached is None else f'{reached:.0f}'} |"
        rows.append(row)
    return "\n".join(rows)
