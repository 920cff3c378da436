"""Belief filters (``env.belief.filter``) behind one interface, :class:`BeliefFilter`."""

from aia.envs.config import FILTER_NAMES
from aia.envs.filters.base import BeliefFilter, GaussianFilter
from aia.envs.filters.kalman import KalmanFilter
from aia.envs.filters.particle import ParticleFilter
from aia.envs.filters.unscented import UnscentedKalmanFilter

FILTERS = dict(zip(FILTER_NAMES, (KalmanFilter, UnscentedKalmanFilter, ParticleFilter), strict=True))

__all__ = ["FILTERS", "BeliefFilter", "GaussianFilter", "KalmanFilter", "ParticleFilter", "UnscentedKalmanFilter"]
