"""``ukf``: the unscented Kalman filter, batched, with angle-aware means and residuals.

Sigma points as ttenv's code chooses them (filterpy's ``JulierSigmaPoints(n, kappa)``): the mean and the
mean plus and minus each column of the Cholesky factor of ``(n + kappa) Sigma``, weights
``kappa / (n + kappa)`` and ``1 / (2 (n + kappa))``. The heading entry of a state and the bearing of a
measurement are averaged on the circle (``atan2`` of the weighted sines and cosines) and their residuals
wrapped to [-pi, pi). The update regenerates the sigma points from the predicted mean and covariance (as
filterpy's ``predict`` does at its end), so a step is a function of the belief alone: nothing is carried
from one episode to the next. An update that would leave a covariance that is not positive definite is
not applied (the predicted belief is kept). ``tests/envs/filters`` checks it against filterpy to 1e-6 in float64.
"""

from __future__ import annotations

import torch
from torch import Tensor

from aia.envs import belief
from aia.envs.belief_models import BeliefModel
from aia.envs.filters.base import GaussianFilter, wrap_entry


class UnscentedKalmanFilter(GaussianFilter):
    """The UKF over any :class:`~aia.envs.belief_models.BeliefModel`; ``kappa`` scales the sigma points."""

    def __init__(self, model: BeliefModel, meas_noise: Tensor, kappa: float = 1.0, **kwargs) -> None:
        super().__init__(model, meas_noise, **kwargs)
        self.kappa = kappa
        self.weights = sigma_weights(model.dim, kappa, meas_noise.dtype).to(meas_noise.device)

    def predict(self, mean: Tensor, cov: Tensor, key: Tensor, step: Tensor) -> tuple[Tensor, Tensor]:
        uniforms = self.control_uniforms(key, step, mean.shape[-2], mean.dtype)
        points = self.model.propagate(sigma_points(mean, cov, self.kappa), uniforms)
        predicted = weighted_mean(points, self.weights, self.model.angle)
        spread = residual(points, predicted.unsqueeze(-2), self.model.angle)
        return predicted, weighted_outer(spread, spread, self.weights) + self.model.noise

    def update(self, mean: Tensor, cov: Tensor, measurement: Tensor, pose: Tensor) -> tuple[Tensor, Tensor]:
        points = sigma_points(mean, cov, self.kappa)
        predicted_z = belief.range_bearing(points[..., :2], pose[:, None, None, :])
        z_mean = weighted_mean(predicted_z, self.weights, 1)
        dz = residual(predicted_z, z_mean.unsqueeze(-2), 1)
        dx = residual(points, mean.unsqueeze(-2), self.model.angle)
        innovation = weighted_outer(dz, dz, self.weights) + self.meas_noise
        gain = belief.bmm(weighted_outer(dx, dz, self.weights), belief.inverse2(innovation))
        error = residual(measurement, z_mean, 1)
        mean_post = mean + belief.bmm(gain, error.unsqueeze(-1)).squeeze(-1)
        cov_post = cov - belief.bmm(belief.bmm(gain, innovation), gain.mT)
        cov_post = 0.5 * (cov_post + cov_post.mT)
        # Guard: where the update leaves a covariance that is not positive definite (a strongly nonlinear
        # measurement of a wide belief can; filterpy then fails in its next Cholesky), the measurement is
        # not used and the predicted belief is kept.
        valid = torch.linalg.cholesky_ex(cov_post)[1] == 0
        return (torch.where(valid[..., None], mean_post, mean),
                torch.where(valid[..., None, None], cov_post, cov))


def sigma_weights(n: int, kappa: float, dtype: torch.dtype = torch.float64) -> Tensor:
    """``[2n + 1]`` Julier's weights (the same for the mean and the covariance)."""
    weights = torch.full((2 * n + 1,), 0.5 / (n + kappa), dtype=dtype)
    weights[0] = kappa / (n + kappa)
    return weights


def sigma_points(mean: Tensor, cov: Tensor, kappa: float) -> Tensor:
    """``[..., 2n + 1, n]``: ``mean``, then ``mean + L[:, k]`` for each k, then ``mean - L[:, k]``, with
    ``L L^T = (n + kappa) cov``."""
    n = mean.shape[-1]
    chol, _ = torch.linalg.cholesky_ex((n + kappa) * cov)
    columns = chol.mT
    centre = mean.unsqueeze(-2)
    return torch.cat((centre, centre + columns, centre - columns), -2)


def weighted_mean(points: Tensor, weights: Tensor, angle: int | None, dim: int = -2) -> Tensor:
    """``[..., n]`` the weighted mean of ``points [..., P, n]`` (``dim=-1``: entries first, ``[..., n, P]``),
    circular in entry ``angle``; ``weights`` ``[P]`` or ``[..., P]``."""
    entry_dim = -1 if dim == -2 else -2
    mean = (weights.unsqueeze(entry_dim) * points).sum(dim)
    if angle is None:
        return mean
    heading = points.select(entry_dim, angle)
    heading = torch.atan2((weights * torch.sin(heading)).sum(-1), (weights * torch.cos(heading)).sum(-1))
    return torch.cat((mean[..., :angle], heading.unsqueeze(-1), mean[..., angle + 1:]), -1)


def residual(a: Tensor, b: Tensor, angle: int | None) -> Tensor:
    """``a - b`` with entry ``angle`` wrapped to [-pi, pi)."""
    return wrap_entry(a - b, angle)


def weighted_outer(a: Tensor, b: Tensor, weights: Tensor) -> Tensor:
    """``[..., n, m]`` ``sum_k w_k a_k b_k^T`` of ``a [..., P, n]`` and ``b [..., P, m]``, ``weights`` ``[P]`` or
    ``[..., P]``.

    A batched matmul, not a broadcast multiply-and-sum: compiled, the sum let inductor recompute the sigma
    points' unicycle move inside every entry's reduction, and the 5-state UKF stepped 4,096 worlds in 65 ms
    against 16 ms this way (and 19.8 ms eager).
    """
    return (weights.unsqueeze(-1) * a).mT @ b

