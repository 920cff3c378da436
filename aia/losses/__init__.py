"""Losses and targets for deep Q-learning (ADFQ posterior and loss)."""

from aia.losses.adfq import ADFQLoss, adfq_posterior

__all__ = ["ADFQLoss", "adfq_posterior"]
