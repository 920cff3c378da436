"""Checkpoints: each member of a population writes its own, in its own run folder.

A member's checkpoint holds its slice of everything the population stacks (online and target networks, Adam's
moments, its replay rows and sampler count, its worlds' episode counters), the shared counters and step
counts, its config and, for ``aia-eval``, its network as the state dict of a solo actor. Every random draw of
the loop is counter-based, so these counters are the whole random state: a population resumes by loading each
member's file, and a member may resume alone or inside another population. How the files are written, kept and
verified: :mod:`aia.training.checkpoint_files`.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import torch
from omegaconf import DictConfig, OmegaConf
from tensordict import TensorDictBase
from torch import Tensor
from torchrl.objectives import HardUpdate

from aia.modules import PopulationQPolicy
from aia.training.optimizer import StackedAdam
from aia.training.replay import MemberReplay

CHECKPOINT_NAME = "checkpoints/last.pt"
PREVIOUS_CHECKPOINT_NAME = "checkpoints/previous.pt"  # the one before: what resume=auto falls back to


@dataclass
class PopulationParts:
    """What a checkpoint reads from and writes into: the loop's stacked state."""

    online: TensorDictBase  # the loss module's value_network_params
    target: TensorDictBase  # its target_value_network_params
    optimizer: StackedAdam
    policy: PopulationQPolicy
    replay: MemberReplay
    target_updater: HardUpdate
    world_episodes: Tensor  # the training env's per-world episode counters, [P * W] member-major


def _flat(params: TensorDictBase) -> dict[str, Tensor]:
    return {".".join(key): value for key, value in params.items(include_nested=True, leaves_only=True)}


def member_checkpoint(parts: PopulationParts, member: int, cfg: DictConfig, state: dict, actor_state: dict) -> dict:
    """Member ``member``'s checkpoint: its slices, the counters ``state`` and its solo actor's state dict."""
    worlds = parts.world_episodes.shape[0] // parts.optimizer.params[0].shape[0]
    return {
        "config": OmegaConf.to_container(cfg, resolve=True),
        "saved_at_ns": time.time_ns(),  # a resumed run's log drops what the log it continues wrote later
        "state": state,
        "actor": actor_state,
        "online": {k: v[member].detach().clone() for k, v in _flat(parts.online).items()},
        "target": {k: v[member].detach().clone() for k, v in _flat(parts.target).items()},
        "optimizer": {"step": parts.optimizer.step_count,
                      "exp_avg": [m[member].clone() for m in parts.optimizer.exp_avgs],
                      "exp_avg_sq": [m[member].clone() for m in parts.optimizer.exp_avg_sqs]},
        "policy_steps": parts.policy.steps,
        "target_updater_counter": parts.target_updater.counter,
        "replay": parts.replay.member_state(member),
        "env_episodes": parts.world_episodes[member * worlds:(member + 1) * worlds].clone(),
    }


def load_member(parts: PopulationParts, member: int, checkpoint: dict) -> None:
    """Put ``checkpoint`` (from :func:`member_checkpoint`) into member ``member``'s slices."""
    with torch.no_grad():
        for params, saved in ((parts.online, checkpoint["online"]), (parts.target, checkpoint["target"])):
            flat = _flat(params)
            if flat.keys() != saved.keys() or any(flat[k][member].shape != saved[k].shape for k in flat):
                raise ValueError("the checkpoint's network does not match this run's network")
            for key, value in saved.items():
                flat[key].data[member].copy_(value)
        opt = checkpoint["optimizer"]
        for moments, saved in ((parts.optimizer.exp_avgs, opt["exp_avg"]), (parts.optimizer.exp_avg_sqs,
                                                                             opt["exp_avg_sq"])):
            for moment, value in zip(moments, saved, strict=True):
                moment[member].copy_(value)
    parts.optimizer.step_count = opt["step"]
    parts.policy.steps = checkpoint["policy_steps"]
    parts.target_updater.counter = checkpoint["target_updater_counter"]
    parts.replay.load_member_state(member, checkpoint["replay"])
    worlds = checkpoint["env_episodes"].shape[0]
    parts.world_episodes[member * worlds:(member + 1) * worlds] = checkpoint["env_episodes"]
