"""Learned policies' building blocks: Q-networks, the Q-value actor, exploration modules and
the members' stacked networks, the population policy and the evaluation snapshots."""

from aia.modules.exploration import (
    ALGORITHMS,
    EXPLORATIONS,
    EpsilonGreedy,
    LinearEpsilon,
    check_exploration,
    exploring,
)
from aia.modules.population_acting import PopulationQPolicy
from aia.modules.q_networks import ADFQNetwork, ConvQNetwork, ConvTorso, make_q_network, make_qvalue_actor
from aia.modules.snapshots import SnapshotPolicy, parameter_snapshot
from aia.modules.stacked import StackedConvQNetwork, StackedQNetwork

__all__ = [
    "ALGORITHMS",
    "EXPLORATIONS",
    "ADFQNetwork",
    "ConvQNetwork",
    "ConvTorso",
    "EpsilonGreedy",
    "LinearEpsilon",
    "PopulationQPolicy",
    "SnapshotPolicy",
    "StackedConvQNetwork",
    "StackedQNetwork",
    "check_exploration",
    "exploring",
    "make_q_network",
    "make_qvalue_actor",
    "parameter_snapshot",
]
