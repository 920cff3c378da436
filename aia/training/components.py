"""The parts a training run is wired from: networks, the loss, the logger and the scene recorder."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import torch
from omegaconf import DictConfig
from tensordict.nn import TensorDictSequential
from torch import nn
from torchrl.objectives import DQNLoss, LossModule
from torchrl.record.loggers import Logger
from torchrl.record.loggers.csv import CSVLogger

from aia.logging import MCAPLogger, SceneRecorder
from aia.logging.segments import RESUMED_AFTER_KEY, next_segment
from aia.losses import ADFQLoss, use_memberwise_double
from aia.modules import ADFQNetwork, ConvQNetwork, ConvTorso, StackedConvQNetwork, StackedQNetwork, make_q_network
from aia.modules.q_networks import MAP_KEY, OBSERVATION_KEY, make_qvalue_actor


def map_shape(observation_spec) -> tuple[int, int, int] | None:
    """``(C, H, W)`` of the observation's map image (its ``local_map`` key), or ``None`` without one."""
    return tuple(observation_spec[MAP_KEY].shape[-3:]) if MAP_KEY in observation_spec else None


def observation_layout(observation_spec) -> str:
    """What a Q-network reads of a world's observation, in words: ``"observation [8], local_map [1, 28, 28]"``
    (the belief features' size and, with a map image, its ``C, H, W``)."""
    image = map_shape(observation_spec)
    features = f"{OBSERVATION_KEY} [{observation_spec[OBSERVATION_KEY].shape[-1]}]"
    return features if image is None else f"{features}, {MAP_KEY} [{', '.join(map(str, image))}]"


def make_network(cfg: DictConfig, obs_dim: int, num_actions: int,
                 map_image: tuple[int, int, int] | None = None) -> nn.Module:
    """One member's Q-network (MLP, or the ADFQ mean/log-sd network), initialised from torch's global RNG; with a
    map image ``(C, H, W)`` (:func:`map_shape`), that network as the head of a :class:`~aia.modules.ConvQNetwork`
    whose torso (``cfg.conv_layers``, made first) reads the image."""
    torso = None
    if map_image is not None:
        channels, height, width = map_image
        if height != width:
            raise ValueError(f"the map image must be square, got {height} x {width}")
        torso = ConvTorso(channels, height, [tuple(layer) for layer in cfg.conv_layers])
        obs_dim += torso.out_features
    hidden = tuple(cfg.hidden)
    if cfg.algo.name == "adfq":
        head = ADFQNetwork(obs_dim, num_actions, hidden, var_min=cfg.algo.var_min, sd_max=cfg.algo.sd_max)
    else:
        head = make_q_network(obs_dim, num_actions, hidden)
    return head if torso is None else ConvQNetwork(torso, head)


def make_actor(cfg: DictConfig, env) -> TensorDictSequential:
    """The greedy Q-value actor of one run for ``env``'s observation (what ``aia-eval`` loads a checkpoint into)."""
    network = make_network(cfg, env.observation_spec[OBSERVATION_KEY].shape[-1], env.action_spec.n,
                           map_shape(env.observation_spec))
    return make_qvalue_actor(network.to(cfg.device), env.action_spec, adfq=cfg.algo.name == "adfq")


def make_stacked_network(cfgs: Sequence[DictConfig], obs_dim: int, num_actions: int,
                         map_image: tuple[int, int, int] | None = None) -> StackedQNetwork | StackedConvQNetwork:
    """The members' networks stacked, member ``k`` initialised under ``torch.manual_seed(cfgs[k].seed)``
    (the initialisation a population of one with that seed gets), the inner layers' matmuls in
    ``cfg.inner_dtype``; with a map image, conv networks (:func:`make_network`)."""
    networks = []
    for cfg in cfgs:
        torch.manual_seed(cfg.seed)
        networks.append(make_network(cfg, obs_dim, num_actions, map_image))
    stacked = StackedQNetwork if map_image is None else StackedConvQNetwork
    return stacked.stack(networks, getattr(torch, cfgs[0].inner_dtype)).to(cfgs[0].device)


def make_loss(cfgs: Sequence[DictConfig], actor: TensorDictSequential) -> LossModule:
    """The population's loss on ``actor``, with per-sample losses (``reduction="none"``: the optimiser step
    averages each member's own): ADFQ, or TorchRL's DQNLoss for DQN and Double DQN members, with a
    :class:`~aia.losses.MemberwiseDoubleTD0` target when the population mixes the two."""
    cfg = cfgs[0]  # the settings every member shares
    if cfg.algo.name == "adfq":
        return ADFQLoss(actor, gamma=cfg.gamma, noise=cfg.algo.noise, var_min=cfg.algo.var_min,
                        sd_max=cfg.algo.sd_max, reward_var=cfg.algo.reward_var,
                        loss_function=cfg.algo.loss_function, reduction="none")
    double = [c.algo.name == "ddqn" for c in cfgs]
    loss = DQNLoss(actor, loss_function=cfg.algo.loss_function, delay_value=True,
                   double_dqn=all(double), action_space="categorical", reduction="none")
    # the estimator's buffers (its discount) made on the run's device: TorchRL would make them on the CPU and
    # move them at the first call, and a compiled update traced then would compile again at the second (found
    # on an H200: a recompile inside the measured steps of every compiled CUDA job)
    if len(set(double)) > 1:
        return use_memberwise_double(loss, double, cfg.gamma, cfg.device)
    loss.make_value_estimator(gamma=cfg.gamma, device=cfg.device)
    return loss


def make_logger(cfg: DictConfig, out_dir: Path, resumed_after_ns: int | None = None) -> Logger | None:
    """TorchRL logger of one run (``logger=mcap``, ``logger=csv`` or ``logger=none``); it gets the config.

    A resumed run (``resumed_after_ns``: when its checkpoint was written) whose MCAP log exists writes the
    log's next segment (:mod:`aia.logging.segments`), read back with the first as one history."""
    if cfg.logger.name == "none":
        return None
    if cfg.logger.name == "csv":
        logger = CSVLogger(exp_name="csv", log_dir=str(out_dir))
    elif cfg.logger.name == "mcap":
        resumed = {RESUMED_AFTER_KEY: resumed_after_ns} if resumed_after_ns is not None else {}
        logger = MCAPLogger(
            exp_name=f"{cfg.algo.name}-{cfg.exploration.name}-seed{cfg.seed}", log_dir=out_dir,
            file_name=next_segment(out_dir / cfg.logger.file).name, compression=cfg.logger.compression,
            chunk_size=cfg.logger.chunk_size, flush_interval_s=cfg.logger.flush_interval_s,
            run_metadata={"seed": cfg.seed, "algo": cfg.algo.name, "exploration": cfg.exploration.name, **resumed},
        )
    else:
        raise ValueError(f"logger={cfg.logger.name!r} is not one of ['mcap', 'csv', 'none']")
    logger.log_hparams(cfg)
    return logger


def make_recorders(cfg: DictConfig, loggers: Sequence[Logger | None], eval_env) -> list[SceneRecorder]:
    """One scene recorder per member on the evaluation env when the MCAP loggers record episodes, else none."""
    if cfg.logger.name != "mcap" or cfg.logger.record_every_evaluations < 1:
        return []
    recorders = [SceneRecorder(logger) for logger in loggers]
    for recorder in recorders:
        eval_env.append_transform(recorder)
    return recorders
