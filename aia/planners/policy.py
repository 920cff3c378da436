"""ARVI as a TensorDict policy: re-plans every ``replan_every`` steps and executes that many actions."""

from __future__ import annotations

import torch
from tensordict import TensorDictBase
from tensordict.nn import TensorDictModuleBase
from torch import Tensor

from aia.envs.tracking import TargetTrackingEnv
from aia.planners.config import ARVIConfig
from aia.planners.search import ARVIPlanner, PlanResult


class ARVIPolicy(TensorDictModuleBase):
    """ARVI as a TensorDict policy for :class:`~aia.envs.TargetTrackingEnv` rollouts.

    Reads the belief (``robot_pose``, ``belief_mean``, ``belief_cov``, never ``target_state``) and
    ``step_count`` (from TorchRL's ``StepCounter`` transform); every world re-plans when its step count is
    a multiple of ``replan_every`` (so at every reset) and executes the first ``replan_every`` actions of
    its plan. ``groups [B]`` (optional) gives each world of the env a budget group (integer labels): the
    worlds of a group plan as if alone under a node or pass budget (:meth:`ARVIPlanner.plan_groups`), so one
    policy can play several seeds' episodes at once. ``last`` holds the most recent plans, a
    :class:`PlanResult` per budget group of the worlds that re-planned.
    """

    in_keys = ["robot_pose", "belief_mean", "belief_cov", "step_count"]
    out_keys = ["action"]

    def __init__(self, env: TargetTrackingEnv, config: ARVIConfig | None = None, groups: Tensor | None = None
                 ) -> None:
        super().__init__()
        self.planner = ARVIPlanner(getattr(env, "base_env", env), config)
        self.replan_every = self.planner.config.replan_every
        self.groups = groups
        self.plans: Tensor | None = None
        self.last: list[PlanResult] = []

    def forward(self, tensordict: TensorDictBase) -> TensorDictBase:
        if "step_count" not in tensordict:
            raise KeyError("ARVIPolicy needs 'step_count' to re-plan every replan_every steps: append "
                           "torchrl.envs.StepCounter() to the env")
        step = tensordict.get("step_count").reshape(-1)
        phase = step % self.replan_every
        if self.plans is None or self.plans.shape[0] != step.numel():
            self.plans = torch.zeros(step.numel(), self.planner.config.horizon, dtype=torch.long, device=step.device)
            replan = torch.ones_like(step, dtype=torch.bool)
        else:
            replan = phase == 0
        worlds = replan.nonzero().squeeze(-1)
        if worlds.numel():
            state = (tensordict.get(key)[worlds] for key in ("robot_pose", "belief_mean", "belief_cov"))
            actions = self._plan(worlds, *state)
            # A plan made mid-cycle starts at the current phase, so it lasts until the next re-planning step.
            shift = phase[worlds]
            index = (torch.arange(self.plans.shape[1], device=step.device) - shift[:, None]) % self.plans.shape[1]
            self.plans[worlds] = actions.gather(1, index)
        return tensordict.set("action", self.plans[torch.arange(step.numel(), device=step.device), phase])

    def _plan(self, worlds: Tensor, pose: Tensor, mean: Tensor, cov: Tensor) -> Tensor:
        """The ``[len(worlds), T]`` plans of ``worlds`` (one call, by budget group); kept in ``last``."""
        if self.groups is None:
            self.last = [self.planner.plan(pose, mean, cov, worlds)]
            return self.last[0].actions
        if self.groups.shape != (self.plans.shape[0],):
            raise ValueError(f"groups has shape {list(self.groups.shape)}, the env {self.plans.shape[0]} worlds")
        _, groups = torch.unique(self.groups.to(worlds.device)[worlds], return_inverse=True)
        self.last = self.planner.plan_groups(pose, mean, cov, groups, worlds)
        actions = torch.empty(worlds.numel(), self.plans.shape[1], dtype=torch.long, device=worlds.device)
        for group, result in enumerate(self.last):
            actions[groups == group] = result.actions
        return actions
