"""``Population``: the objects a population's training builds once, shared by the loop, the checkpoints and the
evaluator.

:func:`build_population` makes them from the members' configs (the settings they share from ``cfgs[0]``, what
they may differ in from their own), loads the members' checkpoints into them when the run resumes, and points
every member's worlds at the streams a solo run with its seed would meet. The loop (:mod:`aia.training.loop`)
then only steps them; a checkpoint (:mod:`aia.training.checkpoint`) reads and writes their member slices.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, replace

import torch
from omegaconf import DictConfig
from tensordict import TensorDictBase
from tensordict.nn import TensorDictSequential
from torch import Tensor
from torchrl.envs import EnvBase, SelectTransform
from torchrl.objectives import HardUpdate, LossModule
from torchrl.record.loggers import Logger

from aia.envs import make_env
from aia.envs.config import TrackingConfig
from aia.envs.factory import to_tracking_config
from aia.evaluation import Evaluator
from aia.modules import PopulationQPolicy, StackedConvQNetwork, StackedQNetwork
from aia.modules.q_networks import MAP_KEY, OBSERVATION_KEY, make_qvalue_actor
from aia.training.checkpoint import TrainingState, load_member
from aia.training.components import make_actor, make_loss, make_recorders, make_stacked_network, map_shape
from aia.training.optimizer import StackedAdam, Updater
from aia.training.replay import MemberReplay
from aia.training.target_cache import TargetCache

# Seeds of member k's evaluation worlds and noise, derived from its seed.
_EVAL_SEED_OFFSET = 1_000_003


@dataclass
class Population:
    """``P`` members' stacked training objects; member ``k`` owns worlds ``k W .. k W + W - 1`` of ``env``."""

    cfgs: list[DictConfig]
    env_config: TrackingConfig
    env: EnvBase  # the training env of P * W worlds, member-major
    network: StackedQNetwork | StackedConvQNetwork
    policy: PopulationQPolicy
    loss: LossModule
    online: TensorDictBase  # the loss module's value_network_params
    target: TensorDictBase  # its target_value_network_params
    target_updater: HardUpdate
    optimizer: StackedAdam
    replay: MemberReplay
    targets: TargetCache | None  # ADFQ's cached targets of the replay rows
    update: Updater
    evaluator: Evaluator
    world_episodes: Tensor  # the training env's per-world episode counters, [P * W] member-major
    actor_template: TensorDictSequential  # a solo actor: the shape of a member's network in its checkpoint

    @property
    def worlds_per_member(self) -> int:
        """``W``: each member's worlds of the training env."""
        return self.cfgs[0].collector.num_envs


def build_population(cfgs: list[DictConfig], loggers: Sequence[Logger | None], checkpoints: list[dict | None]
                     ) -> tuple[Population, TrainingState, list[list[float]]]:
    """The population of ``cfgs`` (one recorder per member's logger), with ``checkpoints`` (all or none) loaded;
    with the counters it continues from (shared by the members) and each member's evaluation scores so far."""
    cfg = cfgs[0]  # the shared settings
    P, W = len(cfgs), cfg.collector.num_envs
    seeds = [int(c.seed) for c in cfgs]
    env_config = to_tracking_config(cfg.env)
    env = make_env(env_config, batch_size=P * W, device=cfg.device, compile=cfg.compile.env)
    # The collector copies every key of every frame: keep what the policy, the loss and the score read.
    image = map_shape(env.observation_spec)
    observed = (OBSERVATION_KEY, MAP_KEY) if image else (OBSERVATION_KEY,)
    env.append_transform(SelectTransform(*observed, "logdet_cov", keep_rewards=True, keep_dones=True))
    eval_env = make_env(env_config, batch_size=cfg.eval.episodes * cfg.eval.per_rollout * P, device=cfg.device,
                        compile=cfg.compile.env)
    obs_dim, num_actions = env.observation_spec[OBSERVATION_KEY].shape[-1], env.action_spec.n
    network = make_stacked_network(cfgs, obs_dim, num_actions, image)
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
    world_episodes = torch.zeros(P * W, dtype=torch.int64)
    shared, scores = _counters(checkpoints)
    evaluator = Evaluator(
        eval_env, network, num_actions, cfg.eval.episodes, cfg.eval.epsilon,
        seeds=[s + _EVAL_SEED_OFFSET for s in seeds], noise_seeds=[(s + 1) * _EVAL_SEED_OFFSET for s in seeds],
        first_index=shared.evaluations, recorders=make_recorders(cfg, loggers, eval_env),
        record_every=cfg.logger.get("record_every_evaluations", 0), compile=cfg.compile.policy)
    population = Population(
        cfgs, env_config, env, network, policy, loss, loss.value_network_params, loss.target_value_network_params,
        target_updater, optimizer, replay, targets, update, evaluator, world_episodes, make_actor(cfg, env))
    for member, checkpoint in enumerate(checkpoints):
        if checkpoint is not None:
            load_member(population, member, checkpoint)
    # member k's worlds are a solo run's worlds with its seed (episode counters as checkpointed)
    env.base_env.replay_streams(torch.tensor(seeds).repeat_interleave(W), torch.arange(W).repeat(P), world_episodes)
    return population, shared, scores


def _counters(checkpoints: list[dict | None]) -> tuple[TrainingState, list[list[float]]]:
    """The counters the members continue from (the same in every member's checkpoint) and each member's
    evaluation scores so far."""
    if checkpoints[0] is None:
        return TrainingState(), [[] for _ in checkpoints]
    states = [TrainingState(**checkpoint["state"]) for checkpoint in checkpoints]
    return replace(states[0], eval_scores=[]), [s.eval_scores for s in states]
