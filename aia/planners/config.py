"""The planner's parameters (``conf/planner/arvi.yaml``), checked when the planner is built."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Optional

from omegaconf import DictConfig, OmegaConf
from omegaconf.errors import OmegaConfBaseException


@dataclass
class ARVIConfig:
    """Parameters of the planner; defaults are the reference's (SPEC 10, issue 6)."""

    # Search depth T in steps.
    horizon: int = 12
    # Pruning radius of the first pass after the greedy chain, and its decrease per pass.
    delta0: float = 3.0
    delta_step: float = 0.05
    # Covariance redundancy tolerance; inf prunes on distance alone.
    eps: float = math.inf
    # Node distance sqrt(dx^2 + dy^2 + distance_offset): 1 is the reference's convention (delta < 1 prunes
    # nothing, delta = 3 is 2 sqrt(2) m in the plane); 0 gives the planar distance.
    distance_offset: float = 1.0
    # Budgets: planning stops at the first one reached (null disables it; at least one must be set).
    time_budget: Optional[float] = 1.0  # wall-clock seconds per call
    max_passes: Optional[int] = None  # passes after the greedy chain
    max_nodes: Optional[int] = None  # nodes generated, per world
    # The policy re-plans every replan_every steps and executes that many planned actions.
    replan_every: int = 5
    # Points checked for collision along each primitive's arc (evenly spaced in time, the end included).
    arc_checks: int = 4
    # The planner counts on a measurement of a predicted target only from this distance on (m). 0 is the
    # sensing rule as written (SPEC 4); then the bearing's information, which grows as 1/r^2, draws the
    # plan onto the belief mean itself, where the robot can sit blind to a target a few metres away
    # (docs/planner.md, "Minimum planning range").
    min_range: float = 0.0

    def __post_init__(self) -> None:
        validate(self)


def validate(cfg: ARVIConfig) -> None:
    """Raise ``ValueError`` naming the first parameter outside its allowed range."""
    for name in ("horizon", "replan_every", "arc_checks"):
        value = getattr(cfg, name)
        if not (isinstance(value, int) and value >= 1):
            raise ValueError(f"planner.{name}={value!r} must be an integer >= 1")
    for name in ("delta0", "delta_step"):
        if not getattr(cfg, name) > 0:
            raise ValueError(f"planner.{name}={getattr(cfg, name)!r} must be > 0")
    for name in ("eps", "distance_offset", "min_range"):
        if not getattr(cfg, name) >= 0:
            raise ValueError(f"planner.{name}={getattr(cfg, name)!r} must be >= 0 (eps may be inf)")
    if cfg.replan_every > cfg.horizon:
        raise ValueError(f"planner.replan_every={cfg.replan_every} must be <= planner.horizon={cfg.horizon}")
    budgets = {"time_budget": cfg.time_budget, "max_passes": cfg.max_passes, "max_nodes": cfg.max_nodes}
    for name, value in budgets.items():
        if value is not None and not value >= 0:
            raise ValueError(f"planner.{name}={value!r} must be >= 0 or null")
    if all(value is None for value in budgets.values()):
        raise ValueError(f"planner: set at least one of {list(budgets)} (all are null: the search would not stop)")


def to_arvi_config(cfg: DictConfig | ARVIConfig) -> ARVIConfig:
    """A validated :class:`ARVIConfig` from a composed ``planner`` node (a misspelt field is named)."""
    if isinstance(cfg, ARVIConfig):
        return cfg
    try:
        return OmegaConf.to_object(OmegaConf.merge(OmegaConf.structured(ARVIConfig), cfg))
    except OmegaConfBaseException as err:
        raise ValueError(f"invalid planner config: {err}") from None
