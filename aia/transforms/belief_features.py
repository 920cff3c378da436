"""``BeliefFeatures``: the paper's RL state (SPEC 6) computed from the env's raw belief keys.

Its layout follows the belief the env keeps, read from the env's specs: ``6N + 2`` features when the beliefs
carry a velocity (the env emits ``belief_velocity``), ``4N + 2`` without (ttenv v2's layout: no rates).
"""

from __future__ import annotations

import math

import torch
from tensordict import TensorDictBase
from torch import Tensor
from torchrl.data import Bounded, Composite
from torchrl.envs.transforms import Transform

from aia.envs.dynamics import wrap_angle
from aia.runtime.compiling import compiled

_IN_KEYS = ("robot_pose", "robot_velocity", "belief_mean", "logdet_cov", "observed", "obstacle_polar")
_VELOCITY_KEY = "belief_velocity"
_RELATIVE_VELOCITY = ("exact", "2019")


class BeliefFeatures(Transform):
    """Write the ``6N + 2`` feature vector of SPEC 6 under ``out_key`` (default ``"observation"``).

    Per target, in the robot frame: ``[r, alpha, rdot, alphadot, log det Sigma, observed]`` of the belief
    mean (the rates relative to the robot moving at its last commanded (v, w), from ``belief_velocity``);
    then ``[o_r, o_alpha]`` of the closest obstacle in view. Where the env emits no ``belief_velocity`` the
    rates are left out: ``[r, alpha, log det Sigma, observed]`` per target, ``4N + 2`` in all.
    ``relative_velocity="2019"`` reproduces the authors' 2019 formula, whose angular rate is taken about the
    map origin and whose robot velocity carries an extra ``|p| w`` term.
    """

    def __init__(self, relative_velocity: str = "exact", out_key: str = "observation", compile: bool = False) -> None:
        if relative_velocity not in _RELATIVE_VELOCITY:
            raise ValueError(f"relative_velocity={relative_velocity!r} is not one of {list(_RELATIVE_VELOCITY)}")
        super().__init__(in_keys=list(_IN_KEYS), out_keys=[out_key])
        self.relative_velocity = relative_velocity
        self._features = compiled(belief_features) if compile else belief_features

    def _call(self, tensordict: TensorDictBase) -> TensorDictBase:
        pose, velocity, mean, logdet, observed, obstacle = (tensordict.get(k) for k in _IN_KEYS)
        target_velocity = tensordict.get(_VELOCITY_KEY, None)
        features = self._features(pose, velocity, mean[..., :2], target_velocity, logdet, observed, obstacle,
                                  self.relative_velocity)
        tensordict.set(self.out_keys[0], features)
        return tensordict

    def _reset(self, tensordict: TensorDictBase, tensordict_reset: TensorDictBase) -> TensorDictBase:
        return self._call(tensordict_reset)

    def transform_observation_spec(self, observation_spec: Composite) -> Composite:
        mean_spec = observation_spec["belief_mean"]
        obstacle_spec = observation_spec["obstacle_polar"]
        num_targets = mean_spec.shape[-2]
        batch = mean_spec.shape[:-2]
        sensor_range = float(obstacle_spec.space.high.reshape(-1, 2)[0, 0])
        inf = math.inf
        rates = _VELOCITY_KEY in observation_spec.keys()  # noqa: SIM118 (a Composite has no `in`)
        per_target_low = [0.0, -math.pi, *([-inf, -inf] if rates else []), -inf, 0.0]
        per_target_high = [inf, math.pi, *([inf, inf] if rates else []), inf, 1.0]
        low = torch.tensor(per_target_low * num_targets + [0.0, -math.pi], dtype=mean_spec.dtype)
        high = torch.tensor(per_target_high * num_targets + [sensor_range, math.pi], dtype=mean_spec.dtype)
        size = len(per_target_low) * num_targets + 2
        observation_spec[self.out_keys[0]] = Bounded(
            low=low.expand(*batch, size), high=high.expand(*batch, size), shape=(*batch, size),
            dtype=mean_spec.dtype, device=mean_spec.device,
        )
        return observation_spec


def belief_features(
    pose: Tensor,
    velocity: Tensor,
    position: Tensor,
    target_velocity: Tensor | None,
    logdet: Tensor,
    observed: Tensor,
    obstacle: Tensor,
    relative_velocity: str = "exact",
) -> Tensor:
    """``[..., 6N + 2]`` features from ``pose [..., 3]``, ``velocity [..., 2]`` (v, w), the belief means'
    ``position [..., N, 2]`` and ``target_velocity [..., N, 2]``, ``logdet [..., N]``, ``observed [..., N]``
    and ``obstacle [..., 2]`` (SPEC 6); ``[..., 4N + 2]`` without the rates when ``target_velocity`` is None."""
    xy, theta = pose[..., None, :2], pose[..., None, 2]
    delta = position - xy
    r2 = delta.square().sum(-1)
    r = torch.sqrt(r2)
    alpha = wrap_angle(torch.atan2(delta[..., 1], delta[..., 0]) - theta)
    if target_velocity is None:
        per_target = torch.stack((r, alpha, logdet, observed.to(r.dtype)), -1)
        return torch.cat((per_target.flatten(-2), obstacle), -1)
    v, w = velocity[..., None, 0], velocity[..., None, 1]
    heading = torch.stack((torch.cos(theta), torch.sin(theta)), -1)
    if relative_velocity == "exact":
        robot_velocity = v[..., None] * heading
        relative = target_velocity - robot_velocity
        cross = delta[..., 0] * relative[..., 1] - delta[..., 1] * relative[..., 0]
        alpha_dot = torch.where(r2 > 0, cross / r2.clamp_min(1e-12), 0.0) - w
    else:
        # 2019 code (xyg2polarb_dot_2): robot velocity with a |p| w term, angular rate about the origin.
        rho = torch.linalg.vector_norm(xy, dim=-1)
        normal = torch.stack((-heading[..., 1], heading[..., 0]), -1)
        robot_velocity = v[..., None] * heading + (rho * w)[..., None] * normal
        relative = target_velocity - robot_velocity
        origin_r2 = position.square().sum(-1)
        cross = position[..., 0] * target_velocity[..., 1] - target_velocity[..., 0] * position[..., 1]
        alpha_dot = torch.where(origin_r2 > 0, cross / origin_r2.clamp_min(1e-12), 0.0) - w
    r_dot = torch.where(r > 0, (delta * relative).sum(-1) / r.clamp_min(1e-12), 0.0)
    if relative_velocity == "2019":
        alpha_dot = torch.where(r > 0, alpha_dot, 0.0)  # the 2019 code returns (0, 0) at r = 0
    per_target = torch.stack((r, alpha, r_dot, alpha_dot, logdet, observed.to(r.dtype)), -1)
    return torch.cat((per_target.flatten(-2), obstacle), -1)
