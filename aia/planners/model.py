"""What the planner knows of a setting (the env's own motion, filter and sensor model) and the filter's
covariance step of a tree node's children."""

from __future__ import annotations

import math
from typing import NamedTuple

import torch
from torch import Tensor

from aia.config.checks import require
from aia.envs import belief
from aia.envs.filters import KalmanFilter
from aia.envs.sensing import Geometry
from aia.envs.tracking import TargetTrackingEnv


class TrackingModel(NamedTuple):
    """What the planner knows of a setting: the env's own motion, filter and sensor model (float64)."""

    primitives: Tensor  # [A, 2] (v, w)
    dt: float
    transition: Tensor  # [4, 4] A
    process_noise: Tensor  # [4, 4] W of the belief
    meas_noise: Tensor  # [2, 2] V
    log_det_cap: float  # the env's det cap (inf: none)
    geometry: Geometry  # collision and the sensing rule (range, field of view, line of sight); a map per world
    # when the env's worlds each have their own (WorldMapGeometry), the plans of a world on its map

    @classmethod
    def from_env(cls, env: TargetTrackingEnv) -> TrackingModel:
        """The model of ``env`` (its very tensors, cast to float64; its geometry, whose per-world maps a reset
        replaces in place). ARVI plans with the Kalman filter's linear-Gaussian model: a setting whose beliefs
        another filter keeps is refused in one line."""
        cfg, f64, kf = env.config, torch.float64, env.belief_filter
        require(isinstance(kf, KalmanFilter), "env.belief.filter", cfg.belief.filter,
                "kf (ARVI plans with the Kalman filter's linear-Gaussian model; use a learned or heuristic "
                "policy on this setting)")
        return cls(env.primitives.to(f64), cfg.dt, kf.transition.to(f64), kf.model.noise.to(f64),
                   env.meas_noise.to(f64), kf.log_det_cap, env.geometry)


def visible_targets(geometry: Geometry, pose: Tensor, positions: Tensor, min_range: float = 0.0) -> Tensor:
    """``[..., N]`` whether each target position ``[..., N, 2]`` is seen from ``pose [..., 3]``: the env's
    sensing rule (:meth:`Geometry.in_view`, SPEC 4), and at least ``min_range`` away."""
    visible, polar = geometry.in_view(pose, positions)
    return visible & (polar[..., 0] >= min_range) if min_range > 0 else visible


def predict_cov(model: TrackingModel, cov: Tensor, logdet: Tensor) -> tuple[Tensor, Tensor]:
    """The env's covariance prediction ``A Sigma A^T + W`` with its det cap (the rule of
    :func:`belief.cap_det`: keep ``cov`` where the prediction reaches the cap), and the result's log det.
    ``logdet [...]`` is that of ``cov [..., 4, 4]``, reused where the cap keeps it. The products use
    ``torch.matmul`` (see :func:`update_cov`)."""
    predicted = model.transition @ cov @ model.transition.mT + model.process_noise
    predicted_logdet = belief.logdet(predicted)
    if not math.isfinite(model.log_det_cap):
        return predicted, predicted_logdet
    keep = predicted_logdet >= model.log_det_cap
    return torch.where(keep[..., None, None], cov, predicted), torch.where(keep, logdet, predicted_logdet)


def update_visible(model: TrackingModel, predicted: Tensor, logdet: Tensor, pose: Tensor, positions: Tensor,
                   visible: Tensor) -> tuple[Tensor, Tensor]:
    """Kalman covariance update of the ``visible [M, N]`` targets only, the Jacobian taken at ``positions
    [M, N, 2]`` seen from ``pose [M, 3]``; the others keep their ``predicted [M, N, 4, 4]`` covariance and
    its ``logdet [M, N]``. Returns the covariances and their log dets (both new tensors)."""
    node, target = visible.nonzero(as_tuple=True)
    jacobian = belief.measurement_jacobian(positions[node, target], pose.index_select(0, node))
    updated = update_cov(predicted[node, target], jacobian, model.meas_noise)
    cov = predicted.index_put((node, target), updated)
    return cov, logdet.index_put((node, target), belief.logdet(updated))


def update_cov(cov: Tensor, jacobian: Tensor, meas_noise: Tensor) -> Tensor:
    """:func:`belief.update_cov` (Joseph form, closed-form 2x2 inverse) with ``torch.matmul`` for the
    products, as :func:`predict_cov`: for the planner's eager float64 blocks faster than :func:`belief.bmm`
    (which the env's compiled step fuses). Measured 2026-12-02 (cProfile, small3, 50 worlds, 5,000 nodes per
    world, one thread): the covariance update of one call 0.98 s -> 0.24 s, the call 4.1 s -> 3.6 s; the
    plans stay bit for bit those of :func:`belief.update_cov` (``tests/planners/test_plans.py``)."""
    cov_ht = cov @ jacobian.mT
    innovation = jacobian @ cov_ht + meas_noise
    a, b, c, d = innovation[..., 0, 0], innovation[..., 0, 1], innovation[..., 1, 0], innovation[..., 1, 1]
    inverse = torch.stack((torch.stack((d, -b), -1), torch.stack((-c, a), -1)), -2) / (a * d - b * c)[
        ..., None, None
    ]
    gain = cov_ht @ inverse
    reduce = torch.eye(cov.shape[-1], dtype=cov.dtype, device=cov.device) - gain @ jacobian
    updated = reduce @ cov @ reduce.mT + gain @ meas_noise @ gain.mT
    return 0.5 * (updated + updated.mT)
