"""``particle``: a bootstrap particle filter, ``K`` weighted particles per target, batched over worlds.

A step moves every particle by the filter's :class:`~aia.envs.belief_models.BeliefModel` plus a draw of its
process noise ``N(0, Q)``; an observed target's weights are multiplied by the range-bearing likelihood of its
measurement (Gaussian, bearing residual wrapped) and normalised. Where the effective sample size
``1 / sum w^2`` falls below ``resample_threshold * K``, the particles are resampled systematically (one
uniform per target) and roughened against collapse (Gordon, Salmond and Smith 1993): each entry jittered by
``roughening * E_j * K^(-1/d)`` times a zero-mean, unit-variance draw, with ``E_j`` the spread (max - min) of
entry ``j`` over the particles before resampling (the heading's relative to the first particle). The jitter
is uniform on ``[-sqrt(3), sqrt(3)]``, not Gaussian: the kernel only needs its scale, and without its Box-Muller
normals (and the circular mean the spread needed) K = 256 steps 4,096 worlds in 79 ms compiled instead of 119.
The Gaussian summary the features, reward and score read is the weighted mean (circular in the heading) and
the weighted covariance ``sum_k w_k r_k r_k^T`` of the particles. Every draw comes from the world's
counter-based streams (:mod:`aia.rng`), so a world's beliefs do not depend on the batch. The det cap and the
2019 clipping do not apply (clipped particles pile up on the bound and their covariance loses rank); headings
are wrapped.
"""

from __future__ import annotations

import math

import torch
from torch import Tensor
from torchrl.data import TensorSpec, Unbounded

from aia import rng
from aia.envs import belief
from aia.envs.belief_models import BeliefModel
from aia.envs.filters.base import BeliefFilter, wrap_entry
from aia.envs.filters.unscented import residual, weighted_mean, weighted_outer


class ParticleFilter(BeliefFilter):
    """``particles`` per target, resampled below ``resample_threshold * K`` effective particles, roughened by
    ``roughening`` (see the module docstring)."""

    def __init__(self, model: BeliefModel, meas_noise: Tensor, num_targets: int, particles: int = 256,
                 resample_threshold: float = 0.5, roughening: float = 0.2, **kwargs) -> None:
        super().__init__(model, meas_noise, **kwargs)
        self.num_targets, self.particles = num_targets, particles
        self.resample_threshold, self.roughening = resample_threshold, roughening
        self.noise_chol = torch.linalg.cholesky(model.noise.double()).to(model.noise)
        self.meas_precision = 1.0 / torch.diagonal(meas_noise)
        d, device = model.dim, meas_noise.device
        self._draws = num_targets * particles * d
        self._noise_slots = rng.slot_keys(2 * math.ceil(self._draws / 2), device)
        self._rough_slots = rng.slot_keys(self._draws, device)
        self._resample_slots = rng.slot_keys(num_targets, device)
        self._offsets = torch.arange(particles, device=device, dtype=meas_noise.dtype) / particles

    def extra_specs(self, batch: int, num_targets: int, dtype: torch.dtype,
                    device: torch.device) -> dict[str, TensorSpec]:
        shape = (batch, num_targets, self.particles)
        return {"belief_particles": Unbounded(shape=(*shape, self.dim), dtype=dtype, device=device),
                "belief_weights": Unbounded(shape=shape, dtype=dtype, device=device)}

    def initial(self, mean: Tensor, init_cov: float, key: Tensor, step: Tensor) -> dict[str, Tensor]:
        B, N, K, d = *mean.shape[:2], self.particles, self.dim
        normals = rng.normal(key, step, rng.WorldStream.PARTICLE, self._draws, mean.dtype, self._noise_slots)
        particles = self.clip(mean.unsqueeze(-2) + math.sqrt(init_cov) * normals.reshape(B, N, K, d))
        weights = torch.full((B, N, K), 1.0 / K, dtype=mean.dtype, device=mean.device)
        return self._summary(particles, weights)

    def step(self, state: dict[str, Tensor], measurement: Tensor, observed: Tensor, pose: Tensor, key: Tensor,
             step: Tensor) -> dict[str, Tensor]:
        particles, weights = state["belief_particles"], state["belief_weights"]
        B, N, K, d = particles.shape
        process = rng.normal(key, step, rng.WorldStream.PARTICLE, self._draws, particles.dtype,
                             self._noise_slots).reshape(B, N, K, d)
        rough = rng.uniform(key, step, rng.WorldStream.ROUGHENING, self._draws, particles.dtype,
                            self._rough_slots).reshape(B, N, K, d)
        particles = self.model.propagate(particles, self.control_uniforms(key, step, N, particles.dtype))
        particles = particles + belief.bmm(process.unsqueeze(-2), self.noise_chol.mT).squeeze(-2)

        # Weights: the measurement's likelihood under each particle, for the observed targets.
        predicted = belief.range_bearing(particles[..., :2], pose[:, None, None, :])
        error = residual(measurement.unsqueeze(-2), predicted, 1)
        log_likelihood = -0.5 * (error.square() * self.meas_precision).sum(-1)
        log_weights = torch.log(weights) + log_likelihood
        updated = torch.softmax(log_weights, dim=-1)
        weights = torch.where(observed[..., None], updated, weights)

        # Systematic resampling where the effective sample size is low, then roughening.
        low = 1.0 / weights.square().sum(-1) < self.resample_threshold * K
        start = rng.uniform(key, step, rng.WorldStream.RESAMPLE, N, particles.dtype, self._resample_slots)
        positions = (start.unsqueeze(-1) / K + self._offsets).contiguous()
        cumulative = torch.cumsum(weights, -1).contiguous()
        index = torch.searchsorted(cumulative, positions).clamp_max(K - 1)
        chosen = torch.gather(particles, -2, index.unsqueeze(-1).expand(B, N, K, d))
        # The spread is taken before resampling: after a collapse onto few particles the resampled set has
        # next to none, and the roughening is what gives it back. Max - min needs no centre but the heading's
        # wrap: relative to the first particle.
        spread = residual(particles, particles[..., :1, :], self.model.angle)
        extent = spread.amax(-2) - spread.amin(-2)
        jitter = (2.0 * rough - 1.0) * math.sqrt(3.0)
        chosen = chosen + jitter * (self.roughening * extent * K ** (-1.0 / d)).unsqueeze(-2)
        particles = torch.where(low[..., None, None], chosen, particles)
        weights = torch.where(low[..., None], torch.full_like(weights, 1.0 / K), weights)
        return self._summary(self.clip(particles), weights)

    def clip(self, mean: Tensor) -> Tensor:
        """Headings wrapped; no other clipping (see the module docstring)."""
        return wrap_entry(mean, self.model.angle)

    def _summary(self, particles: Tensor, weights: Tensor) -> dict[str, Tensor]:
        """The state with its Gaussian summary: weighted mean and covariance of the particles."""
        mean = weighted_mean(particles, weights, self.model.angle)
        spread = residual(particles, mean.unsqueeze(-2), self.model.angle)
        cov = weighted_outer(spread, spread, weights)
        return {"belief_mean": mean, "belief_cov": 0.5 * (cov + cov.mT), "belief_particles": particles,
                "belief_weights": weights}
