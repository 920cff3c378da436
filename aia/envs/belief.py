"""The batched extended Kalman filter over target states, with a range-bearing measurement.

Every function works on any leading batch shape (``[B, N]`` worlds x targets in the env, tree nodes in
the planner): the covariance steps here are the single implementation that both use.
"""

from __future__ import annotations

import math

import torch
from torch import Tensor

from aia.envs.dynamics import wrap_angle


def bmm(a: Tensor, b: Tensor) -> Tensor:
    """Batched product of small matrices as a broadcast multiply-and-sum.

    For 2x4 and 4x4 blocks this beats batched GEMM calls (no per-call dispatch of a BLAS kernel), and
    ``torch.compile`` fuses it with the elementwise code around it.
    """
    return (a.unsqueeze(-1) * b.unsqueeze(-3)).sum(-2)


def predict(mean: Tensor, cov: Tensor, transition: Tensor, noise: Tensor) -> tuple[Tensor, Tensor]:
    """Kalman prediction: ``mu' = A mu``, ``Sigma' = A Sigma A^T + W``."""
    return bmm(mean.unsqueeze(-2), transition.mT).squeeze(-2), predict_cov(cov, transition, noise)


def predict_cov(cov: Tensor, transition: Tensor, noise: Tensor) -> Tensor:
    """Covariance half of the prediction: ``A Sigma A^T + W``."""
    return bmm(bmm(transition, cov), transition.mT) + noise


def cap_det(prior: Tensor, predicted: Tensor, log_det_cap: float) -> Tensor:
    """The 2019 code's det cap: keep the ``prior`` covariance where the ``predicted`` one reaches
    ``log det >= log_det_cap`` (``inf``: no cap). The update never raises det, so it is not capped."""
    if not math.isfinite(log_det_cap):
        return predicted
    keep = logdet(predicted) >= log_det_cap
    return torch.where(keep[..., None, None], prior, predicted)


def range_bearing(points: Tensor, pose: Tensor) -> Tensor:
    """``[..., 2]`` range and bearing (wrapped to [-pi, pi)) of 2-D ``points`` seen from ``pose`` (x, y, theta).

    ``pose`` broadcasts against ``points``: pass ``pose[..., None, :]`` for several points per pose.
    """
    delta = points - pose[..., :2]
    distance = torch.linalg.vector_norm(delta, dim=-1)
    bearing = wrap_angle(torch.atan2(delta[..., 1], delta[..., 0]) - pose[..., 2])
    return torch.stack((distance, bearing), dim=-1)


def measurement_jacobian(position: Tensor, pose: Tensor) -> Tensor:
    """``[..., 2, 4]`` Jacobian of (range, bearing) w.r.t. the target state at ``position``.

    ``H = (1/r) [[d1, d2, 0, 0], [-d2/r, d1/r, 0, 0]]`` with ``d = position - robot position``.
    """
    delta = position - pose[..., :2]
    r2 = (delta * delta).sum(-1)
    r = torch.sqrt(r2)
    d1, d2 = delta.unbind(-1)
    zero = torch.zeros_like(r)
    row_range = torch.stack((d1 / r, d2 / r, zero, zero), dim=-1)
    row_bearing = torch.stack((-d2 / r2, d1 / r2, zero, zero), dim=-1)
    return torch.stack((row_range, row_bearing), dim=-2)


def update_cov(cov: Tensor, jacobian: Tensor, meas_noise: Tensor) -> tuple[Tensor, Tensor]:
    """Kalman covariance update in Joseph form; returns ``(Sigma+, K)``.

    ``K = Sigma H^T (H Sigma H^T + V)^-1``; ``Sigma+ = (I - K H) Sigma (I - K H)^T + K V K^T``, which stays
    symmetric positive definite under rounding. The 2x2 innovation covariance is inverted in closed form.
    """
    cov_ht = bmm(cov, jacobian.mT)
    innovation = bmm(jacobian, cov_ht) + meas_noise
    gain = bmm(cov_ht, inverse2(innovation))
    reduce = torch.eye(cov.shape[-1], dtype=cov.dtype, device=cov.device) - bmm(gain, jacobian)
    updated = bmm(bmm(reduce, cov), reduce.mT) + bmm(bmm(gain, meas_noise), gain.mT)
    return 0.5 * (updated + updated.mT), gain


def update(
    mean: Tensor, cov: Tensor, measurement: Tensor, pose: Tensor, meas_noise: Tensor
) -> tuple[Tensor, Tensor]:
    """EKF update of ``(mean, cov)`` with a range-bearing ``measurement`` taken from ``pose``.

    The Jacobian and the predicted measurement are taken at the prior mean; the bearing residual is
    wrapped to [-pi, pi).
    """
    jacobian = measurement_jacobian(mean[..., :2], pose)
    cov_post, gain = update_cov(cov, jacobian, meas_noise)
    residual = measurement - range_bearing(mean[..., :2], pose)
    residual = torch.stack((residual[..., 0], wrap_angle(residual[..., 1])), dim=-1)
    mean_post = mean + bmm(gain, residual.unsqueeze(-1)).squeeze(-1)
    return mean_post, cov_post


def inverse2(matrix: Tensor) -> Tensor:
    """Closed-form inverse of ``[..., 2, 2]`` matrices (the innovation covariances)."""
    a, b, c, d = matrix[..., 0, 0], matrix[..., 0, 1], matrix[..., 1, 0], matrix[..., 1, 1]
    adjugate = torch.stack((torch.stack((d, -b), -1), torch.stack((-c, a), -1)), -2)
    return adjugate / (a * d - b * c)[..., None, None]


def logdet(cov: Tensor) -> Tensor:
    """Log determinant of symmetric positive definite matrices (via Cholesky)."""
    chol, _ = torch.linalg.cholesky_ex(cov)
    return 2.0 * torch.log(torch.diagonal(chol, dim1=-2, dim2=-1)).sum(-1)
