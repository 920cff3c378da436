"""Random maps (``env.map=random_obstacles``): the seconds to draw new maps for every world at an episode's start,
and the memory of the env at that size.

1. Generation: ``WorldMapGeometry.draw_maps`` for ``B`` worlds' episode keys (the layouts and their start
   cells, written into the env's buffers on the CPU, copied to another device), as a reset draws them; the
   median of ``--repeats`` calls after a warm-up (numba compiles on the first), each for fresh episode keys.
2. Memory: the peak resident memory of a process that builds ``make_env("random_obstacles", B)``, resets it and
   steps it ``--steps`` times (compiled with ``--compile``), measured in a fresh process.

Prints one line per figure and writes JSON (default ``benchmarks/results/map_generation_<device>.json``).

    python benchmarks/map_generation.py                       # B = 4096, the preset's 36.2 m maps at 0.2 m
    python benchmarks/map_generation.py --batch-size 1024 --device cuda
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import resource
import statistics
import subprocess
import sys
import time
from pathlib import Path

import torch
from _cli import POSITIVE_INT, parse_checked

from aia import rng
from aia.envs import load_env_config, make_env
from aia.envs.map_generator import RandomObstacles
from aia.envs.sensing import WorldMapGeometry

HERE = Path(__file__).resolve().parent


def generation_seconds(batch_size: int, device: str, repeats: int) -> tuple[list[float], list[float]]:
    """Wall-clock and CPU seconds (all threads: what the call costs on a machine shared with other work) per call of
    drawing ``batch_size`` maps, one per repeat (after a warm-up)."""
    config = load_env_config("random_obstacles")
    layouts = RandomObstacles(config.random_map, config.margin)
    geometry = WorldMapGeometry(batch_size, tuple(config.random_map.size), config.random_map.resolution,
                                config.margin, config.sensor.range, 2.0, config.sensor.obstacle_ray_spacing,
                                config.collision_supersample, device)
    world = rng.world_keys(0, batch_size, device)
    worlds = torch.arange(batch_size, device=device)
    seconds, cpu = [], []
    for episode in range(repeats + 1):
        keys = rng.episode_keys(world, torch.full_like(world, episode + 1))
        start, start_cpu = time.perf_counter(), time.process_time()
        geometry.draw_maps(worlds, layouts, keys)
        if device != "cpu":
            torch.cuda.synchronize(device)
        seconds.append(time.perf_counter() - start)
        cpu.append(time.process_time() - start_cpu)
    return seconds[1:], cpu[1:]


def peak_memory(batch_size: int, device: str, steps: int, compile: bool) -> float:
    """Peak resident memory (GB) of this process after building, resetting and stepping the env."""
    env = make_env("random_obstacles", batch_size=batch_size, device=device, seed=0, compile=compile)
    td = env.reset()
    for _ in range(steps):
        td.set("action", torch.randint(0, env.action_spec.n, (batch_size,), device=device))
        _, td = env.step_and_maybe_reset(td)
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 2**20


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--batch-size", type=POSITIVE_INT, default=4096)
    parser.add_argument("--device", default="cpu")
    parser.add_argument("--repeats", type=POSITIVE_INT, default=5)
    parser.add_argument("--steps", type=POSITIVE_INT, default=20, help="steps of the memory figure's env")
    parser.add_argument("--compile", action="store_true", help="the memory figure's env compiled")
    parser.add_argument("--out", type=Path, default=None)
    parser.add_argument("--memory-only", action="store_true", help=argparse.SUPPRESS)  # the fresh process
    args = parse_checked(parser)
    if args.memory_only:
        print(peak_memory(args.batch_size, args.device, args.steps, args.compile))
        return

    seconds, cpu = generation_seconds(args.batch_size, args.device, args.repeats)
    command = [sys.executable, __file__, "--memory-only", "--batch-size", str(args.batch_size), "--device",
               args.device, "--steps", str(args.steps), *(["--compile"] if args.compile else [])]
    memory = float(subprocess.run(command, capture_output=True, text=True, check=True).stdout.split()[-1])
    result = {"batch_size": args.batch_size, "device": args.device,
              "machine": platform.processor() or platform.machine(), "threads": torch.get_num_threads(),
              "generation_s_median": statistics.median(seconds), "generation_s": seconds,
              "generation_cpu_s_median": statistics.median(cpu), "load_average": os.getloadavg()[0],
              "peak_memory_gb": memory, "compiled": args.compile}
    print(f"new maps for {args.batch_size} worlds: {result['generation_s_median']:.3f} s (median of "
          f"{args.repeats}; {min(seconds):.3f}-{max(seconds):.3f}), {statistics.median(cpu):.3f} CPU s over all "
          f"threads (load average {os.getloadavg()[0]:.1f})")
    print(f"env at {args.batch_size} worlds ({'compiled' if args.compile else 'eager'}, {args.steps} steps): "
          f"peak memory {memory:.2f} GB")
    out = args.out or HERE / "results" / f"map_generation_{args.device}.json"
    out.write_text(json.dumps(result, indent=2) + "\n")


if __name__ == "__main__":
    main()
