"""How fast run logs are written, and what logging costs a default ``aia-train`` run.

1. Scalars: ``MCAPLogger.log_scalar`` messages per second (zstd chunks), against the naive way
   (``json.dumps`` of a dict per message into the same ``mcap`` writer).
2. Scenes: frames per second that ``SceneRecorder`` writes (``/tf`` + ``/scene`` per step, ``/world`` per
   episode) while it replays stored steps of obstacles1 with 3 targets; the env's own time is excluded.
3. Overhead: a default ``aia-train`` run with ``logger=mcap``, every logging call timed in place; reports
   the share of the run's wall time spent logging.

Each figure is the median of ``--repeats`` windows. Prints a table and writes JSON (default
``benchmarks/results/log_throughput.json``).

    python benchmarks/log_throughput.py
    python benchmarks/log_throughput.py --skip-train      # only the writer figures (seconds, not minutes)
"""

from __future__ import annotations

import argparse
import functools
import json
import platform
import statistics
import tempfile
import time
from pathlib import Path

import torch
from _cli import POSITIVE_INT, parse_checked
from mcap.writer import Writer
from omegaconf import DictConfig

from aia.apps.hydra_app import COMPOSITION_ERRORS, composition_message
from aia.config.composing import compose_config
from aia.config.errors import ConfigError, one_line
from aia.config.schemas import SCHEMAS
from aia.config.validation import validate_train_config
from aia.envs import make_env
from aia.logging import MCAPLogger, SceneRecorder
from aia.logging.mcap_logger import MCAPRun
from aia.training import train


def scalars_per_second(messages: int, repeats: int) -> dict:
    """``log_scalar`` throughput, and the naive ``json.dumps`` writer's for comparison."""
    def ours(folder: Path) -> float:
        logger = MCAPLogger("bench", folder)
        start = time.perf_counter()
        for i in range(messages):
            logger.log_scalar("train/loss", 0.001 * i, step=i)
        logger.close()
        return messages / (time.perf_counter() - start)

    def naive(folder: Path) -> float:
        with open(folder / "naive.mcap", "wb") as f:
            writer = Writer(f)
            writer.start()
            schema = writer.register_schema("aia.Scalar", "jsonschema", b"{}")
            channel = writer.register_channel("train/loss", "json", schema)
            start = time.perf_counter()
            for i in range(messages):
                now = time.time_ns()
                writer.add_message(channel, now, json.dumps({"frame": i, "value": 0.001 * i}).encode(), now)
            writer.finish()
            return messages / (time.perf_counter() - start)

    results = {}
    for name, fn in (("mcap_logger", ours), ("naive_json", naive)):
        rates = []
        for _ in range(repeats):
            with tempfile.TemporaryDirectory() as folder:
                rates.append(fn(Path(folder)))
        results[name] = statistics.median(rates)
    return {"messages": messages, "scalars_per_s": results["mcap_logger"],
            "naive_json_scalars_per_s": results["naive_json"]}


def scene_frames_per_second(episodes: int, repeats: int, setting: str = "obstacles1", targets: int = 3) -> dict:
    """Frames/s of the recorder alone, replaying the steps of stored episodes of ``setting``."""
    env = make_env(setting, batch_size=1, seed=0, overrides=[f"num_targets={targets}"])
    steps = env.base_env.config.max_steps
    rollout = env.rollout(steps, break_when_any_done=False)
    first = env.reset()
    stored = [rollout[:, t]["next"] for t in range(steps)]
    rates = []
    for _ in range(repeats):
        with tempfile.TemporaryDirectory() as folder:
            logger = MCAPLogger("bench", folder)
            recorder = SceneRecorder(logger)
            env.append_transform(recorder)
            start = time.perf_counter()
            for episode in range(episodes):
                recorder.record(episode=episode, frame=episode * steps)
                recorder._reset(first, first)  # what the env's reset runs: /world and the first frame
                for next_td in stored:
                    recorder(next_td)
            logger.close()
            rates.append(episodes * (steps + 1) / (time.perf_counter() - start))
            env.transform.pop(-1)
    return {"setting": setting, "targets": targets, "frames": episodes * (steps + 1),
            "scene_frames_per_s": statistics.median(rates)}


class _Stopwatch:
    """Accumulates the time spent in wrapped functions (outermost calls only)."""

    def __init__(self) -> None:
        self.seconds = 0.0
        self.calls = 0
        self._depth = 0

    def wrap(self, fn):
        @functools.wraps(fn)
        def timed(*args, **kwargs):
            self._depth += 1
            start = time.perf_counter()
            try:
                return fn(*args, **kwargs)
            finally:
                self._depth -= 1
                if self._depth == 0:
                    self.seconds += time.perf_counter() - start
                    self.calls += 1
        return timed


def train_config(overrides: list[str]) -> DictConfig:
    """The config of the ``aia-train`` run with ``logger=mcap`` and ``overrides``, composed and validated as
    ``aia-train`` does: a :class:`ConfigError` (or the error Hydra raised, for :func:`composition_message`) if
    ``aia-train`` would refuse them."""
    cfg = compose_config("train", ["logger=mcap", *overrides])
    validate_train_config(cfg)
    return cfg


def training_overhead(cfg: DictConfig, overrides: list[str]) -> dict:
    """Share of the wall time of an ``aia-train`` run of ``cfg`` spent in the MCAP logger and the recorder."""
    watch = _Stopwatch()
    patched = [(MCAPLogger, name) for name in ("log_scalar", "log_hparams", "log_text", "flush", "shutdown")]
    patched += [(MCAPRun, "__init__"), (SceneRecorder, "_write_frame"), (SceneRecorder, "_reset")]
    originals = [(cls, name, getattr(cls, name)) for cls, name in patched]
    for cls, name, fn in originals:
        setattr(cls, name, watch.wrap(fn))
    try:
        with tempfile.TemporaryDirectory() as folder:
            start = time.perf_counter()
            state = train(cfg, Path(folder))
            seconds = time.perf_counter() - start
            size = (Path(folder) / cfg.logger.file).stat().st_size
    finally:
        for cls, name, fn in originals:
            setattr(cls, name, fn)
    return {"overrides": overrides, "frames": state.frames, "run_s": seconds, "logging_s": watch.seconds,
            "logging_calls": watch.calls, "overhead_pct": 100 * watch.seconds / seconds, "log_bytes": size}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--messages", type=POSITIVE_INT, default=200_000, help="scalars per timed window")
    parser.add_argument("--episodes", type=POSITIVE_INT, default=20, help="recorded episodes per timed window")
    parser.add_argument("--repeats", type=POSITIVE_INT, default=3)
    parser.add_argument("--skip-train", action="store_true", help="skip the aia-train overhead run")
    parser.add_argument("--train-overrides", nargs="*", default=[],
                        help="overrides of the aia-train run, as aia-train takes them (algo=adfq frames=5000)")
    parser.add_argument("--out", type=Path, default=Path(__file__).parent / "results" / "log_throughput.json")
    args = parse_checked(parser)
    cfg = None
    if not args.skip_train:  # refused before any measuring, in aia-train's words
        try:
            cfg = train_config(args.train_overrides)
        except (*COMPOSITION_ERRORS, ConfigError) as err:
            message = err if isinstance(err, ConfigError) else composition_message(err, SCHEMAS["train"])
            parser.error(f"--train-overrides: {one_line(message)}")
    torch.manual_seed(0)

    scalars = scalars_per_second(args.messages, args.repeats)
    scenes = scene_frames_per_second(args.episodes, args.repeats)
    print("| figure | value | target |\n|---|---|---|")
    print(f"| scalar messages/s (MCAPLogger) | {scalars['scalars_per_s']:,.0f} | >= 100,000 |")
    print(f"| scalar messages/s (json.dumps into mcap, for comparison) | {scalars['naive_json_scalars_per_s']:,.0f} "
          f"| |")
    print(f"| scene frames/s (obstacles1, 3 targets) | {scenes['scene_frames_per_s']:,.0f} | >= 4,000 |", flush=True)
    overhead = None
    if not args.skip_train:
        overhead = training_overhead(cfg, args.train_overrides)
        print(f"| logging share of a default aia-train run ({overhead['run_s']:.0f} s, {overhead['logging_calls']} "
              f"calls, {overhead['log_bytes'] / 1e3:.0f} kB) | {overhead['overhead_pct']:.2f} % | < 3 % |")

    meta = {"torch": torch.__version__, "threads": torch.get_num_threads(), "machine": platform.machine(),
            "python": platform.python_version()}
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps({"meta": meta, "scalars": scalars, "scenes": scenes, "training": overhead},
                                   indent=2))
    print(f"results written to {args.out}")


if __name__ == "__main__":
    main()
