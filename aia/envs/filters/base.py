"""The one interface the env calls to keep its beliefs: :class:`BeliefFilter` (and :class:`GaussianFilter`,
the filters whose whole belief is a mean and a covariance: ``kf`` and ``ukf``).

A filter keeps, per world and target, a belief whose Gaussian summary ``belief_mean [B, N, d]`` and
``belief_cov [B, N, d, d]`` the features, the reward and the score read (through its log det); a filter may
keep more state beside them (:meth:`BeliefFilter.extra_specs`). Each step it predicts every belief with its
:class:`~aia.envs.belief_models.BeliefModel` and updates the observed ones with their range-bearing
measurement. The env holds no filter-specific branch: it calls :meth:`initial` at a reset and :meth:`step`
every step, inside the compiled step where the step is compiled.
"""

from __future__ import annotations

import math
from abc import ABC, abstractmethod

import torch
from torch import Tensor
from torchrl.data import TensorSpec, Unbounded

from aia import rng
from aia.envs import belief
from aia.envs.belief_models import BeliefModel
from aia.envs.dynamics import wrap_angle


def wrap_entry(x: Tensor, index: int | None, dim: int = -1) -> Tensor:
    """``x`` with entry ``index`` of dimension ``dim`` (a heading or a bearing) wrapped to [-pi, pi); ``None``:
    ``x``."""
    if index is None:
        return x
    before, entry, after = x.split((index, 1, x.shape[dim] - index - 1), dim)
    return torch.cat((before, wrap_angle(entry), after), dim)


class BeliefFilter(ABC):
    """A batched Bayes filter over ``[B, N]`` targets.

    Args:
        model: the motion model the filter assumes.
        meas_noise: ``[2, 2]`` covariance of the range-bearing noise.
        log_det_cap: keep the previous covariance where the predicted one reaches this log det (the 2019
            code's cap, SPEC 5; ``inf``: none).
        map_size: ``[2]`` the map's width and height (for ``clip_to_map``).
        clip_to_map: clip means into the map (2019 code).
        speed_clip: clip the mean's velocity entries to +-this (2019 code; None: no clip).
    """

    def __init__(self, model: BeliefModel, meas_noise: Tensor, log_det_cap: float = math.inf,
                 map_size: Tensor | None = None, clip_to_map: bool = False, speed_clip: float | None = None) -> None:
        self.model = model
        self.meas_noise = meas_noise
        self.log_det_cap = log_det_cap
        self.map_size = map_size
        self.clip_to_map = clip_to_map
        self.speed_clip = speed_clip

    @property
    def dim(self) -> int:
        """The belief state's dimension ``d``."""
        return self.model.dim

    def extra_specs(self, batch: int, num_targets: int, dtype: torch.dtype,
                    device: torch.device) -> dict[str, TensorSpec]:
        """Specs of the state the filter keeps beside ``belief_mean`` and ``belief_cov`` (none here)."""
        return {}

    def specs(self, batch: int, num_targets: int, dtype: torch.dtype, device: torch.device) -> dict[str, TensorSpec]:
        """Specs of every key the filter writes into the env's state."""
        d = self.dim
        return {
            "belief_mean": Unbounded(shape=(batch, num_targets, d), dtype=dtype, device=device),
            "belief_cov": Unbounded(shape=(batch, num_targets, d, d), dtype=dtype, device=device),
            **self.extra_specs(batch, num_targets, dtype, device),
        }

    def initial(self, mean: Tensor, init_cov: float, key: Tensor, step: Tensor) -> dict[str, Tensor]:
        """The belief at an episode's start: ``mean [B, N, d]`` (clipped as configured) and ``init_cov I``."""
        eye = torch.eye(self.dim, dtype=mean.dtype, device=mean.device)
        cov = (init_cov * eye).expand(*mean.shape[:-1], self.dim, self.dim).clone()
        return {"belief_mean": self.clip(mean), "belief_cov": cov}

    @abstractmethod
    def step(self, state: dict[str, Tensor], measurement: Tensor, observed: Tensor, pose: Tensor, key: Tensor,
             step: Tensor) -> dict[str, Tensor]:
        """Predict every belief, then update the ``observed [B, N]`` ones with ``measurement [B, N, 2]`` taken
        from ``pose [B, 3]`` (SPEC 5 order). ``key`` and ``step`` (``[B]``) key the filter's random draws.
        Returns every key of :meth:`specs`."""

    def clip(self, mean: Tensor) -> Tensor:
        """2019 code: means clipped into the map and their velocity entries to +-speed_clip; headings wrapped."""
        if self.clip_to_map:
            position = torch.minimum(mean[..., :2].clamp_min(0.0), self.map_size)
            mean = torch.cat((position, mean[..., 2:]), -1)
        if self.speed_clip is not None and self.model.speed_entries is not None:
            first, end = self.model.speed_entries
            speeds = mean[..., first:end].clamp(-self.speed_clip, self.speed_clip)
            mean = torch.cat((mean[..., :first], speeds, mean[..., end:]), -1)
        return wrap_entry(mean, self.model.angle)

    def control_uniforms(self, key: Tensor, step: Tensor, num_targets: int, dtype: torch.dtype) -> Tensor | None:
        """``[B, N, 1, 2]`` the uniforms of the ``random`` control the model assumes this step (one per target,
        shared by its sigma points or particles), or None when the model takes none."""
        if not self.model.random_controls:
            return None
        u = rng.uniform(key, step, rng.WorldStream.CONTROL, 2 * num_targets, dtype)
        return u.unflatten(-1, (num_targets, 1, 2))


class GaussianFilter(BeliefFilter):
    """A filter whose whole belief is a mean and a covariance: a step is :meth:`predict`, the det cap and the
    clipping, then :meth:`update` of the observed targets."""

    def step(self, state: dict[str, Tensor], measurement: Tensor, observed: Tensor, pose: Tensor, key: Tensor,
             step: Tensor) -> dict[str, Tensor]:
        """Predict every belief, then update the ``observed [B, N]`` ones with ``measurement [B, N, 2]`` taken
        from ``pose [B, 3]`` (SPEC 5 order)."""
        prior_cov = state["belief_cov"]
        mean, cov = self.predict(state["belief_mean"], prior_cov, key, step)
        cov = belief.cap_det(prior_cov, cov, self.log_det_cap)
        mean = self.clip(mean)
        mean_post, cov_post = self.update(mean, cov, measurement, pose)
        mean = torch.where(observed[..., None], self.clip(mean_post), mean)
        cov = torch.where(observed[..., None, None], cov_post, cov)
        return {"belief_mean": mean, "belief_cov": cov}

    @abstractmethod
    def predict(self, mean: Tensor, cov: Tensor, key: Tensor, step: Tensor) -> tuple[Tensor, Tensor]:
        """The predicted ``(mean, cov)`` of every belief."""

    @abstractmethod
    def update(self, mean: Tensor, cov: Tensor, measurement: Tensor, pose: Tensor) -> tuple[Tensor, Tensor]:
        """The updated ``(mean, cov)`` of every belief as if all were observed (the caller keeps the others)."""
