"""Frames per second of the transformed tracking env under random actions.

For each setting and batch size B, steps the env (with its feature and reward transforms) for a fixed
number of batched steps after a warm-up and reports frames/s (= B * steps / seconds) and the time of one
batched step. Each case runs in a fresh process, as a user's run would (in one long process, compiled
code of earlier envs adds guard checks to later ones). Prints a table and writes JSON (default
``benchmarks/results/env_throughput_<device>.json``), whose ``meta`` names the commit (and whether the checkout
was dirty), the arguments, the start and end (UTC) and the machine's matmul rate before and after.

A case is a preset, optionally with env overrides after a colon (``small2:belief.filter=particle``).
``--filters`` measures one case per belief filter (kf, the UKF over 3 and 5 states, the particle filter with
256 and 1,024 particles); ``--baseline REV`` measures every case again with the code of commit ``REV`` in the
same run (the cases that commit cannot build are left out), so a change's cost is a ratio within one run.

``--rounds N`` measures every case N times, round by round (each round's cases one after another, so that they
meet the same hour of a shared VM, where a case swings by 40 % from one minute to the next), and reports each
case's median and range over the rounds; ``--relative-to SETTING`` adds each case's frames/s as a fraction of
that setting's in the same round (mode, batch size and code), with its median and range: the form of a target
such as "random maps at least half the frames/s of the fixed map".

    python benchmarks/env_throughput.py                     # CPU, B in {1, 16, 256, 4096}, the four settings
    python benchmarks/env_throughput.py --device cuda --batch-sizes 1 1024 16384 65536
    python benchmarks/env_throughput.py --filters --batch-sizes 1 4096 --baseline 54a9a5a
    python benchmarks/env_throughput.py --settings obstacles1 random_obstacles --batch-sizes 4096 --modes compiled \
        --rounds 5 --relative-to obstacles1
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import torch
from _cli import NON_NEGATIVE_INT, POSITIVE_INT, env_case, git_commit, parse_checked

from aia.envs import make_env
from aia.logging.mcap_logger import git_state
from aia.runtime.timing import sgemm_gflops, synchronize, utc_now

SETTINGS = ("empty1", "obstacles1", "small2", "small3")
# One case per belief filter: kf, the UKF over [x, y, theta] and [x, y, theta, v, w], particles K = 256, 1024.
FILTER_CASES = ("empty1", "ttenv_v2", "ttenv_v3", "ttenv_v2:belief.filter=particle,belief.particles=256",
                "ttenv_v2:belief.filter=particle,belief.particles=1024")
HERE = Path(__file__).resolve().parent


def measure(setting: str, batch_size: int, device: str, steps: int, warmup: int, compile: bool,
            repeats: int = 5) -> dict:
    """Median over ``repeats`` windows of ``steps`` batched steps of random actions (auto-reset at the
    episode end, like a collector), after ``warmup`` steps (which include compilation)."""
    name, _, overrides = setting.partition(":")
    env = make_env(name, batch_size=batch_size, device=device, seed=0, validate_actions=False, compile=compile,
                   overrides=[o for o in overrides.split(",") if o])
    num_actions = env.action_spec.n
    td = env.reset()
    actions = torch.randint(0, num_actions, (warmup + repeats * steps, batch_size), device=device)

    def run(first: int, count: int, td):
        for i in range(first, first + count):
            td.set("action", actions[i])
            _, td = env.step_and_maybe_reset(td)
        return td

    td = run(0, warmup, td)
    windows = []
    for r in range(repeats):
        synchronize(device)
        start = time.perf_counter()
        td = run(warmup + r * steps, steps, td)
        synchronize(device)
        windows.append(time.perf_counter() - start)
    seconds = statistics.median(windows)
    return {
        "setting": setting,
        "batch_size": batch_size,
        "device": device,
        "compiled": compile,
        "steps": steps,
        "repeats": repeats,
        "seconds": seconds,
        "frames_per_s": batch_size * steps / seconds,
        "ms_per_step": 1e3 * seconds / steps,
    }


def summarise(rows: list[dict], relative_to: str | None = None) -> list[dict]:
    """One row per case (setting, mode, batch size, code) over its rounds: the median frames/s and ms a step, the
    range of frames/s, and with ``relative_to`` the frames/s as a fraction of that setting's in the same round
    (``relative``: median; ``relative_range``)."""
    key = ("setting", "mode", "batch_size", "code")
    reference = {(r["round"], r["mode"], r["batch_size"], r["code"]): r["frames_per_s"] for r in rows
                 if r["setting"] == relative_to}
    cases: dict[tuple, list[dict]] = {}
    for row in rows:
        cases.setdefault(tuple(row[k] for k in key), []).append(row)
    summary = []
    for case, runs in cases.items():
        rates = [r["frames_per_s"] for r in runs]
        entry = dict(zip(key, case, strict=True), rounds=len(runs), frames_per_s=statistics.median(rates),
                     frames_per_s_range=[min(rates), max(rates)],
                     ms_per_step=statistics.median(r["ms_per_step"] for r in runs))
        ratios = [r["frames_per_s"] / reference[(r["round"], *case[1:])] for r in runs
                  if (r["round"], *case[1:]) in reference]
        if ratios:  # none without relative_to
            entry |= {"relative_to": relative_to, "relative": statistics.median(ratios),
                      "relative_range": [min(ratios), max(ratios)]}
        summary.append(entry)
    return summary


def markdown_table(rows: list[dict]) -> str:
    """Frames/s per setting and batch size (:func:`summarise`'s rows: medians over the rounds, with the range and
    the fraction of the reference setting where there are), eager and compiled side by side (for the README)."""
    cells = {(r["setting"], r["batch_size"], _column(r)): r for r in rows}
    settings = list(dict.fromkeys(r["setting"] for r in rows))
    sizes = sorted({r["batch_size"] for r in rows})
    modes = list(dict.fromkeys(_column(r) for r in rows))
    lines = ["| setting | B | " + " | ".join(f"{m} frames/s (ms/step)" for m in modes) + " |",
             "|---|---:|" + "---:|" * len(modes)]
    for setting in settings:
        for size in sizes:
            entries = []
            for mode in modes:
                row = cells.get((setting, size, mode))
                entries.append(_cell(row) if row else "")
            lines.append(f"| {setting} | {size} | " + " | ".join(entries) + " |")
    return "\n".join(lines)


def _cell(row: dict) -> str:
    """``frames/s (ms a step)``, then the range over the rounds and the fraction of the reference setting."""
    text = f"{row['frames_per_s']:,.0f} ({row['ms_per_step']:.2f})"
    if row["rounds"] > 1:
        low, high = row["frames_per_s_range"]
        text += f", {low:,.0f}-{high:,.0f}"
    if "relative" in row and row["setting"] != row["relative_to"]:
        low, high = row["relative_range"]
        text += f"; {row['relative']:.2f}x {row['relative_to']}" + (f" ({low:.2f}-{high:.2f})" if row["rounds"] > 1
                                                                     else "")
    return text


def _column(row: dict) -> str:
    """A table column: the mode, and the code's commit when it is a baseline's."""
    return row["mode"] if row.get("code", "now") == "now" else f"{row['mode']} @ {row['code']}"


def run_case(case: dict, env: dict | None = None) -> dict | str:
    """One case in a fresh process (with ``env`` added to its environment): its row, or the last line the process
    wrote to stderr when it fails (an unknown setting: the allowed ones)."""
    done = subprocess.run([sys.executable, str(HERE / "env_throughput.py"), "--single", json.dumps(case)],
                          capture_output=True, text=True, env=os.environ | (env or {}), cwd=env and env["PYTHONPATH"])
    if done.returncode != 0:
        lines = done.stderr.strip().splitlines()
        return lines[-1] if lines else f"exit status {done.returncode}"
    return json.loads(done.stdout.strip().splitlines()[-1])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--device", default="cpu")
    parser.add_argument("--settings", nargs="+", type=env_case, default=list(SETTINGS),
                        help="env cases: presets, each optionally with overrides after a colon "
                             "(ttenv_v2:belief.filter=particle,belief.particles=256)")
    parser.add_argument("--batch-sizes", nargs="+", type=POSITIVE_INT, default=[1, 16, 256, 4096])
    parser.add_argument("--steps", type=POSITIVE_INT, default=100, help="batched steps per timed window")
    parser.add_argument("--repeats", type=POSITIVE_INT, default=5,
                        help="timed windows per case; the median is reported")
    parser.add_argument("--warmup", type=NON_NEGATIVE_INT, default=20)
    parser.add_argument("--modes", nargs="+", choices=("eager", "compiled"), default=["eager", "compiled"],
                        help="eager steps, and steps through torch.compile (make_env(compile=True))")
    parser.add_argument("--filters", action="store_true", help="one case per belief filter (FILTER_CASES)")
    parser.add_argument("--baseline", type=git_commit, default=None,
                        help="git commit whose code measures every case again")
    parser.add_argument("--rounds", type=POSITIVE_INT, default=1, help="times every case is measured, round by round")
    parser.add_argument("--relative-to", default=None, metavar="SETTING",
                        help="report each case as a fraction of this setting's frames/s in the same round")
    parser.add_argument("--out", type=Path, default=None)
    parser.add_argument("--single", default=None, help=argparse.SUPPRESS)  # one case, JSON in and out
    args = parse_checked(parser)
    if args.single:
        case = json.loads(args.single)
        print(json.dumps(measure(**case)))
        return

    settings = list(FILTER_CASES) if args.filters else args.settings
    if args.relative_to is not None and args.relative_to not in settings:
        parser.error(f"--relative-to {args.relative_to!r} is not one of the settings measured: {settings}")
    rows = []
    started, gflops_before = utc_now(), sgemm_gflops(device=args.device)
    with tempfile.TemporaryDirectory() as tmp:
        codes = {"now": None}
        if args.baseline:
            old = Path(tmp) / "old"
            old.mkdir()
            archive = subprocess.run(["git", "archive", args.baseline], cwd=HERE.parent, capture_output=True,
                                     check=True)
            subprocess.run(["tar", "-x", "-C", str(old)], input=archive.stdout, check=True)
            (old / "aia" / "conf").symlink_to(old / "conf")  # the old code's configs, as its install maps them
            codes[args.baseline] = {"PYTHONPATH": str(old)}
        print(f"{'setting':<40}{'mode':<10}{'code':<10}{'B':>7}{'frames/s':>14}{'ms/step':>10}{'round':>7}")
        for round_ in range(args.rounds):
            for setting in settings:
                for mode in args.modes:
                    for batch_size in args.batch_sizes:
                        for code, env in codes.items():  # the baseline right beside the case it compares with
                            case = dict(setting=setting, batch_size=batch_size, device=args.device,
                                        steps=args.steps, warmup=args.warmup, compile=mode == "compiled",
                                        repeats=args.repeats)
                            row = run_case(case, env)
                            if isinstance(row, str):
                                failure = f"{setting} ({mode}, B={batch_size}, {code}) failed: {row}"
                                if code == "now":
                                    raise SystemExit(f"env_throughput: {failure}")
                                print(f"{failure}; measured on the working tree only", flush=True)
                                continue
                            row |= {"mode": mode, "code": code, "round": round_}
                            rows.append(row)
                            print(f"{setting:<40}{mode:<10}{code:<10}{batch_size:>7}{row['frames_per_s']:>14,.0f}"
                                  f"{row['ms_per_step']:>10.3f}{round_ + 1:>7}", flush=True)

    out = args.out or Path(__file__).parent / "results" / f"env_throughput_{args.device.split(':')[0]}.json"
    out.parent.mkdir(parents=True, exist_ok=True)
    meta = {
        "started_utc": started,
        "finished_utc": utc_now(),
        **git_state(HERE),
        "argv": sys.argv[1:],
        "sgemm_gflops_before": gflops_before,
        "sgemm_gflops_after": sgemm_gflops(device=args.device),
        "torch": torch.__version__,
        "threads": torch.get_num_threads(),
        "machine": platform.machine(),
        "processor": platform.processor() or platform.machine(),
        "gpu": torch.cuda.get_device_name() if args.device.startswith("cuda") else None,
    }
    summary = summarise(rows, args.relative_to)
    out.write_text(json.dumps({"meta": meta, "results": rows, "summary": summary}, indent=2))
    print()
    print(markdown_table(summary))
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
