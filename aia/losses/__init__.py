"""Losses and targets for deep Q-learning (ADFQ posterior)."""

from aia.losses.adfq import adfq_posterior

__all__ = ["adfq_posterior"]
