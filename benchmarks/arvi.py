"""ARVI planning time, tree size and score: a fast budget against the reference's 1 s budget.

Speed: for each setting, number of worlds planned in one call and budget, plans from ``--states`` seeded
states (reset plus a few random steps) and reports the median wall time per call, the nodes generated per
world and the smallest ``delta`` the anytime schedule reached. Quality: ``--episodes`` seeded single-world
episodes of the 1-target setting under each budget (re-planning every 5 steps, as the reference), with the
mean score and the paired difference to the reference budget. Prints markdown tables and writes JSON
(default ``benchmarks/results/arvi_<device>.json``).

    python benchmarks/arvi.py                                   # CPU: empty1 and small3, 1 and 10 worlds
    python benchmarks/arvi.py --device cuda --episodes 0        # timings only

Throughput: nodes generated per second per world-batch at a node budget (``--nodes`` per world), at 1, 10
and 50 worlds, and a profile of one call (where the time goes); with ``--baseline-commit``, also for the planner
of that commit (read from git and run in the same process, on the same states), with the ratio. The planner of
54a9a5a (before issue 16, the comparison in docs/planner.md) no longer runs on today's env (it reads the env's
``transition``), so there is no default.

    python benchmarks/arvi.py --only throughput   # the table and profile: results/arvi_cpu_throughput.{json,md}

Timings on a machine shared with other jobs vary by tens of percent from run to run.
"""

from __future__ import annotations

import argparse
import cProfile
import importlib.util
import io
import json
import math
import platform
import pstats
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import torch
from _cli import NON_NEGATIVE_INT, POSITIVE_INT, POSITIVE_NUMBER, env_setting, parse_checked
from torchrl.envs import StepCounter

from aia.envs import make_env
from aia.evaluation import episode_scores, run_episodes
from aia.planners import ARVIConfig, ARVIPlanner, ARVIPolicy
from aia.policies import RandomPolicy
from aia.runtime.timing import synchronize

REFERENCE_BUDGET = 1.0  # seconds per call (the reference's ARVI)


def planning_states(setting: str, num_worlds: int, states: int, device: str) -> list:
    """``states`` batches of ``num_worlds`` env states: a seeded reset then 0, 3, 6... random steps."""
    env = make_env(setting, batch_size=num_worlds, device=device, seed=0, transforms=False)
    random = RandomPolicy(env.action_spec.n, seed=0, device=device)
    td, out = env.reset(), []
    for _ in range(states):
        out.append((td["robot_pose"], td["belief_mean"], td["belief_cov"]))
        for _ in range(3):
            td = env.step(random(td))["next"]
    return out


def measure_speed(setting: str, num_worlds: int, budget: float, states: int, device: str) -> dict:
    """Median wall time per planning call at ``budget`` seconds, with the tree it built."""
    env = make_env(setting, batch_size=num_worlds, device=device, seed=0, transforms=False)
    planner = ARVIPlanner(env, ARVIConfig(time_budget=budget))
    batches = planning_states(setting, num_worlds, states, device)
    planner.plan(*batches[0])  # warm-up
    seconds, nodes, deltas = [], [], []
    for batch in batches:
        synchronize(device)
        start = time.perf_counter()
        result = planner.plan(*batch)
        synchronize(device)
        seconds.append(time.perf_counter() - start)
        nodes.append(result.nodes.float().mean().item())
        deltas.append(result.delta)
    return {"setting": setting, "targets": env.num_targets, "worlds": num_worlds, "budget_s": budget,
            "device": device, "states": states, "ms_per_call": 1e3 * statistics.median(seconds),
            "ms_max": 1e3 * max(seconds), "nodes_per_world": statistics.median(nodes),
            "delta_reached": statistics.median(deltas)}


class BaselineError(ValueError):
    """A ``--baseline-commit`` whose planner cannot be read or run: the command's one-line error."""


def load_baseline(commit: str):
    """The planner module ``aia/planners/arvi.py`` of ``commit``, imported from git (a
    :class:`BaselineError` when git has no such file at that commit)."""
    shown = subprocess.run(["git", "show", f"{commit}:aia/planners/arvi.py"], capture_output=True, text=True,
                           cwd=Path(__file__).parent)
    if shown.returncode != 0:
        raise BaselineError(f"--baseline-commit {commit}: git has no aia/planners/arvi.py there "
                         f"({shown.stderr.strip().splitlines()[-1] if shown.stderr.strip() else 'git failed'})")
    source = shown.stdout
    path = Path(tempfile.mkdtemp()) / "arvi_baseline.py"
    path.write_text(source)
    spec = importlib.util.spec_from_file_location("arvi_baseline", path)
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module
    spec.loader.exec_module(module)
    return module


def measure_throughput(setting: str, num_worlds: int, nodes: int, states: int, device: str, baseline) -> dict:
    """Nodes generated per second per call (all worlds together) at ``nodes`` per world: this planner and
    ``baseline``'s, on the same ``states`` batches (median and range), and whether their plans are identical."""
    env = make_env(setting, batch_size=num_worlds, device=device, seed=0, transforms=False)
    batches = planning_states(setting, num_worlds, states, device)
    row = {"setting": setting, "targets": env.num_targets, "worlds": num_worlds, "nodes_per_world": nodes,
           "device": device, "states": states, "identical_plans": True}
    plans = {}
    modules = [("new", sys.modules["aia.planners"])] + ([("old", baseline)] if baseline is not None else [])
    for name, module in modules:
        try:
            planner = module.ARVIPlanner(env, module.ARVIConfig(time_budget=None, max_nodes=nodes))
            planner.plan(*batches[0])  # warm-up
        except Exception as err:  # noqa: BLE001  (an old planner against today's env: named in one line)
            if name == "new":
                raise
            raise BaselineError(f"--baseline-commit: its planner does not run on today's env "
                             f"({type(err).__name__}: {err})") from None
        rates, plans[name] = [], []
        for batch in batches:
            synchronize(device)
            start = time.perf_counter()
            result = planner.plan(*batch)
            synchronize(device)
            rates.append(result.nodes.sum().item() / (time.perf_counter() - start))
            plans[name].append(result.actions)
        row[f"{name}_nodes_per_s"] = statistics.median(rates)
        row[f"{name}_nodes_per_s_range"] = [min(rates), max(rates)]
    if baseline is not None:
        row["identical_plans"] = all(torch.equal(a, b) for a, b in zip(plans["new"], plans["old"], strict=True))
        row["ratio"] = row["new_nodes_per_s"] / row["old_nodes_per_s"]
    return row


def profile_call(setting: str, num_worlds: int, nodes: int, device: str, top: int = 15) -> str:
    """cProfile of one planning call (by own time): where the time goes."""
    env = make_env(setting, batch_size=num_worlds, device=device, seed=0, transforms=False)
    planner = ARVIPlanner(env, ARVIConfig(time_budget=None, max_nodes=nodes))
    batch = planning_states(setting, num_worlds, 1, device)[0]
    planner.plan(*batch)
    profile = cProfile.Profile()
    profile.runcall(planner.plan, *batch)
    out = io.StringIO()
    pstats.Stats(profile, stream=out).sort_stats("tottime").print_stats(top)
    return out.getvalue()


def markdown_table(header: list[str], cells: list[list[str]]) -> str:
    """A markdown table, the first column left-aligned and the others right-aligned."""
    lines = ["| " + " | ".join(header) + " |", "|---|" + "---:|" * (len(header) - 1)]
    return "\n".join(lines + ["| " + " | ".join(row) + " |" for row in cells])


def throughput_table(rows: list[dict]) -> str:
    if rows and "ratio" not in rows[0]:  # no --baseline-commit
        return markdown_table(["setting", "targets", "worlds", "nodes per world", "nodes/s"],
                              [[r["setting"], str(r["targets"]), str(r["worlds"]), f"{r['nodes_per_world']:,}",
                                f"{r['new_nodes_per_s']:,.0f}"] for r in rows])
    return markdown_table(
        ["setting", "targets", "worlds", "nodes per world", "old nodes/s", "new nodes/s", "ratio", "identical plans"],
        [[r["setting"], str(r["targets"]), str(r["worlds"]), f"{r['nodes_per_world']:,}",
          f"{r['old_nodes_per_s']:,.0f}",
          f"{r['new_nodes_per_s']:,.0f}", f"{r['ratio']:.2f}", "yes" if r["identical_plans"] else "NO"] for r in rows])


def measure_scores(setting: str, budget: float, episodes: int, device: str) -> list[float]:
    """Scores of single-world episodes with seeds ``0 .. episodes - 1`` at ``budget`` seconds per plan."""
    scores = []
    for seed in range(episodes):
        env = make_env(setting, batch_size=1, device=device, seed=seed)
        env.append_transform(StepCounter())
        policy = ARVIPolicy(env, ARVIConfig(time_budget=budget))
        scores.append(episode_scores(run_episodes(env, policy, seed=seed)).item())
    return scores


def speed_table(rows: list[dict]) -> str:
    return markdown_table(
        ["setting", "targets", "worlds", "budget (s)", "ms per call (max)", "nodes per world", "delta reached"],
        [[r["setting"], str(r["targets"]), str(r["worlds"]), f"{r['budget_s']:g}",
          f"{r['ms_per_call']:.1f} ({r['ms_max']:.1f})", f"{r['nodes_per_world']:,.0f}", f"{r['delta_reached']:.2f}"]
         for r in rows])


def quality_summary(quality: dict) -> str:
    reference = quality[str(REFERENCE_BUDGET)]
    lines = ["| budget (s) | score mean | score std | paired difference to 1 s (mean +- s.e.) |",
             "|---:|---:|---:|---:|"]
    for budget, scores in quality.items():
        diffs = [a - b for a, b in zip(scores, reference, strict=True)]
        se = statistics.stdev(diffs) / math.sqrt(len(diffs)) if len(diffs) > 1 else math.nan
        lines.append(f"| {float(budget):g} | {statistics.mean(scores):.1f} | {statistics.pstdev(scores):.1f} | "
                     f"{statistics.mean(diffs):+.1f} +- {se:.1f} |")
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--device", default="cpu")
    parser.add_argument("--settings", nargs="+", type=env_setting, default=["empty1", "small3"])
    parser.add_argument("--worlds", nargs="+", type=POSITIVE_INT, default=[1, 10])
    parser.add_argument("--fast-budget", type=POSITIVE_NUMBER, default=0.04,
                        help="seconds per call of the fast setting")
    parser.add_argument("--states", type=POSITIVE_INT, default=5, help="planning calls timed per case")
    parser.add_argument("--episodes", type=NON_NEGATIVE_INT, default=8,
                        help="seeded episodes per budget for the scores (0: no scores)")
    parser.add_argument("--quality-setting", type=env_setting, default="empty1")
    parser.add_argument("--threads", type=POSITIVE_INT, default=1,
                        help="torch CPU threads (planning is latency-bound: on a busy machine a second thread "
                             "makes every batched Cholesky wait for the other core)")
    parser.add_argument("--only", choices=["throughput", "timing"], default=None,
                        help="run only the throughput table (and profile) or only the timing and score tables")
    parser.add_argument("--nodes", type=POSITIVE_INT, default=5000,
                        help="node budget per world of the throughput table")
    parser.add_argument("--throughput-worlds", nargs="+", type=POSITIVE_INT, default=[1, 10, 50])
    parser.add_argument("--throughput-states", type=POSITIVE_INT, default=3,
                        help="planning calls timed per throughput case")
    parser.add_argument("--baseline-commit", default=None,
                        help="git commit of a planner to compare the throughput to (default: none)")
    parser.add_argument("--out", type=Path, default=None)
    args = parse_checked(parser)
    torch.set_num_threads(args.threads)

    throughput, profile = [], ""
    if args.only != "timing":
        try:
            baseline = load_baseline(args.baseline_commit) if args.baseline_commit else None
            for setting in args.settings:
                for worlds in args.throughput_worlds:
                    throughput.append(measure_throughput(setting, worlds, args.nodes, args.throughput_states,
                                                         args.device, baseline))
                    print(throughput_table(throughput[-1:]).splitlines()[-1], flush=True)
        except BaselineError as err:
            parser.error(str(err))
        profile = profile_call(args.settings[-1], max(args.throughput_worlds), args.nodes, args.device)
        print(profile)
    if args.only == "throughput":
        args.worlds, args.episodes = [], 0

    budgets = [args.fast_budget, REFERENCE_BUDGET]
    rows = []
    for setting in args.settings:
        for worlds in args.worlds:
            for budget in budgets:
                rows.append(measure_speed(setting, worlds, budget, args.states, args.device))
                print(speed_table(rows[-1:]).splitlines()[-1], flush=True)
    quality = {}
    if args.episodes:
        for budget in budgets:
            quality[str(budget)] = measure_scores(args.quality_setting, budget, args.episodes, args.device)
            print(f"budget {budget:g} s: scores {[round(s) for s in quality[str(budget)]]}", flush=True)

    suffix = "_throughput" if args.only == "throughput" else ""
    out = args.out or Path(__file__).parent / "results" / f"arvi_{args.device.split(':')[0]}{suffix}.json"
    out.parent.mkdir(parents=True, exist_ok=True)
    meta = {"torch": torch.__version__, "threads": torch.get_num_threads(), "machine": platform.machine(),
            "gpu": torch.cuda.get_device_name() if args.device.startswith("cuda") else None,
            "quality_setting": args.quality_setting}
    meta["baseline_commit"] = args.baseline_commit
    out.write_text(json.dumps({"meta": meta, "throughput": throughput, "speed": rows, "scores": quality}, indent=2))
    if throughput:
        table = throughput_table(throughput)
        out.with_suffix(".md").write_text(f"{table}\n\nProfile ({args.settings[-1]}, "
                                          f"{max(args.throughput_worlds)} worlds):\n\n{profile}")
        print()
        print(table)
    if rows:
        print()
        print(speed_table(rows))
    if quality:
        print()
        print(quality_summary(quality))
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
