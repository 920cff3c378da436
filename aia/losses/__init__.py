"""Losses and targets for deep Q-learning (ADFQ posterior and loss; DQN and Double DQN members in one population)."""

from aia.losses.adfq import ADFQLoss, adfq_posterior
from aia.losses.double_dqn import MemberwiseDoubleTD0, use_memberwise_double

__all__ = ["ADFQLoss", "MemberwiseDoubleTD0", "adfq_posterior", "use_memberwise_double"]
