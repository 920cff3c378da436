"""Belief filters (``env.belief.filter``) behind one interface, :class:`BeliefFilter`."""

from aia.envs.filters.base import BeliefFilter
from aia.envs.filters.kalman import KalmanFilter
from aia.envs.filters.unscented import UnscentedKalmanFilter

FILTERS = {"kf": KalmanFilter, "ukf": UnscentedKalmanFilter}

__all__ = ["FILTERS", "BeliefFilter", "KalmanFilter", "UnscentedKalmanFilter"]
