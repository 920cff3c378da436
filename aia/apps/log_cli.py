"""``aia-log``: inspect aia run logs (MCAP files) from the shell.

    aia-log summary RUN...                         topics, counts, time span, config, recorded episodes, scores
    aia-log scalars RUN... --topic eval/score [--csv scores.csv]
    aia-log plot 'outputs/multirun/**/run.mcap' --metric eval/score --group-by algo --window 4 --out curves.png
    aia-log plot outputs/repro/learners --where env.map=empty --group-by algo --group-by exploration --x episode \\
        --window 4 --baseline outputs/repro/arvi --baseline-label ARVI --out empty1.png   # the paper's Fig. 2
    aia-log plot ... --baseline arvi --baseline-label ARVI --baseline arvi_min2 --baseline-label "ARVI, 2 m"
    aia-log plot ... --ci bootstrap          # the IQM over runs with its stratified-bootstrap CI band (rliable)
    aia-log stats outputs/repro/small3/learners --group-by method --baseline outputs/repro/small3/arvi_min2 \\
        --baseline-label "ARVI 2 m" [--json]   # IQM, mean, P(improvement), verdict, first x reaching it, with CIs
    aia-log render RUN --episode last --out episode.gif        # or .png: a strip of --frames frames

RUN arguments are files, folders (searched for ``*.mcap``) or globs. A run killed before it closed its log
is read up to its last complete chunk and reported as truncated; a damaged chunk (its CRC-32 does not match) is
read around and reported in one line naming it and when its messages were logged.
"""

from __future__ import annotations

import argparse
import csv
import json
import sys
from collections.abc import Sequence
from datetime import datetime
from pathlib import Path

import numpy as np

from aia.apps.output_files import written_whole
from aia.config.errors import Stopped
from aia.logging.curves import X_AXES, baseline_level, lower_is_better, select_runs
from aia.logging.episode_images import episode_images, image_strip
from aia.logging.figures import X_LABELS, curves_figure, results_table
from aia.logging.metadata import flatten
from aia.logging.reader import RunLog, RunLogError, find_runs, read_run
from aia.logging.stats import (
    STATISTICS,
    VERDICT_BY,
    StatsConfig,
    describe,
    group_stats,
    stats_json,
    stats_table,
)
from aia.runtime.process_exit import freeze_at_exit
from aia.runtime.stopping import interrupting

RENDER_FORMATS = (".gif", ".png")
SUMMARY_KEYS = ("algo", "exploration", "env.map", "env.num_targets", "seed", "frames")


def _status(run: RunLog) -> str:
    if run.complete and not run.damage and not run.failure:
        return "complete"
    parts = [run.failure] if run.failure else []
    if not run.complete:
        read = "" if run.only_topics is None else f"{', '.join(sorted(run.only_topics))} "
        parts.append(f"truncated: {len(run.messages)} {read}messages recovered ({run.problem})")
    parts += run.damage
    return "; ".join(parts)


def _stamp(seconds: float) -> str:
    return datetime.fromtimestamp(seconds).strftime("%Y-%m-%d %H:%M:%S")


def summary(run: RunLog) -> str:
    """The text ``aia-log summary`` prints for one run."""
    lines = [f"{run.path}  [{_status(run)}]"]
    span = run.time_span()
    if span:
        lines.append(f"  time      {_stamp(span[0])} -> {_stamp(span[1])}  ({span[1] - span[0]:.1f} s)")
    info = run.metadata.get("run", {})
    config = [f"{key}={run.config_value(key)}" for key in SUMMARY_KEYS if run.config_value(key) is not None]
    if config:
        lines.append("  config    " + " ".join(config))
    if "git_commit" in info:
        dirty = " (uncommitted changes)" if info.get("git_dirty") == "true" else ""
        lines.append(f"  code      git {info['git_commit'][:12]}{dirty}, torch {info.get('version.torch', '?')}, "
                     f"torchrl {info.get('version.torchrl', '?')}")
    lines.append(f"  metadata  {', '.join(run.metadata) or '-'};  attachments {', '.join(run.attachments) or '-'}")
    lines.append("  topics")
    counts = run.topic_counts()
    width = max((len(t) for t in counts), default=5)
    for topic, (schema, count) in counts.items():
        lines.append(f"    {topic:<{width}}  {schema:<24} {count:>8}")
    episodes = run.episodes()
    if episodes:
        lines.append(f"  episodes  {len(episodes)} recorded: {_short_list(episodes)}")
    for topic in ("eval/score", "train/score"):
        if topic in counts:
            series = run.scalars(topic)
            best = int(np.nanargmax(series.values)) if np.isfinite(series.values).any() else -1
            lines.append(f"  {topic:<12}last {series.values[-1]:.1f} at frame {series.frames[-1]:.0f}; best "
                         f"{series.values[best]:.1f} at frame {series.frames[best]:.0f}; {len(series.values)} values")
    return "\n".join(lines)


def _short_list(values: list[int], edge: int = 4) -> str:
    if len(values) <= 2 * edge:
        return ", ".join(map(str, values))
    return ", ".join(map(str, values[:edge])) + ", ..., " + ", ".join(map(str, values[-edge:]))


def scalar_rows(runs: Sequence[RunLog], topics: Sequence[str]) -> list[dict[str, object]]:
    """Rows ``run, topic, frame, seconds (since the run's first message), value`` of every scalar message."""
    rows = []
    for run in runs:
        span = run.time_span()
        start = span[0] if span else 0.0
        for topic in topics or run.scalar_topics():
            series = run.scalars(topic)
            for frame, seconds, value in zip(series.frames, series.times, series.values, strict=True):
                rows.append({"run": str(run.path), "topic": topic.lstrip("/"),
                             "frame": None if np.isnan(frame) else int(frame),
                             "seconds": round(float(seconds - start), 3), "value": float(value)})
    return rows


def baseline_runs(paths: Sequence[str], labels: Sequence[str], where: Sequence[str], metric: str
                  ) -> list[tuple[str, list[RunLog]]]:
    """The baselines of ``--baseline`` / ``--baseline-label`` as (label, runs): with one label or none, all
    ``paths`` pool into one baseline; with one label per path, each path is a baseline of its own. Without a
    label, the baseline is named by the ``policy`` its runs share (``aia-eval``'s: arvi, pursuit), else
    "baseline"."""
    if not paths:
        if labels:
            raise ValueError(f"--baseline-label {labels[0]!r} without --baseline: name the baseline's runs with "
                             "--baseline (a folder, file or glob of run logs)")
        return []
    if len(labels) <= 1:
        groups = [(labels[0] if labels else None, list(paths))]
    elif len(labels) == len(paths):
        groups = [(label, [path]) for label, path in zip(labels, paths, strict=True)]
    else:
        raise ValueError(f"{len(labels)} --baseline-label for {len(paths)} --baseline: give one label (the runs "
                         "pool into one baseline) or one per --baseline")
    baselines = []
    for label, group in groups:
        runs = _with_metric(select_runs(_read_all(group, [metric]), where), metric)
        if not runs:
            raise ValueError(f"no {label or 'baseline'} run in {group} matches --where {list(where)} and has "
                             f"{metric!r}")
        if label is None:
            policies = {run.config_value("policy") for run in runs}
            label = str(policies.pop()) if len(policies) == 1 and None not in policies else "baseline"
        baselines.append((label, runs))
    return baselines


def render(run: RunLog, episode: str, out: Path, size: int, frames: int, fps: float, zoom: bool = True
           ) -> tuple[int, int]:
    """Write a recorded episode (:func:`~aia.logging.episode_images.episode_images`) as a GIF of every step or a
    PNG strip of ``frames`` evenly spaced steps; returns the image's (width, height)."""
    if out.suffix.lower() not in RENDER_FORMATS:
        raise ValueError(f"--out {out}: the format must be one of {list(RENDER_FORMATS)}")
    if frames < 1:
        raise ValueError(f"--frames={frames} must be >= 1")
    if fps <= 0:
        raise ValueError(f"--fps={fps} must be > 0")
    gif = out.suffix.lower() == ".gif"
    images = episode_images(run, episode if episode in ("first", "last") else _episode_index(episode), size,
                            None if gif else frames, zoom)
    image = images[0] if gif else image_strip(images)
    out.parent.mkdir(parents=True, exist_ok=True)
    with written_whole(out) as temporary:
        if gif:
            image.save(temporary, save_all=True, append_images=images[1:], duration=round(1000 / fps), loop=0)
        else:
            image.save(temporary)
    return image.size


def _episode_index(text: str) -> int:
    try:
        return int(text)
    except ValueError:
        raise ValueError(f"--episode {text!r} must be an episode index, 'first' or 'last'") from None


def _read_all(patterns: Sequence[str], only_topics: Sequence[str] | None = None) -> list[RunLog]:
    """The runs of ``patterns`` (only their messages of ``only_topics``: :func:`read_run`), with a warning for each
    one that is not complete."""
    runs = [read_run(path, only_topics) for path in find_runs(list(patterns))]
    for run in runs:
        if _status(run) != "complete":
            print(f"warning: {run.path}: {_status(run)}", file=sys.stderr)
    return runs


def runs_with_metric(patterns: Sequence[str], where: Sequence[str], metric: str) -> list[RunLog]:
    """The runs of ``patterns`` that match every ``--where`` and have logged ``metric``; a ValueError when none
    matches, or when none has ``metric`` (naming the scalar topics they have), and a warning for each run left out
    for lack of it while others have it (a run just started)."""
    runs = select_runs(_read_all(patterns, [metric]), where)  # only the metric's messages: see read_run
    if not runs:
        raise ValueError(f"no run of {list(patterns)} matches --where {' '.join(where)}")
    if not any(metric in run.scalar_topics() for run in runs):
        topics = sorted({topic for run in runs for topic in read_run(run.path).scalar_topics()})
        raise ValueError(f"--metric {metric!r}: no run has logged it; expected a scalar topic of the runs: "
                         f"{', '.join(topics) or 'none yet'}")
    return _with_metric(runs, metric)


def _with_metric(runs: Sequence[RunLog], metric: str) -> list[RunLog]:
    """The runs that have logged ``metric``; a warning names each one left out (e.g. a run just started)."""
    kept = []
    for run in runs:
        if metric in run.scalar_topics():
            kept.append(run)
        else:
            print(f"warning: {run.path}: no {metric!r} yet, left out", file=sys.stderr)
    return kept


def check_group_keys(runs: Sequence[RunLog], keys: Sequence[str]) -> None:
    """Every ``--group-by`` key is a config key set in at least one run; else a ValueError names it (or that no
    run sets it), the keys whose values differ among the runs (what one would group by) and every key the runs
    have."""
    for key in keys:
        if all(run.config_value(key) is None for run in runs):
            groups = {k.rsplit(".name", 1)[0] for run in runs for k in flatten(run.config()) if k.endswith(".name")}
            available = sorted(groups | {k for run in runs for k in flatten(run.config())})
            differing = [k for k in available if len({repr(run.config_value(k)) for run in runs}) > 1]
            # a group that differs (algo) stands for its entries (algo.name, algo.noise, ...)
            differing = [k for k in differing if not any(k.startswith(f"{g}.") for g in groups & set(differing))]
            keys = f"every key: {', '.join(available)}"
            if len(runs) > 1:
                keys = f"the {len(runs)} runs differ in: {', '.join(differing) or 'no key'}; {keys}"
            # a key every run leaves unset (method without conf/method/) is a key, with nothing to group by
            problem = f"every run has {key}=None" if key in available else "no run has this config key"
            raise ValueError(f"--group-by {key!r}: {problem}; {keys}")


class OneLineParser(argparse.ArgumentParser):
    """An argument parser whose errors are one line (``aia-log stats: error: argument --reps: ...``), exit 2."""

    def error(self, message: str) -> None:
        self.exit(2, f"{self.prog}: error: {message}\n")


DEFAULTS = StatsConfig()


def add_stats_options(cmd: argparse.ArgumentParser, verdicts: bool) -> None:
    """The options of :class:`aia.logging.stats.StatsConfig` (their defaults are its own)."""
    cmd.add_argument("--statistic", choices=STATISTICS, default=DEFAULTS.statistic,
                     help=f"aggregate over runs: interquartile mean or mean (default: {DEFAULTS.statistic})")
    cmd.add_argument("--reps", type=int, default=DEFAULTS.reps,
                     help=f"bootstrap resamples per interval (default: {DEFAULTS.reps})")
    cmd.add_argument("--ci-level", type=float, default=DEFAULTS.ci_level,
                     help=f"coverage of the confidence intervals (default: {DEFAULTS.ci_level})")
    cmd.add_argument("--seed", type=int, default=DEFAULTS.seed,
                     help=f"seed of the bootstrap's resampling (default: {DEFAULTS.seed})")
    if verdicts:
        cmd.add_argument("--verdict-by", choices=VERDICT_BY, default=DEFAULTS.verdict_by,
                         help="what a verdict against a baseline reads: the CI of the probability of improvement "
                              f"or of the statistic's difference (default: {DEFAULTS.verdict_by})")
        cmd.add_argument("--poi-threshold", type=float, default=DEFAULTS.poi_threshold,
                         help="above when the probability of improvement's CI lies wholly above this, below when "
                              f"wholly below, else undecided (default: {DEFAULTS.poi_threshold})")
        cmd.add_argument("--difference-threshold", type=float, default=DEFAULTS.difference_threshold,
                         help="the same for the CI of statistic(group) - statistic(baseline) under --verdict-by "
                              f"difference (default: {DEFAULTS.difference_threshold})")


def add_comparison_options(cmd: argparse.ArgumentParser, runs_help: str, baseline_use: str) -> None:
    """The runs, groups and baselines that ``plot`` and ``stats`` compare, and how a run's curve is read (its
    smoothing, its x unit and which way is better: the curves' axis and the first x at which a group reaches a
    baseline)."""
    cmd.add_argument("runs", nargs="+", help=runs_help)
    cmd.add_argument("--metric", default="eval/score", help="scalar topic (default: eval/score)")
    cmd.add_argument("--group-by", action="append", default=[], metavar="KEY",
                     help="config key to group runs by, e.g. method, algo or env.num_targets (repeatable)")
    cmd.add_argument("--where", action="append", default=[], metavar="KEY=VALUE",
                     help="keep only runs (and baseline runs) whose config has this value, e.g. env.num_targets=2 "
                          "(repeatable)")
    cmd.add_argument("--baseline", action="append", default=[], metavar="RUNS",
                     help=f"runs whose metric values make a baseline, {baseline_use}, e.g. aia-eval policy=arvi logs")
    cmd.add_argument("--baseline-label", action="append", default=[], metavar="LABEL",
                     help="the baseline's name (e.g. ARVI); one per --baseline makes several baselines")
    cmd.add_argument("--window", type=int, default=1,
                     help="moving-average window of each run's curve (default: 1; the paper's: 4)")
    cmd.add_argument("--x", dest="x_axis", choices=X_AXES, default="frame",
                     help="x unit: training frames (default), training episodes (the paper's) or evaluation index")
    cmd.add_argument("--better", choices=("higher", "lower"),
                     help="which way the metric improves, for the first x reaching a baseline (default: lower for "
                          "a metric named *error* or *loss*, such as eval/belief_error, higher otherwise)")


def compared_runs(args: argparse.Namespace) -> tuple[list[RunLog], list[tuple[str, list[RunLog]]], bool]:
    """What :func:`add_comparison_options` selected: the runs, the baselines as (label, runs), and whether lower
    is better (ValueError naming a bad option)."""
    if args.window < 1:
        raise ValueError(f"--window={args.window} must be >= 1")
    runs = runs_with_metric(args.runs, args.where, args.metric)
    check_group_keys(runs, args.group_by)
    baselines = baseline_runs(args.baseline, args.baseline_label, args.where, args.metric)
    lower_better = lower_is_better(args.metric) if args.better is None else args.better == "lower"
    return runs, baselines, lower_better


def stats_config(args: argparse.Namespace) -> StatsConfig:
    """The :class:`StatsConfig` of the parsed options (ValueError naming a bad value)."""
    names = ("statistic", "reps", "ci_level", "seed", "verdict_by", "poi_threshold", "difference_threshold")
    return StatsConfig(**{name: getattr(args, name) for name in names if hasattr(args, name)})


def make_parser() -> argparse.ArgumentParser:
    """The ``aia-log`` argument parser."""
    parser = OneLineParser(prog="aia-log", description=__doc__.split("\n\n")[0],
                                     formatter_class=argparse.RawDescriptionHelpFormatter,
                                     epilog=__doc__.split("\n\n")[1])
    commands = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    runs_help = "MCAP files, folders or globs (quote '**' patterns)"

    cmd = commands.add_parser("summary", help="topics, message counts, time span, config and scores of runs")
    cmd.add_argument("runs", nargs="+", help=runs_help)

    cmd = commands.add_parser("scalars", help="scalar series as a table on stdout or a CSV file")
    cmd.add_argument("runs", nargs="+", help=runs_help)
    cmd.add_argument("--topic", action="append", default=[], help="scalar topic (repeatable; default: all)")
    cmd.add_argument("--csv", type=Path, help="write the rows to this CSV file instead of printing them")

    cmd = commands.add_parser("plot", help="learning curves across runs: mean and std band per group")
    add_comparison_options(cmd, runs_help, "a horizontal band drawn behind the curves")
    cmd.add_argument("--title", help="figure title (default: the metric)")
    cmd.add_argument("--out", type=Path, default=Path("curves.png"), help="PNG to write (default: curves.png)")
    cmd.add_argument("--ci", choices=("std", "bootstrap"), default="std",
                     help="the band: +-1 std around the mean (default), or the --statistic over runs with its "
                          "pointwise stratified-bootstrap CI (rliable)")
    add_stats_options(cmd, verdicts=False)

    cmd = commands.add_parser("stats", help="per group: IQM and mean of the runs' final levels with bootstrap CIs; "
                                            "against --baseline: P(improvement), difference, verdict (rliable)")
    add_comparison_options(cmd, runs_help, "every group is compared with")
    add_stats_options(cmd, verdicts=True)
    cmd.add_argument("--json", action="store_true", help="print the statistics as JSON instead of a table")

    cmd = commands.add_parser("render", help="a recorded episode as a GIF or a PNG strip of frames")
    cmd.add_argument("run", help="one MCAP file")
    cmd.add_argument("--episode", default="last", help="recorded episode index, 'first' or 'last' (default)")
    cmd.add_argument("--out", type=Path, default=Path("episode.gif"),
                     help="a .gif, or a .png strip of --frames frames (default: episode.gif here)")
    cmd.add_argument("--size", type=int, default=384, help="pixels per frame side (default: 384)")
    cmd.add_argument("--frames", type=int, default=6, help="frames in a PNG strip (default: 6)")
    cmd.add_argument("--fps", type=float, default=10.0, help="GIF frame rate (default: 10)")
    cmd.add_argument("--whole-map", action="store_true",
                     help="draw the whole map (default: zoom on the square where the episode happens)")
    return parser


def run_command(args: argparse.Namespace) -> None:
    """Execute a parsed ``aia-log`` command."""
    if args.command == "summary":
        print("\n\n".join(summary(run) for run in _read_all(args.runs)))
    elif args.command == "scalars":
        rows = scalar_rows(_read_all(args.runs), args.topic)
        if args.csv:
            args.csv.parent.mkdir(parents=True, exist_ok=True)
            with written_whole(args.csv) as temporary, open(temporary, "w", newline="") as f:
                writer = csv.DictWriter(f, fieldnames=["run", "topic", "frame", "seconds", "value"])
                writer.writeheader()
                writer.writerows(rows)
            print(f"{len(rows)} rows written to {args.csv}")
        else:
            print(f"{'topic':<20} {'frame':>10} {'seconds':>10} {'value':>14}  run")
            for row in rows:
                frame = "" if row["frame"] is None else row["frame"]
                print(f"{row['topic']:<20} {frame:>10} {row['seconds']:>10.3f} {row['value']:>14.6g}  {row['run']}")
    elif args.command == "plot":
        if args.out.suffix.lower() != ".png":
            raise ValueError(f"--out {args.out}: plot writes a .png file")
        bootstrap = stats_config(args) if args.ci == "bootstrap" else None
        runs, baseline_groups, lower_better = compared_runs(args)
        figure, curves = curves_figure(runs, args.metric, args.group_by, args.window, args.x_axis, args.title,
                                       baseline_groups, bootstrap)
        args.out.parent.mkdir(parents=True, exist_ok=True)
        with written_whole(args.out) as temporary:
            figure.savefig(temporary)
        baselines = [(label, *baseline_level(members, args.metric)) for label, members in baseline_groups]
        for curve in curves:
            print(f"{curve.label}: {int(curve.runs.max())} runs, final {args.metric} {curve.mean[-1]:.1f} "
                  f"+- {curve.std[-1]:.1f}")
        print(results_table(curves, args.metric, args.x_axis, baselines, lower_better))
        print(f"plot written to {args.out}")
    elif args.command == "stats":
        config = stats_config(args)
        runs, baselines, lower_better = compared_runs(args)
        groups, bases = group_stats(runs, args.metric, args.group_by, baselines, config, args.window, args.x_axis,
                                    lower_better)
        if args.json:
            print(json.dumps(stats_json(groups, bases, args.metric, config), indent=2))
        else:
            print(describe(args.metric, config))
            print(stats_table(groups, bases, args.metric, config, X_LABELS[args.x_axis], lower_better))
    elif args.command == "render":
        width, height = render(read_run(args.run), args.episode, args.out, args.size, args.frames, args.fps,
                               zoom=not args.whole_map)
        print(f"{args.out} written ({width} x {height} pixels)")


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of ``aia-log``; returns the exit status (2 with a one-line message on bad input)."""
    freeze_at_exit()
    parser = make_parser()
    try:
        args = parser.parse_args(argv)
    except SystemExit as stop:  # --help (0), or a bad option: its one line is printed (2)
        return int(stop.code or 0)
    try:
        with interrupting():
            run_command(args)
    except (RunLogError, ValueError, OSError) as err:
        print(f"aia-log: error: {err}", file=sys.stderr)
        return 2
    except Stopped as stop:  # Ctrl-C or SIGTERM: a file being written is left as it was (written_whole)
        print(f"aia-log: stopped by {stop}", file=sys.stderr)
        return stop.exit_status
    return 0


if __name__ == "__main__":
    sys.exit(main())
