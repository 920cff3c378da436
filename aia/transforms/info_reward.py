"""``InfoReward``: the information-acquisition reward of SPEC 7 from the env's raw keys."""

from __future__ import annotations

import torch
from tensordict import TensorDictBase
from torch import Tensor
from torchrl.envs.transforms import Transform

from aia.envs.config import RewardConfig
from aia.runtime.compiling import compiled

_IN_KEYS = ("logdet_cov", "observed", "obstacle_polar", "collision")


class InfoReward(Transform):
    """Replace ``reward`` with the shaped information reward (SPEC 7):

    ``R = -kappa_m * agg_i log det Sigma_i - kappa_d * std_i log det Sigma_i - kappa_o * obstacle(o_r)
    + observed_bonus * mean_i observed_i``, where ``agg`` is the mean (2019 code) or the sum (paper), the
    obstacle term is ``m^2 / max(m^2, o_r^2)`` (2019) or ``1 / o_r^2`` (paper) and applies only when an
    obstacle is in view (``o_r`` below the sensor range, read from the env's ``obstacle_polar`` spec), and
    a collision turns ``R`` into ``min(0, R) - collision_penalty`` when that penalty is positive (later
    rewrite). The defaults are the 2019 code's reward, which produced the paper's runs.
    """

    def __init__(self, config: RewardConfig | None = None, compile: bool = False) -> None:
        super().__init__(in_keys=list(_IN_KEYS), out_keys=["reward"])
        self.config = config or RewardConfig()
        self._sensor_range: float | None = None
        self._reward = compiled(info_reward) if compile else info_reward

    @property
    def sensor_range(self) -> float:
        """Distance reported when no obstacle is in view, from the parent env's ``obstacle_polar`` spec."""
        if self._sensor_range is None:
            spec = self.parent.full_observation_spec["obstacle_polar"]
            self._sensor_range = float(spec.space.high.reshape(-1, 2)[0, 0])
        return self._sensor_range

    def _call(self, tensordict: TensorDictBase) -> TensorDictBase:
        logdet, observed, obstacle, collision = (tensordict.get(k) for k in _IN_KEYS)
        reward = self._reward(logdet, observed, obstacle[..., 0], collision, self.sensor_range, self.config)
        tensordict.set("reward", reward.unsqueeze(-1))
        return tensordict

    def _reset(self, tensordict: TensorDictBase, tensordict_reset: TensorDictBase) -> TensorDictBase:
        return tensordict_reset


def info_reward(
    logdet: Tensor, observed: Tensor, obstacle_distance: Tensor, collision: Tensor, sensor_range: float,
    config: RewardConfig,
) -> Tensor:
    """``[...]`` reward from ``logdet [..., N]``, ``observed [..., N]``, ``obstacle_distance [...]`` and
    ``collision [...]`` (SPEC 7)."""
    aggregate = logdet.mean(-1) if config.target_aggregate == "mean" else logdet.sum(-1)
    reward = -config.kappa_m * aggregate
    if config.kappa_d:
        reward = reward - config.kappa_d * logdet.std(-1, correction=0)
    if config.kappa_o:
        if config.obstacle_form == "2019":
            margin2 = config.obstacle_margin**2
            penalty = margin2 / torch.clamp(obstacle_distance.square(), min=margin2)
        else:
            penalty = 1.0 / obstacle_distance.square().clamp_min(1e-12)
        reward = reward - config.kappa_o * torch.where(obstacle_distance < sensor_range, penalty, 0.0)
    if config.observed_bonus:
        reward = reward + config.observed_bonus * observed.to(reward.dtype).mean(-1)
    if config.collision_penalty:
        reward = torch.where(collision, reward.clamp_max(0.0) - config.collision_penalty, reward)
    return reward
