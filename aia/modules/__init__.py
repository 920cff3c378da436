"""Learned policies' building blocks: Q-networks, the Q-value actor, exploration modules and
the evaluation snapshots."""

from aia.modules.acting import ExploringQPolicy
from aia.modules.exploration import (
    ALGORITHMS,
    EXPLORATIONS,
    EpsilonGreedy,
    LinearEpsilon,
    ThompsonSampling,
    check_exploration,
    exploring,
)
from aia.modules.q_networks import ADFQNetwork, make_q_network, make_qvalue_actor
from aia.modules.snapshots import SnapshotPolicy, parameter_snapshot

__all__ = [
    "ALGORITHMS",
    "EXPLORATIONS",
    "ADFQNetwork",
    "EpsilonGreedy",
    "ExploringQPolicy",
    "LinearEpsilon",
    "SnapshotPolicy",
    "ThompsonSampling",
    "check_exploration",
    "exploring",
    "make_q_network",
    "make_qvalue_actor",
    "parameter_snapshot",
]
