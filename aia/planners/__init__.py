"""Search-based planners: ARVI (anytime reduced value iteration, SPEC 10) and the policy that runs it.

One idea a module: ``config`` (parameters), ``model`` (the env's filter and sensor model, the covariance
step of a node's children), ``tree`` (levels of nodes, expansion), ``pruning`` (greedy suppression over
close pairs), ``search`` (the anytime schedule, :class:`ARVIPlanner`), ``policy`` (:class:`ARVIPolicy`).
"""

from aia.planners.config import ARVIConfig, to_arvi_config
from aia.planners.policy import ARVIPolicy
from aia.planners.search import ARVIPlanner, PlanResult

__all__ = ["ARVIConfig", "ARVIPlanner", "ARVIPolicy", "PlanResult", "to_arvi_config"]
