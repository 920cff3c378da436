"""``aia-train``: train a DQN, Double DQN or ADFQ policy on a tracking setting (Hydra app).

``aia-train --help`` lists the config groups (env, algo, exploration, logger) and every field. SIGTERM,
SIGINT (Ctrl-C) and SIGUSR1 (a cluster's preemption or time limit) end the run at the end of its episode: the
pending evaluations are played, the checkpoint written and the log closed; the app says where the checkpoint
is and exits with status 128 + signal (143 for SIGTERM). ``resume=auto`` continues from it.

The training stack (torch, TorchRL) is imported inside the functions that train, so that ``--help`` and a refused
config answer before it loads: ``aia-train --help`` took 4.3-4.5 s when this module imported it, 1.3-1.5 s now.
"""

from __future__ import annotations

import signal
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING

from hydra.core.hydra_config import HydraConfig
from omegaconf import DictConfig

from aia.apps.hydra_app import hydra_app, run_valid_jobs
from aia.config.validation import validate_train_config
from aia.logging.segments import last_segment
from aia.runtime.stopping import StopOnSignals
from aia.runtime.timing import PhaseTimer
from aia.training.checkpoint_names import CHECKPOINT_NAME

if TYPE_CHECKING:
    from aia.training import TrainingState


@hydra_app("aia-train", config_name="train", population="aia.apps.train.train_jobs")  # bad input: one line, exit 2
def main(cfg: DictConfig) -> float:
    """Entry point of ``aia-train``; returns the run's search objective (:func:`~aia.evaluation.search_objective`).
    The config is validated before anything is printed or written."""
    out_dir = Path(HydraConfig.get().runtime.output_dir)
    validate_job(cfg, out_dir)
    from aia.evaluation import search_objective
    from aia.training import train_population

    choices = HydraConfig.get().runtime.choices
    print(f"training {cfg.algo.name} ({cfg.exploration.name}) on {choices.get('env')} for {cfg.frames} frames, "
          f"seed {cfg.seed}")
    note_no_updates(cfg)
    with StopOnSignals() as stop:
        state = train_population([cfg], [out_dir], stop, validated=True)[0]
    report(cfg, out_dir, state)
    exit_if_stopped(stop, [out_dir], state)
    return search_objective(state.eval_scores)


def train_jobs(cfgs: Sequence[DictConfig], out_dirs: Sequence[Path]) -> list[float | Exception]:
    """The population launcher's task (``hydra/launcher=population``): the jobs' configs trained as one
    population, member ``k`` in ``out_dirs[k]``; each job's search objective, or the error that stopped it
    (an invalid config fails its own job only: the others train without it)."""
    from aia.evaluation import search_objective
    from aia.training import train_population

    def train_valid(valid: list[int]) -> list[float]:
        first = cfgs[valid[0]]
        learners = ", ".join(dict.fromkeys(f"{cfgs[i].algo.name} ({cfgs[i].exploration.name})" for i in valid))
        print(f"training {learners} on {first.env.map} with {first.env.num_targets} target(s) for {first.frames} "
              f"frames as a population of {len(valid)}, seeds {[cfgs[i].seed for i in valid]}")
        note_no_updates(first)
        with StopOnSignals() as stop:
            states = train_population([cfgs[i] for i in valid], [out_dirs[i] for i in valid], stop,
                                      validated=True)
        report_population([cfgs[i] for i in valid], [out_dirs[i] for i in valid], states, bool(stop.signal))
        exit_if_stopped(stop, [out_dirs[i] for i in valid], states[0])
        return [search_objective(state.eval_scores) for state in states]

    return run_valid_jobs(cfgs, lambda k, cfg: validate_job(cfg, Path(out_dirs[k])), train_valid)


def validate_job(cfg: DictConfig, out_dir: Path) -> None:
    """The config (:func:`~aia.config.validation.validate_train_config`) and its run folder: a fresh run into a
    folder that holds a run, or ``resume=auto`` over damaged checkpoints only, is refused here, before the run
    prints anything (:func:`~aia.training.resuming.resume_path`). The run asks again once it holds the folder's
    lock, which is the answer it acts on: another process may have written the folder in between."""
    validate_train_config(cfg)
    from aia.training.resuming import resume_path  # a valid config only: see the module's docstring

    resume_path(cfg, out_dir)


def note_no_updates(cfg: DictConfig) -> None:
    """One line on stderr when the run ends before its first update (``frames < warmup_frames``): it plays
    random actions and evaluates its initial network only."""
    if cfg.frames < cfg.warmup_frames:
        print(f"note: frames={cfg.frames} < warmup_frames={cfg.warmup_frames}: random actions only, no update "
              "(lower warmup_frames or raise frames to learn)", file=sys.stderr)


def exit_if_stopped(stop: StopOnSignals, out_dirs: Sequence[Path], state: TrainingState) -> None:
    """After a signal: one line saying where the checkpoints are, then exit with status 128 + signal."""
    if not stop.signal:
        return
    where = ", ".join(str(Path(d) / CHECKPOINT_NAME) for d in out_dirs)
    print(f"stopped by {signal.Signals(stop.signal).name} at frame {state.frames}: checkpoint {where} "
          "(continue: the same command with resume=auto)", file=sys.stderr)
    raise SystemExit(stop.exit_status)


def report(cfg: DictConfig, out_dir: Path, state: TrainingState) -> None:
    """What a finished run prints: its counters, last score, time split, log and checkpoint."""
    print(f"{state.frames} frames, {state.episodes} episodes, {state.updates} updates; "
          f"last eval score {_last_score(state)}")
    print(f"time: {PhaseTimer(state.seconds).summary()}")
    log = _log_path(cfg, out_dir)
    if cfg.logger.name == "mcap":
        history = out_dir / cfg.logger.file
        whole = " (the run's whole history" if log != history else " (inspect"
        print(f"log written to {log}{whole}: aia-log summary {history})")
    elif log is not None:
        print(f"log written to {log}")
    print(f"checkpoint: {out_dir / CHECKPOINT_NAME}")


def report_population(cfgs: Sequence[DictConfig], out_dirs: Sequence[Path], states: Sequence[TrainingState],
                      stopped: bool = False) -> None:
    """What a finished (or ``stopped``) population prints: the counters and time split its members share, once,
    then a line per member (its learner, seed, learning rate, last score and log); checkpoints lie in each job
    folder."""
    shared = states[0]
    ended = "stopped at" if stopped else "trained:"
    print(f"population of {len(states)} {ended} {shared.frames} frames, {shared.episodes} episodes, "
          f"{shared.updates} updates each; time: {PhaseTimer(shared.seconds).summary()}")
    for cfg, out_dir, state in zip(cfgs, out_dirs, states, strict=True):
        log = _log_path(cfg, out_dir)
        print(f"  {cfg.algo.name} ({cfg.exploration.name}) seed {cfg.seed} lr {cfg.lr:g}: last eval score "
              f"{_last_score(state)}, " + (f"log {log}" if log is not None else "no log (logger=none)"))
    print(f"each member's checkpoint: {CHECKPOINT_NAME} in its folder; inspect a log: aia-log summary <log>")


def _last_score(state: TrainingState) -> str:
    return f"{state.eval_scores[-1]:.1f}" if state.eval_scores else "n/a"


def _log_path(cfg: DictConfig, out_dir: Path) -> Path | None:
    """The run's MCAP log segment this run wrote (``logger=mcap``; ``run.1.mcap`` after a resume), its folder
    (``logger=csv``: the curves' CSV files), or ``None`` (``logger=none``)."""
    if cfg.logger.name == "none":
        return None
    return last_segment(out_dir / cfg.logger.file) if cfg.logger.name == "mcap" else out_dir


if __name__ == "__main__":
    main()
