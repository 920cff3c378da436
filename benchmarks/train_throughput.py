"""Optimiser updates per second of each loss, and frames per second of the whole training loop.

1. Updates: one Adam step (loss, backward, gradient clipping, target-update bookkeeping;
   ``aia.training.optimizer.Updater``, the training loop's, for a population of one) on a batch of 64
   transitions with the replay buffer's keys (each update gets a fresh copy, made outside the timing), for
   DQN, Double DQN and ADFQ, on the 1-target network (3 x 128, 8 inputs) and the 3-target network
   (3 x 256, 20 inputs), eager and compiled (``compile.update=true``); median over 5 windows, and the
   compiled variant's first call (compilation).
2. Loop: ``aia.training.train`` in the paper's regime (one world, one update per frame, evaluation after
   every episode, ``eval.per_rollout`` of them played per batched rollout), eager and with every
   ``compile.*`` switch on: frames per second of the updating frames (the bulk of a long run; median of
   ``--repeats`` jobs of ``--loop-frames`` frames, ``measure_loop``), with the split of a frame's time over
   the loop's phases (``aia.runtime.timing.PhaseTimer``: collect, buffer, update, evaluate, other); also the wall
   time of a whole job and of the first (compiling) job.

The virtual machines we measure on vary by up to 2x over minutes: the JSON keeps the loop's rate of every
job, and its ``meta`` a calibration (a matmul's and a tiny op's microseconds) taken before and after.

Prints a table and writes JSON (default ``benchmarks/results/train_throughput_<device>.json``).

    python benchmarks/train_throughput.py
    python benchmarks/train_throughput.py --parts loop     # only the training loop
    python benchmarks/train_throughput.py --parts loop --algos adfq
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import tempfile
import time
from pathlib import Path

import torch
from _cli import POSITIVE_INT, parse_checked, subset_of
from hydra import compose, initialize_config_module
from torchrl.objectives import HardUpdate

from aia.envs import make_env
from aia.modules.q_networks import make_qvalue_actor
from aia.runtime.timing import synchronize
from aia.training import train
from aia.training.components import make_loss, make_stacked_network
from aia.training.optimizer import StackedAdam, Updater

SETTINGS = {"empty1": "3x128", "small3": "3x256"}
EXPERIMENTS = {"empty1": "paper_empty1", "small3": "paper_small3"}
ALGOS = ("dqn", "ddqn", "adfq")
LOOP_SWITCHES = ("update", "env", "policy")  # the compile.* switches of conf/train.yaml


def _config(*overrides: str):
    with initialize_config_module(config_module="aia.conf", version_base="1.3"):
        return compose(config_name="train", overrides=list(overrides))


def measure_updates(setting: str, algo: str, device: str, compile: bool, updates: int = 200,
                    repeats: int = 5) -> dict:
    """Median time of one optimiser step on a batch of 64 replayed transitions (and of the first step)."""
    exploration = "thompson" if algo == "adfq" else "egreedy"
    cfg = _config(f"experiment={EXPERIMENTS[setting]}", f"algo={algo}", f"exploration={exploration}",
                  f"device={device}")
    env = make_env(setting, batch_size=64, device=device, seed=0)
    network = make_stacked_network([cfg], env.observation_spec["observation"].shape[-1], env.action_spec.n)
    loss = make_loss([cfg], make_qvalue_actor(network, env.action_spec, adfq=algo == "adfq"))
    # 64 transitions with the keys that the loop's replay buffer keeps (the loss's in_keys), one member
    batch = env.rollout(2)[:, -1].select(*loss.in_keys).unsqueeze(0)
    updater = HardUpdate(loss, value_network_update_interval=cfg.target_update_interval)
    optimizer = StackedAdam(list(loss.value_network_params.values(True, True)), [cfg.lr])
    update = Updater(loss, optimizer, updater, cfg.grad_clip, compile=compile)

    start = time.perf_counter()
    update(batch.clone())  # each update gets a fresh batch, as a sample of the replay buffer
    first = time.perf_counter() - start
    for _ in range(20):
        update(batch.clone())
    windows = []
    for _ in range(repeats):
        batches = [batch.clone() for _ in range(updates)]  # made outside the timed window
        synchronize(device)
        start = time.perf_counter()
        for fresh in batches:
            update(fresh)
        synchronize(device)
        windows.append((time.perf_counter() - start) / updates)
    seconds = statistics.median(windows)
    return {"kind": "update", "setting": setting, "network": SETTINGS[setting], "algo": algo, "device": device,
            "compiled": compile, "ms_per_update": 1e3 * seconds, "updates_per_s": 1 / seconds,
            "first_call_s": first}


def measure_loop(algo: str, device: str, frames: int, compile: bool, repeats: int) -> dict:
    """Frames per second of a paper-regime training job on empty1 after its warm-up (its updating frames).

    A first job compiles (``compile=True``: every switch under ``compile`` of ``conf/train.yaml``) what later
    jobs of the process reuse (the env's, the transforms' and the evaluation policy's functions); its time
    is reported. Then ``repeats`` jobs of ``frames`` frames and one of only the warm-up (random actions, no
    updates; it runs about twice as fast). The rate of the updating frames (one update each, evaluations
    included) is theirs over a job's time minus the warm-up job's and minus the job's first optimiser step
    (the ``first_update`` phase: each job compiles its own, ``aia.runtime.compiling.compiled_update``): the rate of
    the bulk of a long run. The median job also gives the split of an updating frame's time over the loop's
    phases (its ``aia.runtime.timing.PhaseTimer`` totals minus the warm-up job's: collect, buffer, update, evaluate,
    other) and the wall time of a whole job.
    """
    exploration = "thompson" if algo == "adfq" else "egreedy"
    switches = [f"compile.{name}={str(compile).lower()}" for name in LOOP_SWITCHES]
    overrides = [f"algo={algo}", f"exploration={exploration}", "logger=none", f"device={device}", *switches]
    warmup = _config(*overrides).warmup_frames

    def job(length: int):
        cfg = _config(*overrides, f"frames={length}")
        with tempfile.TemporaryDirectory() as out:
            start = time.perf_counter()
            state = train(cfg, Path(out))
            return time.perf_counter() - start, state.seconds

    first_run_s, _ = job(frames)
    jobs = [job(frames) for _ in range(repeats)]
    warmup_s, warmup_phases = job(warmup)
    warmup_s -= warmup_phases.pop("first_update", 0.0)  # its last frame makes one (compiling) update
    runs = []
    for job_s, phases in jobs:
        updating_s = job_s - warmup_s - phases["first_update"]
        split = {phase: 1e3 * (t - warmup_phases.get(phase, 0.0)) / (frames - warmup)
                 for phase, t in phases.items() if phase != "first_update"}
        runs.append({"rate": (frames - warmup) / updating_s, "job_s": job_s, "split": split})
    runs.sort(key=lambda run: run["rate"])
    median = runs[len(runs) // 2]
    return {"kind": "loop", "setting": "empty1", "algo": algo, "device": device, "compiled": compile,
            "frames": frames, "warmup_frames": warmup, "first_run_s": first_run_s, "job_s": median["job_s"],
            "warmup_s": warmup_s, "updating_frames_per_s": median["rate"],
            "updating_frames_per_s_runs": [run["rate"] for run in runs],
            "ms_per_updating_frame_by_phase": median["split"]}


def calibrate() -> dict:
    """How fast this machine runs now: microseconds of a 128x256 by 256x256 matmul and of a tiny tensor op.

    A coarse check, taken before and after the measurements: it shows a CPU slowed for the whole run, not
    every swing of a shared VM (the loop's rate has moved by 1.4x while these two stayed within 10 %).
    """
    a, b, x = torch.randn(128, 256), torch.randn(256, 256), torch.randn(8)
    result = {}
    for name, op, calls in (("matmul_us", lambda: a @ b, 2000), ("tiny_op_us", lambda: x + 1, 20000)):
        for _ in range(calls // 20):
            op()
        start = time.perf_counter()
        for _ in range(calls):
            op()
        result[name] = 1e6 * (time.perf_counter() - start) / calls
    return result


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--device", default="cpu")
    parser.add_argument("--loop-frames", type=POSITIVE_INT, default=2000,
                        help="frames of a loop job (conf/train.yaml's warmup_frames of them warm-up)")
    parser.add_argument("--repeats", type=POSITIVE_INT, default=3, help="loop jobs per variant (median)")
    parser.add_argument("--out", type=Path, default=None)
    parser.add_argument("--parts", type=subset_of(("updates", "loop")), default="updates,loop",
                        help="comma-separated: updates, loop")
    parser.add_argument("--algos", type=subset_of(ALGOS), default=",".join(ALGOS),
                        help="comma-separated subset of dqn, ddqn, adfq")
    args = parse_checked(parser)
    parts, algos = set(args.parts), args.algos
    warmup = _config().warmup_frames
    if args.loop_frames <= warmup:
        parser.error(f"--loop-frames {args.loop_frames}: expected more than the {warmup} warm-up frames "
                     "(conf/train.yaml's warmup_frames)")

    calibration_before = calibrate()
    rows = []
    if "updates" in parts:
        print(f"{'network':<8}{'algo':<6}{'mode':<10}{'ms/update':>11}{'updates/s':>11}{'first call s':>14}")
    for setting in SETTINGS if "updates" in parts else ():
        for algo in algos:
            for compile in (False, True):
                row = measure_updates(setting, algo, args.device, compile)
                rows.append(row)
                mode = "compiled" if compile else "eager"
                print(f"{row['network']:<8}{algo:<6}{mode:<10}{row['ms_per_update']:>11.2f}"
                      f"{row['updates_per_s']:>11,.0f}{row['first_call_s']:>14.1f}", flush=True)
    if "loop" in parts:
        print(f"\n{'loop (empty1, 1 world, 1 update/frame)':<40}{'mode':<10}{'updating frames/s':>24}"
              f"{'job s':>8}{'first s':>9}  ms per frame by phase")
    for algo in algos if "loop" in parts else ():
        for compile in (False, True):
            row = measure_loop(algo, args.device, args.loop_frames, compile, args.repeats)
            rows.append(row)
            mode = "compiled" if compile else "eager"
            runs = "/".join(f"{rate:.0f}" for rate in row["updating_frames_per_s_runs"])
            phases = ", ".join(f"{phase} {ms:.2f}" for phase, ms in
                               sorted(row["ms_per_updating_frame_by_phase"].items(), key=lambda item: -item[1]))
            print(f"{algo:<40}{mode:<10}{row['updating_frames_per_s']:>8,.0f} ({runs:>13}){row['job_s']:>8.1f}"
                  f"{row['first_run_s']:>9.1f}  {phases}", flush=True)

    out = args.out or Path(__file__).parent / "results" / f"train_throughput_{args.device.split(':')[0]}.json"
    out.parent.mkdir(parents=True, exist_ok=True)
    meta = {"torch": torch.__version__, "threads": torch.get_num_threads(), "machine": platform.machine(),
            "gpu": torch.cuda.get_device_name() if args.device.startswith("cuda") else None,
            "load_average_1_5_15min": os.getloadavg(),  # other processes' CPU use distorts the timings
            "calibration_before": calibration_before, "calibration_after": calibrate()}
    measured = {("update" if part == "updates" else "loop", algo) for part in parts for algo in algos}
    if out.exists():  # a partial run keeps the earlier rows it did not measure again (meta: this run's)
        earlier = json.loads(out.read_text())["results"]
        rows = [row for row in earlier if (row["kind"], row["algo"]) not in measured] + rows
    out.write_text(json.dumps({"meta": meta, "results": rows}, indent=2))
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
