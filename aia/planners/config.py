"""The planner's parameters (``conf/planner/arvi.yaml``), checked when the planner is built."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Optional

from omegaconf import DictConfig, OmegaConf
from omegaconf.errors import OmegaConfBaseException

from aia.config.errors import ConfigError


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


# What each parameter accepts, in the words of the apps' other refusals.
ALLOWED = {
    "horizon": "an integer >= 1", "replan_every": "an integer >= 1", "arc_checks": "an integer >= 1",
    "delta0": "a number > 0", "delta_step": "a number > 0",
    "eps": "a number >= 0 (inf: prune on distance alone)", "distance_offset": "a number >= 0",
    "min_range": "a number >= 0 (metres)",
    "time_budget": "a number >= 0 (seconds), or null", "max_passes": "an integer >= 0, or null",
    "max_nodes": "an integer >= 0, or null",
}


def validate(cfg: ARVIConfig) -> None:
    """Raise :class:`~aia.config.errors.ConfigError` (a ``ValueError``) naming the first parameter outside its
    allowed range, its value and what is allowed (:data:`ALLOWED`)."""
    budgets = ("time_budget", "max_passes", "max_nodes")
    for name in ALLOWED:
        value = getattr(cfg, name)
        if name in ("horizon", "replan_every", "arc_checks"):
            valid = isinstance(value, int) and value >= 1
        elif name in budgets:
            valid = value is None or value >= 0
        else:
            valid = value > 0 if name in ("delta0", "delta_step") else value >= 0
        if not valid:
            raise ConfigError(f"planner.{name}", value, ALLOWED[name])
    if cfg.replan_every > cfg.horizon:
        raise ConfigError("planner.replan_every", cfg.replan_every,
                          f"at most planner.horizon={cfg.horizon} (a plan is horizon steps long)")
    if all(getattr(cfg, name) is None for name in budgets):
        raise ConfigError("planner.time_budget", None,
                          "a number >= 0 while max_passes and max_nodes are null (set at least one budget, or the "
                          "search would not stop)")


def to_arvi_config(cfg: DictConfig | ARVIConfig | dict) -> ARVIConfig:
    """A validated :class:`ARVIConfig` from a composed ``planner`` node; a misspelt field or a value of the wrong
    type is a :class:`~aia.config.errors.ConfigError` naming the field."""
    if isinstance(cfg, ARVIConfig):
        return cfg
    try:
        return OmegaConf.to_object(OmegaConf.merge(OmegaConf.structured(ARVIConfig), cfg))
    except OmegaConfBaseException as err:
        key = str(getattr(err, "key", None) or "")
        given = OmegaConf.to_container(OmegaConf.create(cfg))
        if key not in ALLOWED:
            raise ConfigError(f"planner.{key}" if key else "planner", given.get(key, given),
                              f"one of the planner's fields: {', '.join(ALLOWED)}") from None
        raise ConfigError(f"planner.{key}", given[key], ALLOWED[key]) from None
