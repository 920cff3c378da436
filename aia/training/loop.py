"""Deep Q-learning on the tracking env (Algorithm 1 of the paper, SPEC 8-9) for one learner or a population.

A run is a function of its config: :func:`train` trains one learner, :func:`train_population` trains ``P``
independent learners (configs that differ only in :data:`~aia.training.members.MEMBER_KEYS`) as one batched
program, and a solo run is a population of one: the same loop, not a second copy. Member ``k``:

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
from dataclasses import dataclass, field, replace
from pathlib import Path

import torch
from omegaconf import DictConfig
from torchrl.collectors import Collector
from torchrl.envs import SelectTransform
from torchrl.objectives import HardUpdate
from torchrl.record.loggers import Logger

from aia.config.errors import ConfigError
from aia.envs import make_env
from aia.envs.factory import to_tracking_config
from aia.evaluation import Evaluator, log_score_summary
from aia.logging import MCAPLogger
from aia.modules import PopulationQPolicy
from aia.modules.q_networks import make_qvalue_actor
from aia.runtime.memory import keep_freed_memory
from aia.runtime.timing import PhaseTimer
from aia.training.checkpoint import PopulationParts, load_member, member_checkpoint
from aia.training.checkpoint_files import save_checkpoints
from aia.training.components import (
    make_actor,
    make_logger,
    make_loss,
    make_recorders,
    make_stacked_network,
)
from aia.training.folder_lock import folder_locks
from aia.training.members import check_population
from aia.training.optimizer import StackedAdam, Updater
from aia.training.progress import progress_bar
from aia.training.replay import MemberReplay
from aia.training.resuming import checkpoint_point, load_resumable, resume_path
from aia.training.stopping import StopOnSignals
from aia.training.target_cache import TargetCache


@dataclass
class TrainingState:
    """A member's counters and evaluation scores: what a checkpoint carries across a restart."""

    frames: int = 0
    updates: int = 0
    episodes: int = 0
    evaluations: int = 0
    eval_scores: list[float] = field(default_factory=list)
    seconds: dict[str, float] = field(default_factory=dict)  # wall clock per phase of the loop (PhaseTimer)


# What the loop reads of each collected frame besides the loss's keys: the score's terms (SPEC 9).
_SCORE_KEY = ("next", "logdet_cov")
# Seeds of member k's evaluation worlds and noise, derived from its seed.
_EVAL_SEED_OFFSET = 1_000_003


def train(cfg: DictConfig, out_dir: Path, stop: StopOnSignals | None = None) -> TrainingState:
    """Run one training job in ``out_dir``; returns its final counters (a population of one)."""
    return train_population([cfg], [out_dir], stop)[0]


def train_population(cfgs: Sequence[DictConfig], out_dirs: Sequence[Path], stop: StopOnSignals | None = None
                     ) -> list[TrainingState]:
    """Train one member per config, member ``k`` in ``out_dirs[k]``, as one batched program; returns each
    member's final counters (metrics go to each member's logger, closed on any exit). Each member's folder is
    locked for the run (:mod:`.folder_lock`: a folder in use raises :class:`~aia.config.errors.FolderLocked`). Once
    ``stop`` has seen a signal, the loop ends at the end of the current episode as at the end of its budget:
    pending evaluations played, every member's checkpoint written, the logs marked stopped. A failed write of a
    log or a checkpoint raises :class:`~aia.config.errors.WriteFailed` after every log is closed marked failed."""
    if len(cfgs) != len(out_dirs):
        raise ValueError(f"{len(cfgs)} configs for {len(out_dirs)} run folders")
    check_population(cfgs)
    out_dirs = [Path(d) for d in out_dirs]
    with folder_locks(out_dirs, cfgs[0].lock_wait_s):
        checkpoints = _checkpoints(list(cfgs), out_dirs)
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
    cfg = cfgs[0]  # the shared settings
    P, W = len(cfgs), cfg.collector.num_envs
    seeds = [int(c.seed) for c in cfgs]
    if cfg.get("threads"):
        torch.set_num_threads(cfg.threads)
    if cfg.keep_freed_memory:
        keep_freed_memory()
    env_config = to_tracking_config(cfg.env)
    env = make_env(env_config, batch_size=P * W, device=cfg.device, compile=cfg.compile.env)
    # The collector copies every key of every frame: keep what the policy, the loss and the score read.
    env.append_transform(SelectTransform("observation", "logdet_cov", keep_rewards=True, keep_dones=True))
    eval_env = make_env(env_config, batch_size=cfg.eval.episodes * cfg.eval.per_rollout * P, device=cfg.device,
                        compile=cfg.compile.env)
    obs_dim, num_actions = env.observation_spec["observation"].shape[-1], env.action_spec.n
    network = make_stacked_network(cfgs, obs_dim, num_actions)
    actor = make_qvalue_actor(network, env.action_spec, adfq=cfg.algo.name == "adfq")
    annealing = [max(1, int(c.exploration.get("annealing_fraction", 1.0) * cfg.frames)) for c in cfgs]
    policy = PopulationQPolicy(
        network, num_actions, W, seeds, thompson=[c.exploration.name == "thompson" for c in cfgs],
        eps_init=[c.exploration.get("eps_init", 0.0) for c in cfgs],
        eps_end=[c.exploration.get("eps_end", 0.0) for c in cfgs], annealing_frames=annealing,
        warmup_frames=cfg.warmup_frames)
    loss = make_loss(cfgs, actor)
    target_updater = HardUpdate(loss, value_network_update_interval=cfg.target_update_interval)
    optimizer = StackedAdam(list(loss.value_network_params.values(True, True)), [c.lr for c in cfgs])
    replay = MemberReplay(cfg.buffer_size, cfg.batch_size, seeds, device=cfg.device)
    # cfg.compile.update would be DictConfig's dict method update (always true), not the switch
    compile_update = cfg.compile["update"]
    targets = TargetCache(loss, network, replay, worlds=W, compile=compile_update) if cfg.algo.name == "adfq" else None
    update = Updater(loss, optimizer, target_updater, cfg.grad_clip, compile=compile_update,
                     on_target_copy=targets.invalidate if targets else None)
    base_env = env.base_env
    world_episodes = torch.zeros(P * W, dtype=torch.int64)
    parts = PopulationParts(loss.value_network_params, loss.target_value_network_params, optimizer, policy, replay,
                            target_updater, world_episodes)
    shared, scores = _resume(checkpoints, parts)
    # member k's worlds are a solo run's worlds with its seed (episode counters as checkpointed)
    base_env.replay_streams(torch.tensor(seeds).repeat_interleave(W), torch.arange(W).repeat(P), world_episodes)
    recorders = make_recorders(cfg, loggers, eval_env)
    evaluator = Evaluator(eval_env, network, num_actions, cfg.eval.episodes, cfg.eval.epsilon,
                          seeds=[s + _EVAL_SEED_OFFSET for s in seeds],
                          noise_seeds=[(s + 1) * _EVAL_SEED_OFFSET for s in seeds], first_index=shared.evaluations,
                          recorders=recorders, record_every=cfg.logger.get("record_every_evaluations", 0),
                          compile=cfg.compile.policy)
    run = _Run(cfgs, out_dirs, loggers, shared, scores, parts, evaluator, actor_template=make_actor(cfg, env))

    remaining = cfg.frames - shared.frames
    if remaining <= 0:
        return run.states()
    steps = math.ceil(remaining / W)
    policy_steps = policy.steps
    collector = Collector(
        env, policy, frames_per_batch=P * W, total_frames=steps * P * W, device=cfg.device,
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
    max_steps = env_config.max_steps
    episode_step = 0  # steps into the current episode (all worlds in lockstep; a resumed run starts afresh)
    first_update = True
    timer = PhaseTimer(shared.seconds)  # updates shared.seconds in place
    measured_before = sum(shared.seconds.values())
    start = time.perf_counter()
    bar = progress_bar(cfg.frames, shared.frames, _description(cfgs))
    batches = iter(collector)
    in_keys = loss.in_keys
    # Python's full collections walk every object, and torch (and compiling) leave about half a million of them:
    # one took 0.3 s in a 2,000-frame job. Objects made before the loop stay out of the collections until it ends.
    gc.freeze()
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
                with timer("evaluate"):
                    run.evaluate()
                bar.set_postfix(**run.status(policy))

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
                with timer("evaluate"):
                    run.evaluate()  # a checkpoint keeps no pending evaluation
                with timer("checkpoint"):
                    run.save(base_env, episode_step)
                checkpoint_due, last_checkpoint = False, time.monotonic()
        with timer("evaluate"):
            run.evaluate()
    finally:
        gc.unfreeze()
        bar.close()
        collector.shutdown()
        # logging, the progress bar and the loop's own bookkeeping
        timer.add("other", time.perf_counter() - start - (sum(shared.seconds.values()) - measured_before))
    run.save(base_env, episode_step)
    run.log_summary(remaining / (time.perf_counter() - start))
    return run.states()


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


def _resume(checkpoints: list[dict | None], parts: PopulationParts) -> tuple[TrainingState, list[list[float]]]:
    """The shared counters and each member's scores, with the members' checkpoints loaded into ``parts``."""
    if checkpoints[0] is None:
        return TrainingState(), [[] for _ in checkpoints]
    states = []
    for member, checkpoint in enumerate(checkpoints):
        load_member(parts, member, checkpoint)
        states.append(TrainingState(**checkpoint["state"]))
    return replace(states[0], eval_scores=[]), [s.eval_scores for s in states]


class _Run:
    """The members' bookkeeping around the loop: counters, scores, logging, evaluations and checkpoints."""

    def __init__(self, cfgs: list[DictConfig], out_dirs: list[Path], loggers: list[Logger | None],
                 shared: TrainingState, scores: list[list[float]], parts: PopulationParts, evaluator: Evaluator,
                 actor_template) -> None:
        self.cfgs, self.out_dirs, self.loggers = cfgs, out_dirs, loggers
        self.shared, self.scores, self.parts, self.evaluator = shared, scores, parts, evaluator
        self.actor_template = actor_template

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
                self.evaluator.add(shared.episodes, shared.frames)

    def evaluate(self) -> None:
        """Play the pending evaluations; log each member's score mean and std and belief error at its frame."""
        results = self.evaluator.flush()
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

    def save(self, base_env, episode_step: int) -> None:
        """Every member's checkpoint, in its own run folder (all of them or none: :func:`save_checkpoints`).
        Between episodes the collector has already reset the worlds into their next episode: the checkpoint counts
        it as not begun, so that a resumed run meets the same next episode; a resumed run abandons an interrupted
        episode (it starts the one after)."""
        self.parts.world_episodes.copy_(base_env._episode - (1 if episode_step == 0 else 0))
        network = self.parts.policy.network

        def checkpoints() -> Iterator[tuple[Path, dict]]:  # one at a time: a member's copy is freed when written
            for member, (cfg, out_dir) in enumerate(zip(self.cfgs, self.out_dirs, strict=True)):
                network.unstack_into(member, self.actor_template[0].module)
                state = replace(self.shared, eval_scores=list(self.scores[member])).__dict__
                yield out_dir, member_checkpoint(self.parts, member, cfg, state, self.actor_template.state_dict())

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
