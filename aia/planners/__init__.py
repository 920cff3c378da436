"""Search-based planners: ARVI (anytime reduced value iteration, SPEC 10) and the policy that runs it.

One idea a module: ``config`` (parameters), ``model`` (the env's filter and sensor model, the covariance
step of a node's children), ``tree`` (levels of nodes, expansion), ``pruning`` (greedy suppression over
close pairs), ``search`` (the anytime schedule, :class:`ARVIPlanner`), ``policy`` (:class:`ARVIPolicy`).
The planner's names load on first use: the apps validate its config (:mod:`aia.planners.config`) without torch.
"""

from typing import TYPE_CHECKING

from aia.planners.config import ARVIConfig, to_arvi_config
from aia.runtime.lazy import lazy_names

if TYPE_CHECKING:
    from aia.planners.policy import ARVIPolicy
    from aia.planners.search import ARVIPlanner, PlanResult

# the planner and its policy import torch
__getattr__ = lazy_names(__name__, {"ARVIPolicy": "aia.planners.policy", "ARVIPlanner": "aia.planners.search",
                                    "PlanResult": "aia.planners.search"})

__all__ = ["ARVIConfig", "ARVIPlanner", "ARVIPolicy", "PlanResult", "to_arvi_config"]
