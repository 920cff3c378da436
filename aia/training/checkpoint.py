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
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import torch
from omegaconf import DictConfig, OmegaConf
from tensordict import TensorDictBase
from torch import Tensor

if TYPE_CHECKING:  # the population module builds on this one
    from aia.training.population import Population


@dataclass
class TrainingState:
    """A member's counters and evaluation scores: what a checkpoint carries across a restart."""

    frames: int = 0
    updates: int = 0
    episodes: int = 0
    evaluations: int = 0
    eval_scores: list[float] = field(default_factory=list)
    seconds: dict[str, float] = field(default_factory=dict)  # wall clock per phase of the loop (PhaseTimer)


def _flat(params: TensorDictBase) -> dict[str, Tensor]:
    return {".".join(key): value for key, value in params.items(include_nested=True, leaves_only=True)}


def member_checkpoint(population: Population, member: int, cfg: DictConfig, state: dict, actor_state: dict) -> dict:
    """Member ``member``'s checkpoint: its slices, the counters ``state`` and its solo actor's state dict."""
    worlds = population.worlds_per_member
    return {
        "config": OmegaConf.to_container(cfg, resolve=True),
        "saved_at_ns": time.time_ns(),  # a resumed run's log drops what the log it continues wrote later
        "state": state,
        "actor": actor_state,
        "online": {k: v[member].detach().clone() for k, v in _flat(population.online).items()},
        "target": {k: v[member].detach().clone() for k, v in _flat(population.target).items()},
        "optimizer": {"step": population.optimizer.step_count,
                      "exp_avg": [m[member].clone() for m in population.optimizer.exp_avgs],
                      "exp_avg_sq": [m[member].clone() for m in population.optimizer.exp_avg_sqs]},
        "policy_steps": population.policy.steps,
        "target_updater_counter": population.target_updater.counter,
        "replay": population.replay.member_state(member),
        "env_episodes": population.world_episodes[member * worlds:(member + 1) * worlds].clone(),
    }


def load_member(population: Population, member: int, checkpoint: dict) -> None:
    """Put ``checkpoint`` (from :func:`member_checkpoint`) into member ``member``'s slices."""
    with torch.no_grad():
        for params, saved in ((population.online, checkpoint["online"]), (population.target, checkpoint["target"])):
            flat = _flat(params)
            if flat.keys() != saved.keys() or any(flat[k][member].shape != saved[k].shape for k in flat):
                raise ValueError("the checkpoint's network does not match this run's network")
            for key, value in saved.items():
                flat[key].data[member].copy_(value)
        opt = checkpoint["optimizer"]
        for moments, saved in ((population.optimizer.exp_avgs, opt["exp_avg"]), (population.optimizer.exp_avg_sqs,
                                                                             opt["exp_avg_sq"])):
            for moment, value in zip(moments, saved, strict=True):
                moment[member].copy_(value)
    population.optimizer.step_count = opt["step"]
    population.policy.steps = checkpoint["policy_steps"]
    population.target_updater.counter = checkpoint["target_updater_counter"]
    population.replay.load_member_state(member, checkpoint["replay"])
    worlds = checkpoint["env_episodes"].shape[0]
    population.world_episodes[member * worlds:(member + 1) * worlds] = checkpoint["env_episodes"]
