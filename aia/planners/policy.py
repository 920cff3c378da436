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
    its plan. ``last`` holds the most recent :class:`PlanResult`.
    """

    in_keys = ["robot_pose", "belief_mean", "belief_cov", "step_count"]
    out_keys = ["action"]

    def __init__(self, env: TargetTrackingEnv, config: ARVIConfig | None = None) -> None:
        super().__init__()
        self.planner = ARVIPlanner(getattr(env, "base_env", env), config)
        self.replan_every = self.planner.config.replan_every
        self.plans: Tensor | None = None
        self.last: PlanResult | None = None

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
            self.last = self.planner.plan(tensordict.get("robot_pose")[worlds], tensordict.get("belief_mean")[worlds],
                                          tensordict.get("belief_cov")[worlds])
            # A plan made mid-cycle starts at the current phase, so it lasts until the next re-planning step.
            shift = phase[worlds]
            index = (torch.arange(self.plans.shape[1], device=step.device) - shift[:, None]) % self.plans.shape[1]
            self.plans[worlds] = self.last.actions.gather(1, index)
        return tensordict.set("action", self.plans[torch.arange(step.numel(), device=step.device), phase])
