"""The planner's parameters (``conf/planner/arvi.yaml``), checked when the planner is built."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Optional

from omegaconf import DictConfig, OmegaConf
from omegaconf.errors import OmegaConfBaseException

from aia.config.checks import Number
from aia.config.composing import node_error
from aia.config.errors import ConfigError
from aia.config.schemas import setting, settings

# The ranges of the counts, and of the budgets (null disables one).
_COUNT = Number(ge=1, integer=True)
_BUDGET_COUNT = Number(ge=0, integer=True, optional=True)


@dataclass
class ARVIConfig:
    """Parameters of the planner; defaults are the reference's (SPEC 10, issue 6). Each field declares its range
    (:func:`~aia.config.schemas.setting`), checked when the config is built."""

    # Search depth T in steps.
    horizon: int = setting(12, check=_COUNT)
    # Pruning radius of the first pass after the greedy chain, and its decrease per pass.
    delta0: float = setting(3.0, check=Number(gt=0))
    delta_step: float = setting(0.05, check=Number(gt=0))
    # Covariance redundancy tolerance; inf prunes on distance alone.
    eps: float = setting(math.inf, check=Number(ge=0))
    # Node distance sqrt(dx^2 + dy^2 + distance_offset): 1 is the reference's convention (delta < 1 prunes
    # nothing, delta = 3 is 2 sqrt(2) m in the plane); 0 gives the planar distance.
    distance_offset: float = setting(1.0, check=Number(ge=0))
    # Budgets: planning stops at the first one reached (null disables it; at least one must be set).
    time_budget: Optional[float] = setting(1.0, check=Number(ge=0, optional=True))  # wall-clock seconds per call
    max_passes: Optional[int] = setting(None, check=_BUDGET_COUNT)  # passes after the greedy chain
    max_nodes: Optional[int] = setting(None, check=_BUDGET_COUNT)  # nodes generated, per world
    # The policy re-plans every replan_every steps and executes that many planned actions.
    replan_every: int = setting(5, check=_COUNT)
    # Points checked for collision along each primitive's arc (evenly spaced in time, the end included).
    arc_checks: int = setting(4, check=_COUNT)
    # The planner counts on a measurement of a predicted target only from this distance on (m). 0 is the
    # sensing rule as written (SPEC 4); then the bearing's information, which grows as 1/r^2, draws the
    # plan onto the belief mean itself, where the robot can sit blind to a target a few metres away
    # (docs/planner.md, "Minimum planning range").
    min_range: float = setting(0.0, check=Number(ge=0))

    def __post_init__(self) -> None:
        validate(self)


def validate(cfg: ARVIConfig) -> None:
    """Raise :class:`~aia.config.errors.ConfigError` (a ``ValueError``) naming the first parameter outside its
    declared range, its value and what is allowed, then the rules between parameters."""
    for key, item in settings(ARVIConfig):
        item.metadata["check"](f"planner.{key}", getattr(cfg, key))
    if cfg.replan_every > cfg.horizon:
        raise ConfigError("planner.replan_every", cfg.replan_every,
                          f"at most planner.horizon={cfg.horizon} (a plan is horizon steps long)")
    budgets = ("time_budget", "max_passes", "max_nodes")
    if all(getattr(cfg, name) is None for name in budgets):
        raise ConfigError("planner.time_budget", None,
                          "a number >= 0 while max_passes and max_nodes are null (set at least one budget, or the "
                          "search would not stop)")


def to_arvi_config(cfg: DictConfig | ARVIConfig | dict) -> ARVIConfig:
    """A validated :class:`ARVIConfig` from a composed ``planner`` node; a misspelt field or a value of the wrong
    type is a :class:`~aia.config.errors.ConfigError` naming the field, worded as the apps word them."""
    if isinstance(cfg, ARVIConfig):
        return cfg
    try:
        return OmegaConf.to_object(OmegaConf.merge(OmegaConf.structured(ARVIConfig), cfg))
    except OmegaConfBaseException as err:
        raise node_error(err, cfg, ARVIConfig, "planner.") from None
