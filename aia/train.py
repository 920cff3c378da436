"""Deep Q-learning on the tracking env (Algorithm 1 of the paper, SPEC 8-9), wired from TorchRL parts.

A ``Collector`` steps ``collector.num_envs`` worlds under the exploring policy into a
``ReplayBuffer(LazyTensorStorage)``; every collected frame buys ``updates_per_frame`` optimiser steps of the
chosen loss (TorchRL's ``DQNLoss`` for DQN and Double DQN, :class:`~aia.losses.ADFQLoss` for ADFQ) with a
hard target-network copy every ``target_update_interval`` steps. After every ``eval.every_episodes``
training episodes, ``eval.episodes`` episodes at epsilon ``eval.epsilon`` evaluate the policy and their score
(SPEC 9) is logged; ``eval.per_rollout`` such evaluations play together in one batched rollout
(:class:`~aia.evaluator.Evaluator`).
"""

from __future__ import annotations

import gc
import math
import time
from dataclasses import dataclass, field
from pathlib import Path

import torch
from omegaconf import DictConfig, OmegaConf
from tensordict import TensorDictBase
from tensordict.nn import TensorDictSequential
from torch import Tensor
from torchrl.collectors import Collector
from torchrl.data import LazyTensorStorage, ReplayBuffer
from torchrl.envs import SelectTransform
from torchrl.objectives import DQNLoss, HardUpdate, LossModule
from torchrl.record.loggers import Logger
from torchrl.record.loggers.csv import CSVLogger
from tqdm import tqdm

from aia.compiling import compiled_update
from aia.envs import make_env
from aia.envs.factory import to_tracking_config
from aia.evaluation import log_score_summary
from aia.evaluator import Evaluator
from aia.logging import MCAPLogger, SceneRecorder
from aia.losses import ADFQLoss
from aia.modules import (
    ADFQNetwork,
    EpsilonGreedy,
    ExploringQPolicy,
    ThompsonSampling,
    check_exploration,
    make_q_network,
)
from aia.modules.q_networks import make_qvalue_actor
from aia.timing import PhaseTimer


@dataclass
class TrainingState:
    """Counters that a checkpoint carries across a restart."""

    frames: int = 0
    updates: int = 0
    episodes: int = 0
    evaluations: int = 0
    eval_scores: list[float] = field(default_factory=list)
    seconds: dict[str, float] = field(default_factory=dict)  # wall clock per phase of the loop (PhaseTimer)


# What the loop reads of each collected frame besides the loss's keys: the score's terms (SPEC 9) and the ends.
_SCORE_KEYS = (("next", "logdet_cov"), ("next", "done"))


def make_actor(cfg: DictConfig, env) -> TensorDictSequential:
    """The greedy Q-value actor (MLP, or the ADFQ mean/log-sd network) for ``env``'s observation."""
    obs_dim = env.observation_spec["observation"].shape[-1]
    num_actions = env.action_spec.n
    hidden = tuple(cfg.hidden)
    if cfg.algo.name == "adfq":
        network = ADFQNetwork(obs_dim, num_actions, hidden, var_min=cfg.algo.var_min, sd_max=cfg.algo.sd_max)
    else:
        network = make_q_network(obs_dim, num_actions, hidden)
    return make_qvalue_actor(network.to(cfg.device), env.action_spec, adfq=cfg.algo.name == "adfq")


def make_exploration(cfg: DictConfig, num_actions: int):
    """The training-time exploration module (epsilon-greedy or Thompson sampling)."""
    if cfg.exploration.name == "thompson":
        return ThompsonSampling(seed=cfg.seed, device=cfg.device)
    annealing = max(1, int(cfg.exploration.annealing_fraction * cfg.frames))
    return EpsilonGreedy(num_actions, cfg.exploration.eps_init, cfg.exploration.eps_end, annealing,
                         seed=cfg.seed, device=cfg.device)


def make_loss(cfg: DictConfig, actor: TensorDictSequential) -> LossModule:
    """DQN, Double DQN (TorchRL's DQNLoss) or ADFQ, with the discount of the config."""
    if cfg.algo.name == "adfq":
        return ADFQLoss(actor, gamma=cfg.gamma, noise=cfg.algo.noise, var_min=cfg.algo.var_min,
                        sd_max=cfg.algo.sd_max, reward_var=cfg.algo.reward_var,
                        loss_function=cfg.algo.loss_function)
    loss = DQNLoss(actor, loss_function=cfg.algo.loss_function, delay_value=True,
                   double_dqn=cfg.algo.name == "ddqn", action_space="categorical")
    loss.make_value_estimator(gamma=cfg.gamma)
    return loss


def make_logger(cfg: DictConfig, out_dir: Path) -> Logger | None:
    """TorchRL logger of the run (``logger=mcap``, ``logger=csv`` or ``logger=none``); it gets the config."""
    if cfg.logger.name == "none":
        return None
    if cfg.logger.name == "csv":
        logger = CSVLogger(exp_name="csv", log_dir=str(out_dir))
    elif cfg.logger.name == "mcap":
        logger = MCAPLogger(
            exp_name=f"{cfg.algo.name}-{cfg.exploration.name}-seed{cfg.seed}", log_dir=out_dir,
            file_name=cfg.logger.file, compression=cfg.logger.compression, chunk_size=cfg.logger.chunk_size,
            flush_interval_s=cfg.logger.flush_interval_s,
            run_metadata={"seed": cfg.seed, "algo": cfg.algo.name, "exploration": cfg.exploration.name},
        )
    else:
        raise ValueError(f"logger={cfg.logger.name!r} is not one of ['mcap', 'csv', 'none']")
    logger.log_hparams(cfg)
    return logger


def make_recorder(cfg: DictConfig, logger: Logger | None, eval_env) -> SceneRecorder | None:
    """The scene recorder on the evaluation env when the MCAP logger records episodes, else None."""
    if not isinstance(logger, MCAPLogger) or cfg.logger.record_every_evaluations < 1:
        return None
    recorder = SceneRecorder(logger)
    eval_env.append_transform(recorder)
    return recorder


def check_config(cfg: DictConfig) -> None:
    """Reject inconsistent settings with a message naming the field."""
    check_exploration(cfg.algo.name, cfg.exploration.name)
    positive = {"frames": cfg.frames, "collector.num_envs": cfg.collector.num_envs, "batch_size": cfg.batch_size,
                "buffer_size": cfg.buffer_size, "eval.episodes": cfg.eval.episodes,
                "eval.every_episodes": cfg.eval.every_episodes, "eval.per_rollout": cfg.eval.per_rollout,
                "target_update_interval": cfg.target_update_interval}
    for name, value in positive.items():
        if value < 1:
            raise ValueError(f"{name}={value} must be >= 1")
    if not cfg.updates_per_frame > 0:
        raise ValueError(f"updates_per_frame={cfg.updates_per_frame} must be > 0")
    record_every = cfg.logger.get("record_every_evaluations", 0)
    if cfg.logger.name == "mcap" and record_every > 0 and cfg.eval.per_rollout > record_every:
        raise ValueError(f"eval.per_rollout={cfg.eval.per_rollout} must be at most "
                         f"logger.record_every_evaluations={record_every} (one recorded episode per rollout)")


def save_checkpoint(path: Path, cfg: DictConfig, state: TrainingState, actor, loss, optimizer, exploration,
                    buffer, env) -> None:
    """Networks (online and target), optimiser, counters, RNG states, replay buffer and config."""
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(".tmp")
    torch.save({
        "config": OmegaConf.to_container(cfg, resolve=True),
        "state": state.__dict__,
        "actor": actor.state_dict(),
        "loss": loss.state_dict(),
        "optimizer": optimizer.state_dict(),
        "exploration": {"generator": exploration.generator.get_state(),
                        "frames": getattr(exploration, "frames", 0)},
        "buffer": buffer.state_dict(),
        "env_episodes": env.base_env._episode.clone(),
        "torch_rng": torch.get_rng_state(),
    }, tmp)
    tmp.replace(path)  # never leave a half-written checkpoint behind


def train(cfg: DictConfig, out_dir: Path) -> TrainingState:
    """Run one training job; returns the final counters (metrics go to the logger, closed on any exit)."""
    check_config(cfg)
    logger = make_logger(cfg, out_dir)
    try:
        return _train(cfg, out_dir, logger)
    finally:
        if logger:
            logger.close()


def _train(cfg: DictConfig, out_dir: Path, logger: Logger | None) -> TrainingState:
    if cfg.get("threads"):
        torch.set_num_threads(cfg.threads)
    torch.manual_seed(cfg.seed)
    env_config = to_tracking_config(cfg.env)
    env = make_env(env_config, batch_size=cfg.collector.num_envs, device=cfg.device, seed=cfg.seed,
                   compile=cfg.compile.env)
    # The collector copies every key of every frame: keep what the policy, the loss and the score read.
    env.append_transform(SelectTransform("observation", "logdet_cov", keep_rewards=True, keep_dones=True))
    eval_env = make_env(env_config, batch_size=cfg.eval.episodes * cfg.eval.per_rollout, device=cfg.device,
                        compile=cfg.compile.env)
    actor = make_actor(cfg, env)
    exploration = make_exploration(cfg, env.action_spec.n)
    policy = ExploringQPolicy(actor[0].module, exploration)  # acts as TensorDictSequential(actor, exploration)
    loss = make_loss(cfg, actor)
    target_updater = HardUpdate(loss, value_network_update_interval=cfg.target_update_interval)
    optimizer = torch.optim.Adam(loss.parameters(), lr=cfg.lr)
    # cfg.compile.update would be DictConfig's dict method update (always true), not the switch
    update = Updater(loss, optimizer, target_updater, cfg.grad_clip, compile=cfg.compile["update"])
    buffer = ReplayBuffer(storage=LazyTensorStorage(cfg.buffer_size, device=cfg.device), batch_size=cfg.batch_size)
    state = TrainingState()
    recorder = make_recorder(cfg, logger, eval_env)

    if cfg.resume:
        checkpoint = torch.load(cfg.resume, weights_only=False)
        actor.load_state_dict(checkpoint["actor"])
        loss.load_state_dict(checkpoint["loss"])
        optimizer.load_state_dict(checkpoint["optimizer"])
        buffer.load_state_dict(checkpoint["buffer"])
        exploration.generator.set_state(checkpoint["exploration"]["generator"])
        if isinstance(exploration, EpsilonGreedy):
            exploration.step(checkpoint["exploration"]["frames"])
        env.base_env._episode.copy_(checkpoint["env_episodes"])
        torch.set_rng_state(checkpoint["torch_rng"])
        state = TrainingState(**checkpoint["state"])
        print(f"resumed from {cfg.resume} at frame {state.frames} (the interrupted episode starts afresh)")
    evaluator = Evaluator(eval_env, actor[0].module, env.action_spec.n, cfg.eval.episodes, cfg.eval.epsilon,
                          seed=cfg.seed + 1_000_003, noise_seed=(cfg.seed + 1) * 1_000_003,
                          first_index=state.evaluations, recorder=recorder,
                          record_every=cfg.logger.get("record_every_evaluations", 0), compile=cfg.compile.policy)

    num_envs = cfg.collector.num_envs
    remaining = cfg.frames - state.frames
    if remaining <= 0:
        return state
    collector = Collector(
        env, policy, frames_per_batch=num_envs, total_frames=math.ceil(remaining / num_envs) * num_envs,
        init_random_frames=max(0, cfg.warmup_frames - state.frames), device=cfg.device,
        auto_register_policy_transforms=False,  # the Q-networks keep no recurrent state
        track_traj_ids=False,  # trajectory ids are not used (episodes end on done): saves a copy per step
        return_same_td=True,  # no clone per batch: the loop copies what it keeps (into the replay buffer)
    )
    running_score = torch.zeros(num_envs, device=cfg.device)
    updates_owed = 0.0
    # read once: an attribute of an OmegaConf config costs about 7 us, several times a frame's budget share
    warmup_frames, updates_per_frame = cfg.warmup_frames, cfg.updates_per_frame
    checkpoint_every, eval_every = cfg.checkpoint_every_frames, cfg.eval.every_episodes
    first_update = True
    timer = PhaseTimer(state.seconds)  # updates state.seconds in place
    measured_before = sum(state.seconds.values())
    start = time.perf_counter()
    bar = tqdm(total=cfg.frames, initial=state.frames, unit="frame", unit_scale=True, desc=cfg.algo.name,
               mininterval=1.0)
    batches = iter(collector)
    # Python's full collections walk every object, and torch (and compiling) leave about half a million of them:
    # one took 0.3 s in a 2,000-frame job. Objects made before the loop stay out of the collections until it ends.
    gc.freeze()
    try:
        while True:
            with timer("collect"):
                batch = next(batches, None)
            if batch is None:
                break
            # only what the loop reads: the loss's keys (a cheaper extend and sample), the score and the ends
            batch = batch.select(*loss.in_keys, *_SCORE_KEYS).reshape(-1)
            with timer("buffer"):
                buffer.extend(batch.select(*loss.in_keys))
            state.frames += batch.numel()
            if isinstance(exploration, EpsilonGreedy):
                exploration.step(batch.numel())
            running_score += -batch[_SCORE_KEYS[0]].mean(-1).reshape(-1, num_envs).sum(0)
            done = batch[_SCORE_KEYS[1]].reshape(-1, num_envs).any(0)
            if done.any():
                for score in running_score[done].tolist():
                    state.episodes += 1
                    if logger:
                        logger.log_scalar("train/score", score, step=state.frames)
                    if state.episodes % eval_every == 0:
                        evaluator.add(state.episodes, state.frames)
                running_score[done] = 0.0
            if evaluator.full:
                with timer("evaluate"):
                    evaluate(evaluator, state, logger)
                bar.set_postfix(score=f"{state.eval_scores[-1]:.0f}", **_exploration_status(exploration))

            if state.frames >= warmup_frames:
                updates_owed += updates_per_frame * batch.numel()
                while updates_owed >= 1:
                    updates_owed -= 1
                    with timer("buffer"):
                        sample = buffer.sample()
                    # the first step of a job compiles (compile.update=true): timed apart from the steady steps
                    with timer("first_update" if first_update else "update"):
                        losses = update(sample)
                    first_update = False
                    state.updates += 1
                    if logger and state.updates % 100 == 0:
                        logger.log_scalar("train/loss", losses["loss"].item(), step=state.frames)
                        if isinstance(exploration, EpsilonGreedy):
                            logger.log_scalar("train/epsilon", exploration.epsilon, step=state.frames)
            if state.frames % checkpoint_every < batch.numel():
                with timer("evaluate"):
                    evaluate(evaluator, state, logger)  # a checkpoint keeps no pending evaluation
                with timer("checkpoint"):
                    save_checkpoint(out_dir / "checkpoints" / "last.pt", cfg, state, actor, loss, optimizer,
                                    exploration, buffer, env)
            bar.update(batch.numel())
        with timer("evaluate"):
            evaluate(evaluator, state, logger)
    finally:
        gc.unfreeze()
        bar.close()
        collector.shutdown()
        # logging, the progress bar and the loop's own bookkeeping
        timer.add("other", time.perf_counter() - start - (sum(state.seconds.values()) - measured_before))
    save_checkpoint(out_dir / "checkpoints" / "last.pt", cfg, state, actor, loss, optimizer, exploration, buffer,
                    env)
    seconds = time.perf_counter() - start
    if logger:
        logger.log_scalar("train/frames_per_s", remaining / seconds, step=state.frames)
        for phase, phase_seconds in state.seconds.items():
            logger.log_scalar(f"time/{phase}_s", phase_seconds, step=state.frames)
    return state


class Updater:
    """One optimiser step per call: loss, gradients, gradient-norm clipping, Adam step, target bookkeeping.

    The step is one function of tensors (:func:`adam_step`): ``torch.autograd.grad`` of the loss, the norm
    clipping of ``torch.nn.utils.clip_grad_norm_`` and Adam's arithmetic (:func:`adam_update`, that of
    ``torch.optim.Adam``'s default single-tensor step, bit for bit) on the optimiser's own state, so that
    checkpoints keep the ``optimizer.state_dict()`` format and a learning rate changed in its parameter group
    takes effect. The step counts and the bias corrections are computed here, outside the step function, and
    enter it as tensors: compiled, a changing Python number would recompile and a correction computed from
    the step inside the graph would be recomputed for every element. ``compile=True`` runs the step function
    as one ``torch.compile`` graph (forward, backward, clipping and Adam fused; the first call compiles;
    :func:`aia.compiling.compiled_update`: the loss module's settings must not change after that call); eager
    and compiled give the same losses and parameters up to float rounding. The hard target-network copy
    (``target_updater.step()``) stays outside the graph.
    """

    def __init__(self, loss: LossModule, optimizer: torch.optim.Adam, target_updater: HardUpdate, grad_clip: float,
                 compile: bool = False) -> None:
        if not isinstance(optimizer, torch.optim.Adam) or len(optimizer.param_groups) != 1:
            raise TypeError("Updater drives a torch.optim.Adam with one parameter group")
        group = optimizer.param_groups[0]
        unsupported = {name: group[name] for name, plain in _PLAIN_ADAM.items() if group[name] != plain}
        if unsupported:
            raise ValueError(f"Updater drives a plain Adam ({_PLAIN_ADAM}); got {unsupported}")
        self.loss = loss
        self.optimizer = optimizer
        self.target_updater = target_updater
        self.grad_clip = float(grad_clip)
        self._step = compiled_update(adam_step) if compile else adam_step
        params = group["params"]
        # This step's learning rate over the first moment's bias correction, and the second one's square root.
        self._corrections = torch.zeros(2, dtype=params[0].dtype, device=params[0].device)

    def __call__(self, batch: TensorDictBase) -> TensorDictBase:
        """Update on ``batch``; returns the loss module's output, detached."""
        group = self.optimizer.param_groups[0]
        params = group["params"]
        states = [_adam_state(self.optimizer, p) for p in params]
        torch._foreach_add_([s["step"] for s in states], 1.0)
        step = states[0]["step"].item()
        beta1, beta2 = group["betas"]
        self._corrections.copy_(torch.tensor([group["lr"] / (1 - beta1**step), (1 - beta2**step) ** 0.5]))
        losses = self._step(
            self.loss, batch, params, [s["exp_avg"] for s in states], [s["exp_avg_sq"] for s in states],
            self._corrections, self.grad_clip, beta1, beta2, group["eps"],
        )
        self.target_updater.step()
        return losses


def adam_step(loss: LossModule, batch: TensorDictBase, params: list[Tensor], exp_avgs: list[Tensor],
              exp_avg_sqs: list[Tensor], corrections: Tensor, grad_clip: float, beta1: float, beta2: float,
              eps: float) -> TensorDictBase:
    """``loss(batch)``, its gradients, ``clip_grad_norm_``'s clipping and :func:`adam_update` in place."""
    losses = loss(batch)
    grads = torch.autograd.grad(losses["loss"], params)
    # clip_grad_norm_'s norm and scale (get_total_norm's _foreach_norm has no inductor kernel: 2 eager calls)
    total_norm = torch.linalg.vector_norm(torch.stack([torch.linalg.vector_norm(g) for g in grads]))
    scale = torch.clamp(grad_clip / (total_norm + 1e-6), max=1.0)
    with torch.no_grad():
        adam_update(params, [g * scale for g in grads], exp_avgs, exp_avg_sqs, corrections, beta1, beta2, eps)
    return losses.detach()


def adam_update(params: list[Tensor], grads: list[Tensor], exp_avgs: list[Tensor], exp_avg_sqs: list[Tensor],
                corrections: Tensor, beta1: float, beta2: float, eps: float) -> None:
    """Adam's update of ``params`` and its moments in place, as ``torch.optim.Adam``'s single-tensor step.

    ``corrections`` holds ``lr / (1 - beta1**step)`` and ``sqrt(1 - beta2**step)`` (in the params' dtype),
    the operations and their order are those of ``torch.optim.adam._single_tensor_adam`` (no weight decay,
    amsgrad or maximize), so the eager result is the same to the bit.
    """
    step_size, bias_correction2_sqrt = corrections[0], corrections[1]
    for param, grad, exp_avg, exp_avg_sq in zip(params, grads, exp_avgs, exp_avg_sqs, strict=True):
        exp_avg.lerp_(grad, 1 - beta1)
        exp_avg_sq.mul_(beta2).addcmul_(grad, grad, value=1 - beta2)
        denom = (exp_avg_sq.sqrt() / bias_correction2_sqrt).add_(eps)
        param.sub_(step_size * exp_avg / denom)


# The Adam options that Updater leaves at torch.optim.Adam's defaults.
_PLAIN_ADAM = {"weight_decay": 0, "amsgrad": False, "maximize": False, "differentiable": False,
               "decoupled_weight_decay": False}


def _adam_state(optimizer: torch.optim.Adam, param: Tensor) -> dict[str, Tensor]:
    """``optimizer.state[param]``, initialised as ``Adam.step`` does before its first step."""
    state = optimizer.state[param]
    if not state:
        group = optimizer.param_groups[0]
        on_device = group["capturable"] or group["fused"]
        state["step"] = torch.zeros((), dtype=torch.float32 if group["fused"] else torch.get_default_dtype(),
                                    device=param.device if on_device else "cpu")
        state["exp_avg"] = torch.zeros_like(param, memory_format=torch.preserve_format)
        state["exp_avg_sq"] = torch.zeros_like(param, memory_format=torch.preserve_format)
    return state


def evaluate(evaluator: Evaluator, state: TrainingState, logger: Logger | None) -> None:
    """Play the pending evaluations; log each one's score mean and std and belief error at its own frame."""
    results = evaluator.flush()
    for point, summary in results:
        state.evaluations += 1
        state.eval_scores.append(summary["score_mean"])
        if logger:
            log_score_summary(logger, summary, point.frame)
            if isinstance(logger, MCAPLogger):
                logger.log_text(f"evaluation {point.index + 1} after {point.episode} training episodes "
                                f"({point.frame} frames): score {summary['score_mean']:.1f} "
                                f"+- {summary['score_std']:.1f} over {len(summary['scores'])} episodes, "
                                f"belief error {summary['belief_error']:.1f} m")
    if logger and results:
        logger.flush()  # a run killed later keeps every evaluation played so far


def _exploration_status(exploration) -> dict[str, str]:
    """What the progress bar shows of the exploration (epsilon-greedy's current epsilon)."""
    return {"eps": f"{exploration.epsilon:.2f}"} if isinstance(exploration, EpsilonGreedy) else {}
