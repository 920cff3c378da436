"""Evaluation rollouts: one episode in every world of a batched env."""

from __future__ import annotations

from collections.abc import Callable

import torch
from tensordict import TensorDictBase
from torchrl.envs import EnvBase


def run_episodes(env: EnvBase, policy: Callable[[TensorDictBase], TensorDictBase], seed: int | None = None
                 ) -> TensorDictBase:
    """One episode in every world of ``env`` under ``policy``: a ``[B, T]`` rollout from a fresh reset."""
    if seed is not None:
        env.set_seed(seed)
    max_steps = env.base_env.config.max_steps if hasattr(env, "base_env") else env.config.max_steps
    with torch.no_grad():
        return env.rollout(max_steps, policy=policy, break_when_any_done=False)
