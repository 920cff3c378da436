"""Scripted policies that act on the tracking env's tensordicts (baselines and smoke tests)."""

from aia.policies.heuristics import BeliefPursuitPolicy, RandomPolicy

__all__ = ["BeliefPursuitPolicy", "RandomPolicy"]
