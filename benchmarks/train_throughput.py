"""Optimiser updates per second of each loss, and frames per second of the whole training loop.

1. Updates: one Adam step (loss, backward, gradient clipping, target-update bookkeeping; ``aia.train.Updater``,
   the training loop's) on a batch of 64 transitions, for DQN, Double DQN and ADFQ, on the 1-target network
   (3 x 128, 8 inputs) and the 3-target network (3 x 256, 20 inputs), eager and compiled
   (``compile.update=true``); median over 5 windows, and the compiled variant's first call (compilation).
2. Loop: ``aia.train.train`` in the paper's regime (one world, one update per frame, evaluation after
   every episode, ``eval.per_rollout`` of them played per batched rollout), eager and with every
   ``compile.*`` switch on. A first job pays for compilation (its time is reported); then frames per second
   of a whole ``--loop-frames`` job (its 500 warm-up frames without updates included) with the split of its
   time over the loop's phases (``aia.timing.PhaseTimer``: collect, buffer, update, evaluate, checkpoint,
   other), and of its updating frames alone ("updating": the frames after the warm-up over the job's time
   minus that of a warm-up-only job), the rate of the bulk of a long run.

Prints a table and writes JSON (default ``benchmarks/results/train_throughput_<device>.json``).

    python benchmarks/train_throughput.py
    python benchmarks/train_throughput.py --parts loop     # only the training loop
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
from hydra import compose, initialize_config_module
from torchrl.objectives import HardUpdate

from aia.envs import make_env
from aia.train import Updater, make_actor, make_loss, train

SETTINGS = {"empty1": "3x128", "small3": "3x256"}
EXPERIMENTS = {"empty1": "paper_empty1", "small3": "paper_small3"}
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
    actor = make_actor(cfg, env)
    batch = env.rollout(2, policy=actor)[:, -1]  # 64 transitions with the training keys
    loss = make_loss(cfg, actor)
    updater = HardUpdate(loss, value_network_update_interval=cfg.target_update_interval)
    update = Updater(loss, torch.optim.Adam(loss.parameters(), lr=cfg.lr), updater, cfg.grad_clip, compile=compile)

    def step():
        update(batch.clone())

    start = time.perf_counter()
    step()
    first = time.perf_counter() - start
    for _ in range(20):
        step()
    windows = []
    for _ in range(repeats):
        if device.startswith("cuda"):
            torch.cuda.synchronize()
        start = time.perf_counter()
        for _ in range(updates):
            step()
        if device.startswith("cuda"):
            torch.cuda.synchronize()
        windows.append((time.perf_counter() - start) / updates)
    seconds = statistics.median(windows)
    return {"kind": "update", "setting": setting, "network": SETTINGS[setting], "algo": algo, "device": device,
            "compiled": compile, "ms_per_update": 1e3 * seconds, "updates_per_s": 1 / seconds,
            "first_call_s": first}


def measure_loop(algo: str, device: str, frames: int, compile: bool) -> dict:
    """Frames per second of a paper-regime training job on empty1: of the whole job, and of its updating part.

    Three jobs run in this process: one of ``frames`` that pays for compilation (``compile=True``: every switch
    under ``compile`` of ``conf/train.yaml``), one of ``frames`` at the steady state, and one of only the
    warm-up (random actions, no updates; it runs about twice as fast). ``frames_per_s`` is the whole job's
    rate, warm-up included; ``updating_frames_per_s`` its frames after the warm-up over its time minus the
    warm-up job's: one update per frame, evaluations included, the rate of the bulk of a long run.
    """
    exploration = "thompson" if algo == "adfq" else "egreedy"
    switches = [f"compile.{name}={str(compile).lower()}" for name in LOOP_SWITCHES]
    overrides = [f"algo={algo}", f"exploration={exploration}", "logger=none", f"device={device}", *switches]
    warmup = _config(*overrides).warmup_frames
    seconds, states = [], []
    for length in (frames, frames, warmup):
        cfg = _config(*overrides, f"frames={length}")
        with tempfile.TemporaryDirectory() as out:
            start = time.perf_counter()
            states.append(train(cfg, Path(out)))
            seconds.append(time.perf_counter() - start)
    job = states[1]
    return {"kind": "loop", "setting": "empty1", "algo": algo, "device": device, "compiled": compile,
            "frames": job.frames, "updates": job.updates, "evaluations": job.evaluations,
            "first_run_s": seconds[0], "seconds": seconds[1], "frames_per_s": job.frames / seconds[1],
            "warmup_s": seconds[2], "updating_frames_per_s": (job.frames - warmup) / (seconds[1] - seconds[2]),
            "ms_per_frame_by_phase": {phase: 1e3 * t / job.frames for phase, t in job.seconds.items()}}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--device", default="cpu")
    parser.add_argument("--loop-frames", type=int, default=2000)
    parser.add_argument("--out", type=Path, default=None)
    parser.add_argument("--parts", default="updates,loop", help="comma-separated: updates, loop")
    args = parser.parse_args()
    parts = set(args.parts.split(","))
    if not parts or not parts <= {"updates", "loop"}:
        parser.error(f"--parts {args.parts!r}: expected a comma-separated subset of updates,loop")

    rows = []
    if "updates" in parts:
        print(f"{'network':<8}{'algo':<6}{'mode':<10}{'ms/update':>11}{'updates/s':>11}{'first call s':>14}")
    for setting in SETTINGS if "updates" in parts else ():
        for algo in ("dqn", "ddqn", "adfq"):
            for compile in (False, True):
                row = measure_updates(setting, algo, args.device, compile)
                rows.append(row)
                mode = "compiled" if compile else "eager"
                print(f"{row['network']:<8}{algo:<6}{mode:<10}{row['ms_per_update']:>11.2f}"
                      f"{row['updates_per_s']:>11,.0f}{row['first_call_s']:>14.1f}", flush=True)
    if "loop" in parts:
        print(f"\n{'loop (empty1, 1 world, 1 update/frame)':<40}{'mode':<10}{'frames/s':>10}{'updating':>10}"
              f"{'first run s':>13}  ms per frame by phase")
    for algo in ("dqn", "ddqn", "adfq") if "loop" in parts else ():
        for compile in (False, True):
            row = measure_loop(algo, args.device, args.loop_frames, compile)
            rows.append(row)
            mode = "compiled" if compile else "eager"
            phases = ", ".join(f"{phase} {ms:.2f}" for phase, ms in
                               sorted(row["ms_per_frame_by_phase"].items(), key=lambda item: -item[1]))
            print(f"{algo:<40}{mode:<10}{row['frames_per_s']:>10,.0f}{row['updating_frames_per_s']:>10,.0f}"
                  f"{row['first_run_s']:>13.1f}  {phases}", flush=True)

    out = args.out or Path(__file__).parent / "results" / f"train_throughput_{args.device.split(':')[0]}.json"
    out.parent.mkdir(parents=True, exist_ok=True)
    meta = {"torch": torch.__version__, "threads": torch.get_num_threads(), "machine": platform.machine(),
            "gpu": torch.cuda.get_device_name() if args.device.startswith("cuda") else None,
            "load_average_1_5_15min": os.getloadavg()}  # other processes' CPU use distorts the timings
    measured = {"update" if part == "updates" else "loop" for part in parts}
    if out.exists() and measured != {"update", "loop"}:  # a partial run keeps the other part's earlier rows
        kept = [row for row in json.loads(out.read_text())["results"] if row["kind"] not in measured]
        rows = kept + rows
    out.write_text(json.dumps({"meta": meta, "results": rows}, indent=2))
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
