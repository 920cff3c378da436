"""Where a population's training steps spend their time, op by op, eager against compiled.

One job of a ``--members`` population in the paper's regime (``benchmarks/population.py``'s rows: one world per
member, one update of batch 64 per frame, here without evaluations) in each mode, compiled after a first job that
compiles (so the profiled job reuses the compiled code, as the benchmark's measured jobs do). ``torch.profiler``
records its steady steps, from the 11th update to the last. For each mode it prints their time a step and the
ops with the most self time on the host and, on CUDA, on the device, with their calls a step; the calls of the
CUDA runtime (kernel launches, copies, synchronisations) say how much a step asks of the host. Written for the
question the first GPU sessions left open (compiled CUDA jobs ran slower than eager ones); on the CPU it
shows the same split.

Prints the tables and writes JSON (default ``benchmarks/results/step_profile_<device>.json``); ``--traces DIR``
also writes each mode's Chrome trace (open in chrome://tracing or Perfetto).

    python benchmarks/step_profile.py --algo dqn --members 20
    python benchmarks/step_profile.py --device cuda --algo adfq --members 80 --traces outputs/traces
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

import torch
from _cli import POSITIVE_INT, folder, number, parse_checked, subset_of
from population import ROWS, member_configs
from torch.profiler import ProfilerActivity, profile

from aia.config.checks import Number
from aia.logging.mcap_logger import git_state
from aia.runtime.timing import synchronize, utc_now
from aia.training import train_population
from aia.training.optimizer import Updater

HERE = Path(__file__).parent
TOP = 15  # ops per table
SKIPPED_UPDATES = 10  # a job's first updates, left out of the profile (compiling, first calls)


def profile_job(algo: str, members: int, compile: bool, warmup: int, frames: int, device: str,
                traces: Path | None) -> dict:
    """The op tables of a job's steady steps: from its ``SKIPPED_UPDATES + 1``-th update to its last, with no
    evaluation (compiled: after a job that compiles)."""
    cfgs = member_configs(algo, members, compile, warmup, warmup + frames, device,
                          extra=["eval.every_episodes=1000000"])  # no evaluation in the job
    updates = frames + 1  # the first update comes with the last warm-up frame
    activities = [ProfilerActivity.CPU] + ([ProfilerActivity.CUDA] if device.startswith("cuda") else [])
    prof = profile(activities=activities)
    window: dict[str, float] = {}
    update = Updater.__call__

    def profiled_update(self: Updater, batch):  # starts the profiler before update SKIPPED_UPDATES + 1
        window["calls"] = window.get("calls", 0) + 1
        if window["calls"] == SKIPPED_UPDATES + 1:
            synchronize(device)
            prof.start()
            window["start"] = time.perf_counter()
        losses = update(self, batch)
        if window["calls"] == updates:  # the job's last update: its step's collection came before it
            synchronize(device)
            window["seconds"] = time.perf_counter() - window["start"]
            prof.stop()
        return losses

    def job() -> None:
        with tempfile.TemporaryDirectory() as out:
            train_population(cfgs, [Path(out) / str(seed) for seed in range(members)])

    if compile:
        job()
    window.clear()
    Updater.__call__ = profiled_update
    try:
        job()
    finally:
        Updater.__call__ = update
    mode = "compiled" if compile else "eager"
    if traces is not None:
        traces.mkdir(parents=True, exist_ok=True)
        prof.export_chrome_trace(str(traces / f"{algo}_p{members}_{mode}.json"))
    steps = updates - SKIPPED_UPDATES
    events = prof.key_averages()

    def table(attribute: str) -> list[dict]:
        ranked = sorted(events, key=lambda e: getattr(e, attribute), reverse=True)[:TOP]
        return [{"op": e.key, "ms_per_step": getattr(e, attribute) / 1e3 / steps, "calls_per_step": e.count / steps}
                for e in ranked if getattr(e, attribute) > 0]

    runtime = {e.key: e.count / steps for e in events if e.key.startswith("cuda")}
    return {"algo": algo, "members": members, "mode": mode, "device": device, "profiled_steps": steps,
            "ms_per_step": 1e3 * window["seconds"] / steps, "host_self": table("self_cpu_time_total"),
            "device_self": table("self_device_time_total") if device.startswith("cuda") else [],
            "cuda_runtime_calls_per_step": runtime}


def _print(row: dict) -> None:
    print(f"\n{row['algo']} P={row['members']} {row['mode']} on {row['device']}: {row['profiled_steps']} steps "
          f"profiled, {row['ms_per_step']:.2f} ms a step under the profiler")
    for title, key in (("host, self", "host_self"), ("device, self", "device_self")):
        if row[key]:
            print(f"  {title:<60}{'ms/step':>9}{'calls/step':>12}")
            for op in row[key]:
                print(f"  {op['op'][:60]:<60}{op['ms_per_step']:>9.3f}{op['calls_per_step']:>12.1f}")
    if row["cuda_runtime_calls_per_step"]:
        calls = ", ".join(f"{name} {n:.1f}" for name, n in sorted(row["cuda_runtime_calls_per_step"].items(),
                                                                   key=lambda i: -i[1]))
        print(f"  CUDA runtime calls a step: {calls}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--device", default="cpu")
    parser.add_argument("--algo", default="dqn", choices=sorted(ROWS))
    parser.add_argument("--members", type=POSITIVE_INT, default=20)
    parser.add_argument("--modes", type=subset_of(("eager", "compiled")), default="eager,compiled",
                        help="comma-separated: eager, compiled")
    parser.add_argument("--warmup", type=POSITIVE_INT, default=100, help="warm-up frames of the job")
    parser.add_argument("--frames", type=number(Number(ge=SKIPPED_UPDATES, integer=True)), default=200,
                        help=f"updating frames of the job (its first {SKIPPED_UPDATES} updates are not profiled)")
    parser.add_argument("--traces", type=folder, default=None, help="a folder for each mode's Chrome trace")
    parser.add_argument("--out", type=Path, default=None)
    args = parse_checked(parser)
    out = args.out or HERE / "results" / f"step_profile_{args.device.split(':')[0]}.json"
    out.parent.mkdir(parents=True, exist_ok=True)
    meta = {"started_utc": utc_now(),
            **git_state(HERE), "argv": sys.argv[1:], "torch": torch.__version__, "threads": torch.get_num_threads()}
    rows = []
    for mode in args.modes:
        rows.append(profile_job(args.algo, args.members, mode == "compiled", args.warmup, args.frames,
                                args.device, args.traces))
        _print(rows[-1])
        out.write_text(json.dumps({"meta": meta, "results": rows}, indent=2))
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
