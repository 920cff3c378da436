"""Search-based planners: ARVI (anytime reduced value iteration) and the policy that runs it in the env."""

from aia.planners.arvi import ARVIConfig, ARVIPlanner, ARVIPolicy, PlanResult, to_arvi_config

__all__ = ["ARVIConfig", "ARVIPlanner", "ARVIPolicy", "PlanResult", "to_arvi_config"]
