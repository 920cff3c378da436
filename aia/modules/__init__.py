"""Learned policies' building blocks: Q-networks, the Q-value actor and exploration modules."""

from aia.modules.exploration import (
    ALGORITHMS,
    EXPLORATIONS,
    EpsilonGreedy,
    LinearEpsilon,
    ThompsonSampling,
    check_exploration,
)
from aia.modules.q_networks import ADFQNetwork, make_q_network, make_qvalue_actor

__all__ = [
    "ALGORITHMS",
    "EXPLORATIONS",
    "ADFQNetwork",
    "EpsilonGreedy",
    "LinearEpsilon",
    "ThompsonSampling",
    "check_exploration",
    "make_q_network",
    "make_qvalue_actor",
]
