"""Deep Q-learning on the tracking env (Algorithm 1 of the paper, SPEC 8-9) for one learner or a population.

A run is a function of its config: :func:`train` trains one learner, :func:`train_population` trains ``P``
independent learners (configs that differ only in :data:`~aia.training.members.MEMBER_KEYS`) as one batched
program, and a solo run is a population of one: the same loop, not a second copy. The objects are built once
(:class:`~aia.training.population.Population`); this module runs the loop over them. Member ``k``:

* steps its own ``collector.num_envs`` worlds of one batched env (seeded as a solo run with its seed);
* acts through its slice of a :class:`~aia.modules.StackedQNetwork` and its own exploration stream
  (:class:`~aia.modules.PopulationQPolicy`);
* replays from its own rows of one storage (:class:`~aia.training.replay.MemberReplay`);
* learns with its own learning rate, gradient-norm clip and Adam moments (:mod:`aia.training.optimizer`);
  the loss is TorchRL's ``DQNLoss`` (DQN, Double DQN) or :class:`~aia.losses.ADFQLoss`, run on ``[P, B]``
  batches, with a hard target-network copy every ``target_update_interval`` steps (ADFQ's targets of the
  replayed transitions computed once per copy, :class:`~aia.training.target_cache.TargetCache`);
* is evaluated after every ``eval.every_episodes`` training episodes (``eval.episodes`` episodes at epsilon
  ``eval.epsilon``, scored as SPEC 9), ``eval.per_rollout`` evaluations of all members per rollout
  (:class:`~aia.evaluation.Evaluator`);
* logs to its own run log and writes its own checkpoint in its own run folder.

Every random draw after the networks' initialisation is counter-based, so member ``k`` draws exactly what a
population of one with its seed draws. Episodes end only at the env's ``max_steps`` (its ``done`` is its
truncation), so all worlds run in lockstep and the loop reads the device only at episode ends, evaluations and
every 100th update's logging.
"""

from __future__ import annotations

import gc
import math
import signal
import time
from collections.abc import Iterator, Sequence
from dataclasses import replace
from pathlib import Path

import torch
from omegaconf import DictConfig
from torchrl.collectors import Collector
from torchrl.record.loggers import Logger

from aia.config.errors import ConfigError
from aia.config.validation import validate_train_config
from aia.evaluation import log_score_summary
from aia.logging import MCAPLogger
from aia.modules import PopulationQPolicy
from aia.runtime.memory import keep_freed_memory
from aia.runtime.stopping import StopOnSignals
from aia.runtime.timing import PhaseTimer
from aia.training.checkpoint import TrainingState, member_checkpoint
from aia.training.checkpoint_files import save_checkpoints
from aia.training.components import make_logger
from aia.training.folder_lock import folder_locks
from aia.training.members import check_population
from aia.training.population import Population, build_population
from aia.training.progress import progress_bar
from aia.training.resuming import checkpoint_point, load_resumable, resume_path

# What the loop reads of each collected frame besides the loss's keys: the score's terms (SPEC 9).
_SCORE_KEY = ("next", "logdet_cov")


def train(cfg: DictConfig, out_dir: Path, stop: StopOnSignals | None = None) -> TrainingState:
    """Run one training job in ``out_dir``; returns its final counters (a population of one)."""
    return train_population([cfg], [out_dir], stop)[0]


def train_population(cfgs: Sequence[DictConfig], out_dirs: Sequence[Path], stop: StopOnSignals | None = None, *,
                     validated: bool = False) -> list[TrainingState]:
    """Train one member per config, member ``k`` in ``out_dirs[k]``, as one batched program; returns each
    member's final counters (metrics go to each member's logger, closed on any exit). Every config is checked
    (:func:`~aia.config.validation.validate_train_config`) unless ``validated``: the population launcher's entry
    checks each job itself, so that a bad job of a sweep fails alone. Each member's folder is
    locked for the run (:mod:`.folder_lock`: a folder in use raises :class:`~aia.config.errors.FolderLocked`). Once
    ``stop`` has seen a signal, the loop ends at the end of the current episode as at the end of its budget:
    pending evaluations played, every member's checkpoint written, the logs marked stopped. A failed write of a
    log or a checkpoint raises :class:`~aia.config.errors.WriteFailed` after every log is closed marked failed."""
    if len(cfgs) != len(out_dirs):
        raise ValueError(f"{len(cfgs)} configs for {len(out_dirs)} run folders")
    if not validated:
        for cfg in cfgs:
            validate_train_config(cfg)
    check_population(cfgs)
    out_dirs = [Path(d) for d in out_dirs]
    with folder_locks(out_dirs, cfgs[0].lock_wait_s):
        checkpoints = _checkpoints(list(cfgs), out_dirs)
        if checkpoints[0] is not None and checkpoints[0]["state"]["frames"] >= cfgs[0].frames:
            # finished already (resume=auto over a whole protocol): nothing to train, no log segment, no checkpoint
            print(f"finished already at frame {checkpoints[0]['state']['frames']} (frames={cfgs[0].frames}): "
                  "nothing to train; raise frames to train on")
            return [TrainingState(**checkpoint["state"]) for checkpoint in checkpoints]
        loggers: list[Logger | None] = []
        try:
            loggers += [make_logger(cfg, out_dir, resumed_after_ns=checkpoint["saved_at_ns"] if checkpoint else None)
                        for cfg, out_dir, checkpoint in zip(cfgs, out_dirs, checkpoints, strict=True)]
            states = _train(list(cfgs), out_dirs, loggers, stop, checkpoints)
            if stop is not None and stop.signal:
                for logger in loggers:
                    if isinstance(logger, MCAPLogger):
                        logger.mark_failed(f"{signal.Signals(stop.signal).name} at frame {states[0].frames}: "
                                           "checkpoint written (resume=auto continues)", status="stopped")
        except BaseException:
            _close(loggers, quiet=True)  # each log marked failed or stopped with the error under way
            raise
        _close(loggers, quiet=False)
        return states


def _close(loggers: Sequence[Logger | None], quiet: bool) -> None:
    """Close every logger; then raise the first error a close raised, unless ``quiet`` (an error is under way)."""
    errors = []
    for logger in loggers:
        if logger:
            try:
                logger.close()
            except Exception as err:  # noqa: BLE001  (the other logs are closed all the same)
                errors.append(err)
    if errors and not quiet:
        raise errors[0]


def _train(cfgs: list[DictConfig], out_dirs: list[Path], loggers: list[Logger | None], stop: StopOnSignals | None,
           checkpoints: list[dict | None]) -> list[TrainingState]:
    """Build the population (resumed from ``checkpoints``) and run the loop to the end of its frame budget."""
    cfg = cfgs[0]  # the shared settings
    if cfg.get("threads"):
        torch.set_num_threads(cfg.threads)
    if cfg.keep_freed_memory:
        keep_freed_memory()
    population, shared, scores = build_population(cfgs, loggers, checkpoints)
    run = _Run(out_dirs, loggers, shared, scores, population)
    _loop(population, run, stop)  # a finished run never comes here (train_population)
    return run.states()


def _loop(population: Population, run: _Run, stop: StopOnSignals | None) -> None:
    """Collect, store, update, evaluate and checkpoint until the frame budget is spent or ``stop`` has seen a
    signal; then play the pending evaluations, write every member's checkpoint and log the run's speed."""
    cfg, shared = population.cfgs[0], run.shared
    P, W = len(population.cfgs), population.worlds_per_member
    policy, replay, targets, update = population.policy, population.replay, population.targets, population.update
    remaining = cfg.frames - shared.frames
    steps = math.ceil(remaining / W)
    policy_steps = policy.steps
    collector = Collector(
        population.env, policy, frames_per_batch=P * W, total_frames=steps * P * W, device=cfg.device,
        auto_register_policy_transforms=False,  # the Q-networks keep no recurrent state
        track_traj_ids=False,  # trajectory ids are not used (episodes end on done): saves a copy per step
        return_same_td=True,  # no clone per batch: the loop copies what it keeps (into the replay buffer)
    )
    policy.steps = policy_steps  # the collector probes the policy once when it is built: not a step
    running_score = torch.zeros(P, W, device=cfg.device)
    updates_owed = 0.0
    # read once: an attribute of an OmegaConf config costs about 7 us, several times a frame's budget share
    warmup_frames, updates_per_frame = cfg.warmup_frames, cfg.updates_per_frame
    checkpoint_every, eval_every = cfg.checkpoint_every_frames, cfg.eval.every_episodes
    checkpoint_every_s, last_checkpoint, checkpoint_due = cfg.checkpoint_every_s, time.monotonic(), False
    max_steps = population.env_config.max_steps
    episode_step = 0  # steps into the current episode (all worlds in lockstep; a resumed run starts afresh)
    first_update = True
    timer = PhaseTimer(shared.seconds)  # updates shared.seconds in place
    measured_before = sum(shared.seconds.values())
    start = time.perf_counter()
    bar = progress_bar(cfg.frames, shared.frames, _description(population.cfgs))
    batches = iter(collector)
    in_keys = population.loss.in_keys
    evaluator = population.evaluator
    # Python's full collections walk every object, and torch (and compiling) leave about half a million of them:
    # one took 0.3 s in a 2,000-frame job. Objects made before the loop stay out of the collections until it ends.
    gc.freeze()

    def evaluate() -> None:
        """Play the pending evaluations; the bar shows the last score wherever one was played."""
        with timer("evaluate"):
            played = run.evaluate()
        if played:
            bar.set_postfix(**run.status(policy))

    try:
        while True:
            with timer("collect"):
                batch = next(batches, None)
            if batch is None:
                break
            # only what the loop reads: the loss's keys (a cheaper extend and sample) and the score
            batch = batch.select(*in_keys, _SCORE_KEY).reshape(P, W)
            with timer("buffer"):
                transitions = batch.select(*in_keys).transpose(0, 1)
                rows = replay.extend(transitions)
            if targets is not None and targets.fresh:
                with timer("first_update" if targets.first_calls else "targets"):
                    targets.record(transitions, rows)
            shared.frames += W
            running_score += -batch.get(_SCORE_KEY).mean(-1)
            episode_step += 1
            if episode_step == max_steps:  # every world's episode ends now (the env's done is its time limit)
                episode_step = 0
                run.end_episodes(running_score, eval_every)
                running_score.zero_()
            if evaluator.full:
                evaluate()

            if shared.frames >= warmup_frames:
                updates_owed += updates_per_frame * W
                while updates_owed >= 1:
                    updates_owed -= 1
                    if targets is not None and not targets.fresh:
                        with timer("first_update" if targets.first_calls else "targets"):
                            targets.refresh()
                    with timer("buffer"):
                        sample = replay.sample()
                    # the first step of a job compiles (compile.update=true): timed apart from the steady steps
                    with timer("first_update" if first_update else "update"):
                        losses = update(sample)
                    first_update = False
                    shared.updates += 1
                    if shared.updates % 100 == 0:
                        run.log_training(losses, policy)
            bar.update(W)
            # Checkpoints (and a stop on a signal) wait for the end of the current episode, so that a resumed
            # run continues exactly as the uninterrupted one (no episode is cut and replayed differently).
            checkpoint_due |= shared.frames % checkpoint_every < W
            checkpoint_due |= time.monotonic() - last_checkpoint >= checkpoint_every_s
            stopping = stop is not None and stop.signal is not None
            if episode_step == 0 and (checkpoint_due or stopping):
                if stopping:
                    break  # then as at the end of the budget: pending evaluations, checkpoints
                evaluate()  # a checkpoint keeps no pending evaluation
                with timer("checkpoint"):
                    run.save(episode_step)
                checkpoint_due, last_checkpoint = False, time.monotonic()
        evaluate()
    finally:
        gc.unfreeze()
        bar.close()
        collector.shutdown()
        # logging, the progress bar and the loop's own bookkeeping
        timer.add("other", time.perf_counter() - start - (sum(shared.seconds.values()) - measured_before))
    run.save(episode_step)
    run.log_summary(remaining / (time.perf_counter() - start))


def _description(cfgs: list[DictConfig]) -> str:
    """The progress bar's label: the members' methods (or algorithms), and their number if more than one."""
    names = ",".join(dict.fromkeys(str(c.get("method") or c.algo.name) for c in cfgs))
    return names if len(cfgs) == 1 else f"{names} x{len(cfgs)}"


def _checkpoints(cfgs: list[DictConfig], out_dirs: list[Path]) -> list[dict | None]:
    """Each member's checkpoint to resume from (:mod:`.resuming`), all from the same point, or none at all."""
    sources = [resume_path(cfg, out_dir) for cfg, out_dir in zip(cfgs, out_dirs, strict=True)]
    for source in sources:
        if source is not None and source.passed_over:
            print(source.passed_over)
    paths = [source.path if source else None for source in sources]
    if not any(paths):
        return [None] * len(cfgs)
    if not all(paths):
        missing = [str(out_dirs[k]) for k, path in enumerate(paths) if path is None]
        raise ConfigError("resume", [str(p) for p in paths], "a checkpoint for every member of a population or for "
                          f"none (none for {', '.join(missing)})")
    checkpoints = [load_resumable(path, cfg, cfgs[0].device) for cfg, path in zip(cfgs, paths, strict=True)]
    points = [checkpoint_point(checkpoint) for checkpoint in checkpoints]
    if len(set(points)) > 1:
        raise ConfigError("resume", [str(p) for p in paths], "checkpoints of one point of a population (their "
                          f"frames: {[point[0] for point in points]})")
    for path, checkpoint in zip(paths, checkpoints, strict=True):
        print(f"resuming from {path} at frame {checkpoint['state']['frames']}")
    return checkpoints


class _Run:
    """The members' bookkeeping around the loop: counters, scores, logging, evaluations and checkpoints."""

    def __init__(self, out_dirs: list[Path], loggers: list[Logger | None], shared: TrainingState,
                 scores: list[list[float]], population: Population) -> None:
        self.out_dirs, self.loggers = out_dirs, loggers
        self.shared, self.scores, self.population = shared, scores, population

    def states(self) -> list[TrainingState]:
        """Each member's counters (shared) and scores (its own)."""
        return [replace(self.shared, eval_scores=list(s), seconds=dict(self.shared.seconds)) for s in self.scores]

    def end_episodes(self, running_score: torch.Tensor, eval_every: int) -> None:
        """Count the episodes that just ended (one per world), log each member's score, ask for evaluations."""
        shared = self.shared
        for world_scores in running_score.transpose(0, 1).tolist():  # world by world: [P] scores each
            shared.episodes += 1
            for logger, score in zip(self.loggers, world_scores, strict=True):
                if logger:
                    logger.log_scalar("train/score", score, step=shared.frames)
            if shared.episodes % eval_every == 0:
                self.population.evaluator.add(shared.episodes, shared.frames)

    def evaluate(self) -> bool:
        """Play the pending evaluations; log each member's score mean and std and belief error at its frame.
        Whether any was pending."""
        results = self.population.evaluator.flush()
        for point, summaries in results:
            self.shared.evaluations += 1
            for logger, scores, summary in zip(self.loggers, self.scores, summaries, strict=True):
                scores.append(summary["score_mean"])
                if logger:
                    _log_evaluation(logger, point, summary)
        if results:
            for logger in self.loggers:
                if logger:
                    logger.flush()  # a run killed later keeps every evaluation played so far
        return bool(results)

    def log_training(self, losses: torch.Tensor, policy: PopulationQPolicy) -> None:
        """Each member's loss (and epsilon) at this frame."""
        egreedy = policy.egreedy_members
        epsilons = policy.epsilon().tolist() if egreedy else []
        for member, (logger, value) in enumerate(zip(self.loggers, losses.tolist(), strict=True)):
            if logger:
                logger.log_scalar("train/loss", value, step=self.shared.frames)
                if member in egreedy:
                    logger.log_scalar("train/epsilon", epsilons[member], step=self.shared.frames)

    def status(self, policy: PopulationQPolicy) -> dict[str, str]:
        """What the progress bar shows: the last evaluation score (mean over members) and the first epsilon-greedy
        member's epsilon."""
        status = {"score": f"{sum(s[-1] for s in self.scores) / len(self.scores):.0f}"}
        egreedy = policy.egreedy_members
        if egreedy:
            status["eps"] = f"{policy.epsilon()[egreedy[0]].item():.2f}"
        return status

    def save(self, episode_step: int) -> None:
        """Every member's checkpoint, in its own run folder (all of them or none: :func:`save_checkpoints`).
        Between episodes the collector has already reset the worlds into their next episode: the checkpoint counts
        it as not begun, so that a resumed run meets the same next episode; a resumed run abandons an interrupted
        episode (it starts the one after)."""
        population = self.population
        population.world_episodes.copy_(population.env.base_env._episode - (1 if episode_step == 0 else 0))
        network, template = population.network, population.actor_template

        def checkpoints() -> Iterator[tuple[Path, dict]]:  # one at a time: a member's copy is freed when written
            for member, (cfg, out_dir) in enumerate(zip(population.cfgs, self.out_dirs, strict=True)):
                network.unstack_into(member, template[0].module)
                state = replace(self.shared, eval_scores=list(self.scores[member])).__dict__
                yield out_dir, member_checkpoint(population, member, cfg, state, template.state_dict())

        save_checkpoints(checkpoints())

    def log_summary(self, frames_per_s: float) -> None:
        """The run's speed and where its time went, in every member's log."""
        for logger in self.loggers:
            if logger:
                logger.log_scalar("train/frames_per_s", frames_per_s, step=self.shared.frames)
                for phase, seconds in self.shared.seconds.items():
                    logger.log_scalar(f"time/{phase}_s", seconds, step=self.shared.frames)


def _log_evaluation(logger: Logger, point, summary: dict) -> None:
    """One evaluation's scalars (and, in an MCAP log, a line of text)."""
    log_score_summary(logger, summary, point.frame)
    if isinstance(logger, MCAPLogger):
        logger.log_text(f"evaluation {point.index + 1} after {point.episode} training episodes "
                        f"({point.frame} frames): score {summary['score_mean']:.1f} "
                        f"+- {summary['score_std']:.1f} over {len(summary['scores'])} episodes, "
                        f"belief error {summary['belief_error']:.1f} m")
