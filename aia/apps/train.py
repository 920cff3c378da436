"""``aia-train``: train a DQN, Double DQN or ADFQ policy on a tracking setting (Hydra app).

``aia-train --help`` lists the config groups (env, algo, exploration, logger) and every field. A SIGTERM
(a cluster's time limit, ``kill``) ends the run like Ctrl-C: the log is closed and stays readable.
"""

from __future__ import annotations

import signal
import threading
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import hydra
from hydra.core.hydra_config import HydraConfig
from omegaconf import DictConfig

from aia.timing import PhaseTimer
from aia.train import train


@contextmanager
def sigterm_as_exit() -> Iterator[None]:
    """Turn SIGTERM into ``SystemExit(143)`` so that ``finally`` blocks (closing the log) run."""
    if threading.current_thread() is not threading.main_thread():
        yield  # only the main thread may install handlers; a launcher's worker thread keeps the default
        return

    def _exit(signum: int, frame) -> None:
        raise SystemExit(128 + signum)

    previous = signal.signal(signal.SIGTERM, _exit)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, previous)


@hydra.main(config_path="pkg://aia.conf", config_name="train", version_base="1.3")
def main(cfg: DictConfig) -> None:
    """Entry point of ``aia-train``."""
    out_dir = Path(HydraConfig.get().runtime.output_dir)
    choices = HydraConfig.get().runtime.choices
    print(f"training {cfg.algo.name} ({cfg.exploration.name}) on {choices.get('env')} for {cfg.frames} frames, "
          f"seed {cfg.seed}")
    with sigterm_as_exit():
        state = train(cfg, out_dir)
    last = f"{state.eval_scores[-1]:.1f}" if state.eval_scores else "n/a"
    print(f"{state.frames} frames, {state.episodes} episodes, {state.updates} updates; last eval score {last}")
    print(f"time: {PhaseTimer(state.seconds).summary()}")
    if cfg.logger.name == "mcap":
        log = out_dir / cfg.logger.file
        print(f"log written to {log} (inspect: aia-log summary {log})")
    else:
        print(f"log written to {out_dir}")
    print(f"checkpoint: {out_dir / 'checkpoints' / 'last.pt'}")


if __name__ == "__main__":
    main()
