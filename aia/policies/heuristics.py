"""Two scripted policies: uniform random actions and a greedy "turn toward the belief" pursuit.

Both read only the env's belief keys (never ``target_state``) and write ``action`` for every world at
once, so they plug into ``env.rollout(policy=...)`` and TorchRL collectors like a learned policy.
"""

from __future__ import annotations

import math

import torch
from tensordict import TensorDictBase
from torch import Tensor

from aia.envs.dynamics import se2_step, wrap_angle
from aia.envs.tracking import TargetTrackingEnv


class RandomPolicy:
    """Uniformly random motion primitives, reproducible through its own ``torch.Generator``."""

    def __init__(self, num_actions: int, seed: int = 0, device: torch.device | str = "cpu") -> None:
        self.num_actions = num_actions
        self.generator = torch.Generator(device=device).manual_seed(seed)
        self.device = torch.device(device)

    def __call__(self, tensordict: TensorDictBase) -> TensorDictBase:
        shape = tensordict.batch_size
        action = torch.randint(0, self.num_actions, shape, generator=self.generator, device=self.device)
        return tensordict.set("action", action)


class BeliefPursuitPolicy:
    """Greedy one-step pursuit of the most uncertain target's belief.

    For every primitive it predicts the robot pose after one step and picks the one that brings the belief
    mean of the target with the largest ``log det Sigma`` closest to the centre of the field of view at
    ``standoff`` times the sensor range: cost ``|bearing| / (fov / 2) + |distance - standoff * range| / range``.
    """

    def __init__(self, env: TargetTrackingEnv, standoff: float = 0.5) -> None:
        cfg = env.config
        self.primitives = env.primitives
        self.dt = cfg.dt
        self.half_fov = math.radians(cfg.sensor.fov_deg) / 2
        self.range = cfg.sensor.range
        self.standoff = standoff

    def __call__(self, tensordict: TensorDictBase) -> TensorDictBase:
        mean = tensordict.get("belief_mean")
        velocity = tensordict.get("belief_velocity", None)
        return tensordict.set(
            "action",
            self.choose(tensordict.get("robot_pose"), mean[..., :2],
                        torch.zeros_like(mean[..., :2]) if velocity is None else velocity,
                        tensordict.get("logdet_cov")),
        )

    def choose(self, pose: Tensor, position: Tensor, velocity: Tensor, logdet: Tensor) -> Tensor:
        """``[B]`` action indices from ``pose [B, 3]``, the belief means' ``position [B, N, 2]`` and
        ``velocity [B, N, 2]`` (zero where the belief has none) and ``logdet [B, N]``."""
        worst = logdet.argmax(-1)
        rows = torch.arange(position.shape[0], device=position.device)
        # Aim at where the belief will be after the step.
        goal = position[rows, worst] + self.dt * velocity[rows, worst]
        nxt = se2_step(pose[:, None, :], self.primitives[None], self.dt)  # [B, A, 3]
        delta = goal[:, None, :] - nxt[..., :2]
        distance = torch.linalg.vector_norm(delta, dim=-1)
        bearing = wrap_angle(torch.atan2(delta[..., 1], delta[..., 0]) - nxt[..., 2])
        cost = bearing.abs() / self.half_fov + (distance - self.standoff * self.range).abs() / self.range
        return cost.argmin(-1)
