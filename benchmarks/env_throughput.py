"""Frames per second of the transformed tracking env under random actions.

For each setting and batch size B, steps the env (with its feature and reward transforms) for a fixed
number of batched steps after a warm-up and reports frames/s (= B * steps / seconds) and the time of one
batched step. Each case runs in a fresh process, as a user's run would (in one long process, compiled
code of earlier envs adds guard checks to later ones). Prints a table and writes JSON (default
``benchmarks/results/env_throughput_<device>.json``).

A case is a preset, optionally with env overrides after a colon (``small2:belief.filter=particle``).
``--filters`` measures one case per belief filter (kf, the UKF over 3 and 5 states, the particle filter with
256 and 1,024 particles); ``--baseline REV`` measures every case again with the code of commit ``REV`` in the
same run (the cases that commit cannot build are left out), so a change's cost is a ratio within one run.

    python benchmarks/env_throughput.py                     # CPU, B in {1, 16, 256, 4096}, the four settings
    python benchmarks/env_throughput.py --device cuda --batch-sizes 1 1024 16384 65536
    python benchmarks/env_throughput.py --filters --batch-sizes 1 4096 --baseline 54a9a5a
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

from aia.envs import make_env
from aia.runtime.timing import synchronize

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


def markdown_table(rows: list[dict]) -> str:
    """Frames/s per setting and batch size, eager and compiled side by side (for the README)."""
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
                entries.append(f"{row['frames_per_s']:,.0f} ({row['ms_per_step']:.2f})" if row else "")
            lines.append(f"| {setting} | {size} | " + " | ".join(entries) + " |")
    return "\n".join(lines)


def _column(row: dict) -> str:
    """A table column: the mode, and the code's commit when it is a baseline's."""
    return row["mode"] if row.get("code", "now") == "now" else f"{row['mode']} @ {row['code']}"


def run_case(case: dict, env: dict | None = None) -> dict | None:
    """One case in a fresh process (with ``env`` added to its environment); None when it fails."""
    done = subprocess.run([sys.executable, str(HERE / "env_throughput.py"), "--single", json.dumps(case)],
                          capture_output=True, text=True, env=os.environ | (env or {}), cwd=env and env["PYTHONPATH"])
    if done.returncode != 0:
        return None
    return json.loads(done.stdout.strip().splitlines()[-1])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--device", default="cpu")
    parser.add_argument("--settings", nargs="+", default=list(SETTINGS))
    parser.add_argument("--batch-sizes", nargs="+", type=int, default=[1, 16, 256, 4096])
    parser.add_argument("--steps", type=int, default=100, help="batched steps per timed window")
    parser.add_argument("--repeats", type=int, default=5, help="timed windows per case; the median is reported")
    parser.add_argument("--warmup", type=int, default=20)
    parser.add_argument("--modes", nargs="+", choices=("eager", "compiled"), default=["eager", "compiled"],
                        help="eager steps, and steps through torch.compile (make_env(compile=True))")
    parser.add_argument("--filters", action="store_true", help="one case per belief filter (FILTER_CASES)")
    parser.add_argument("--baseline", default=None, help="git commit whose code measures every case again")
    parser.add_argument("--out", type=Path, default=None)
    parser.add_argument("--single", default=None, help=argparse.SUPPRESS)  # one case, JSON in and out
    args = parser.parse_args()
    if args.single:
        case = json.loads(args.single)
        print(json.dumps(measure(**case)))
        return

    settings = list(FILTER_CASES) if args.filters else args.settings
    rows = []
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
        print(f"{'setting':<40}{'mode':<10}{'code':<10}{'B':>7}{'frames/s':>14}{'ms/step':>10}")
        for setting in settings:
            for mode in args.modes:
                for batch_size in args.batch_sizes:
                    for code, env in codes.items():  # the baseline right beside the case it compares with
                        case = dict(setting=setting, batch_size=batch_size, device=args.device, steps=args.steps,
                                    warmup=args.warmup, compile=mode == "compiled", repeats=args.repeats)
                        row = run_case(case, env)
                        if row is None:
                            if code == "now":
                                raise SystemExit(f"{setting} ({mode}, B={batch_size}) failed: rerun it alone")
                            continue
                        row |= {"mode": mode, "code": code}
                        rows.append(row)
                        print(f"{setting:<40}{mode:<10}{code:<10}{batch_size:>7}{row['frames_per_s']:>14,.0f}"
                              f"{row['ms_per_step']:>10.3f}", flush=True)

    out = args.out or Path(__file__).parent / "results" / f"env_throughput_{args.device.split(':')[0]}.json"
    out.parent.mkdir(parents=True, exist_ok=True)
    meta = {
        "torch": torch.__version__,
        "threads": torch.get_num_threads(),
        "machine": platform.machine(),
        "processor": platform.processor() or platform.machine(),
        "gpu": torch.cuda.get_device_name() if args.device.startswith("cuda") else None,
    }
    out.write_text(json.dumps({"meta": meta, "results": rows}, indent=2))
    print()
    print(markdown_table(rows))
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
