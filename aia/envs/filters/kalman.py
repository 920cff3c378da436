"""``kf``: the extended Kalman filter of SPEC 5 over the linear double-integrator model."""

from __future__ import annotations

from torch import Tensor

from aia.envs import belief
from aia.envs.filters.base import GaussianFilter


class KalmanFilter(GaussianFilter):
    """Linear prediction ``A mu, A Sigma A^T + W`` and the EKF range-bearing update (:mod:`aia.envs.belief`,
    the covariance step ARVI plans with). Needs a linear model (``double_integrator``)."""

    @property
    def transition(self) -> Tensor:
        """``[4, 4]`` the model's ``A``."""
        return self.model.transition

    def predict(self, mean: Tensor, cov: Tensor, key: Tensor, step: Tensor) -> tuple[Tensor, Tensor]:
        return belief.predict(mean, cov, self.model.transition, self.model.noise)

    def update(self, mean: Tensor, cov: Tensor, measurement: Tensor, pose: Tensor) -> tuple[Tensor, Tensor]:
        return belief.update(mean, cov, measurement, pose[:, None, :], self.meas_noise)
