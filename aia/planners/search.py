"""The anytime schedule of ARVI (SPEC 10): a greedy chain, then passes over the same tree with ``delta``
shrinking by ``delta_step`` until a budget is spent, and the plan: the path of the lowest-cost leaf.

Passes that provably change nothing (``delta`` has not crossed any pairwise node distance of any level)
are skipped without being run, so the result equals the pass-by-pass schedule; levels whose input did not
change since the previous pass are reused. See ``docs/planner.md``.
"""

from __future__ import annotations

import math
import time
from typing import NamedTuple

import torch
from torch import Tensor

from aia.envs import belief
from aia.envs.tracking import TargetTrackingEnv
from aia.planners.config import ARVIConfig
from aia.planners.model import TrackingModel
from aia.planners.pruning import prune
from aia.planners.tree import Expansion, Level


class PlanResult(NamedTuple):
    """Plans of a batch of worlds."""

    actions: Tensor  # [W, T] primitive indices, first action first
    cost: Tensor  # [W] g of the returned leaf
    nodes: Tensor  # [W] nodes generated (children whose covariance was computed)
    passes: int  # passes of the delta schedule covered after the greedy chain (run, or skipped as changing nothing)
    delta: float  # delta of the last covered pass (inf: greedy chain only)


class ARVIPlanner:
    """ARVI over the motion primitives of an env's setting, for any batch of worlds at once.

    Args:
        env: the (base) tracking env whose model the planner uses: primitives, filter, sensor, map.
        config: search parameters and budgets.
    """

    def __init__(self, env: TargetTrackingEnv, config: ARVIConfig | None = None) -> None:
        self.config = config or ARVIConfig()
        self.model = TrackingModel.from_env(env)
        self.device = env.device
        self.expansion = Expansion(self.model, self.config.arc_checks, self.config.min_range)
        self.map_size = (float(env.geometry.map.width), float(env.geometry.map.height))

    @torch.no_grad()
    def plan(self, pose: Tensor, mean: Tensor, cov: Tensor) -> PlanResult:
        """Plans from robot ``pose [W, 3]`` and beliefs ``mean [W, N, 4]``, ``cov [W, N, 4, 4]``."""
        f64 = torch.float64
        return _Search(self, pose.to(f64), mean.to(f64), cov.to(f64)).run()


class _Search:
    """One planning call: the tree, its per-level pruning state and the anytime loop."""

    def __init__(self, planner: ARVIPlanner, pose: Tensor, mean: Tensor, cov: Tensor) -> None:
        self.planner, self.cfg = planner, planner.config
        self.start = time.perf_counter()
        num_worlds, device = pose.shape[0], pose.device
        self.num_worlds = num_worlds
        means = [mean]
        for _ in range(self.cfg.horizon):
            means.append(belief.bmm(means[-1].unsqueeze(-2), planner.model.transition.mT).squeeze(-2))
        self.positions = [m[..., :2] for m in means]  # predicted target positions per depth
        no = torch.full((num_worlds,), -1, dtype=torch.long, device=device)
        root = Level({"pose": pose, "cov": cov, "logdet": belief.logdet(cov),
                      "cost": torch.zeros(num_worlds, dtype=torch.float64, device=device),
                      "world": torch.arange(num_worlds, device=device), "parent": no, "action": no,
                      "expanded": torch.zeros_like(no, dtype=torch.bool)})
        self.levels = [root] + [root.empty() for _ in range(self.cfg.horizon)]
        self.open = [torch.ones(num_worlds, dtype=torch.bool, device=device)] + [
            torch.zeros(0, dtype=torch.bool, device=device) for _ in range(self.cfg.horizon)]
        self.critical = [math.inf] * (self.cfg.horizon + 1)
        self.nodes = torch.zeros(num_worlds, dtype=torch.long, device=device)
        self.total_nodes = 0  # self.nodes.sum(), kept on the host

    # -------------------------------------------------------------- budgets
    def _out_of_budget(self) -> bool:
        cfg = self.cfg
        if cfg.time_budget is not None and time.perf_counter() - self.start >= cfg.time_budget:
            return True
        return cfg.max_nodes is not None and self.total_nodes >= cfg.max_nodes * self.num_worlds

    def _delta(self, k: int) -> float:
        return self.cfg.delta0 - self.cfg.delta_step * k

    def _next_pass(self, k: int) -> int | None:
        """The first pass after ``k`` whose delta falls below a critical distance (None: none ever will)."""
        critical = max(self.critical[1:])
        if critical == -math.inf:
            return None
        nxt = max(k + 1, math.floor((self.cfg.delta0 - critical) / self.cfg.delta_step) + 1)
        # Guard against rounding in the division: step back while the previous pass already qualifies.
        while nxt - 1 > k and self._delta(nxt - 1) < critical:
            nxt -= 1
        return nxt

    # -------------------------------------------------------------- passes
    def run(self) -> PlanResult:
        """The greedy chain, then the passes of the schedule until a budget is spent; the plan."""
        self._pass(math.inf, math.inf, check_budget=False)  # the greedy chain: keeps the best child only
        if math.isfinite(self.cfg.eps):  # the chain ignored eps: the first real pass recomputes every level
            self.critical = [math.inf] * (self.cfg.horizon + 1)
        k, covered = 0, 0  # covered: passes of the schedule whose result the tree holds
        while k is not None and (self.cfg.max_passes is None or k < self.cfg.max_passes):
            if self._out_of_budget() or not self._pass(self._delta(k), self.cfg.eps, check_budget=True):
                break
            nxt = self._next_pass(k)
            # The passes before the next one that changes something are covered too (None: all of them).
            covered = min(math.inf if nxt is None else nxt, self.cfg.max_passes or math.inf)
            covered = k + 1 if math.isinf(covered) else covered
            k = nxt
        return self._best_path(covered, self._delta(covered - 1) if covered else math.inf)

    def _pass(self, delta: float, eps: float, check_budget: bool) -> bool:
        """One pass over the levels at ``delta``; False when a budget ran out before its end.

        A level is recomputed when the open set above it changed or ``delta`` fell below its critical
        distance (``critical`` is +inf until a level was pruned at a finite ``delta``)."""
        changed = False
        for t in range(1, self.cfg.horizon + 1):
            if check_budget and self._out_of_budget():
                return False
            if changed or delta < self.critical[t] or math.isinf(delta):
                changed = self._prune_level(t, delta, eps)
        return True

    def _prune_level(self, t: int, delta: float, eps: float) -> bool:
        """Expand the newly opened nodes of level ``t - 1`` and prune level ``t``; whether its open set changed."""
        above, level = self.levels[t - 1], self.levels[t]
        fresh = (self.open[t - 1] & ~above.expanded).nonzero().squeeze(-1)
        if fresh.numel():
            children = self.planner.expansion.children(above, fresh, self.positions[t])
            above.expanded[fresh] = True
            level.append(children)
            self.nodes += torch.bincount(children["world"], minlength=self.num_worlds)
            self.total_nodes += children["cost"].shape[0]
        candidates = self.open[t - 1].index_select(0, level.parent).nonzero().squeeze(-1)
        diag = level.cov[candidates].diagonal(dim1=-2, dim2=-1).flatten(1) if math.isfinite(eps) else None
        pruned = prune(level.cost[candidates], level.pose[candidates, :2], diag, level.world[candidates], delta, eps,
                       self.cfg.distance_offset, ((0.0, 0.0), self.planner.map_size))
        opened = torch.zeros(level.size, dtype=torch.bool, device=candidates.device)
        opened[candidates] = pruned.keep
        previous = self.open[t]
        changed = previous.numel() != opened.numel() or not torch.equal(previous, opened)
        self.open[t], self.critical[t] = opened, pruned.critical
        return changed

    def _best_path(self, passes: int, delta: float) -> PlanResult:
        leaves = self.levels[-1]
        best = torch.full((self.num_worlds,), math.inf, dtype=torch.float64, device=leaves.cost.device)
        best = best.scatter_reduce(0, leaves.world, leaves.cost, "amin")
        if torch.isinf(best).any():
            stuck = torch.isinf(best).nonzero().squeeze(-1).tolist()
            raise ValueError(f"worlds {stuck}: no collision-free path of {self.cfg.horizon} steps (does the robot "
                             f"pose {self.levels[0].pose[stuck[0]].tolist()} collide?)")
        index = torch.arange(leaves.cost.numel(), device=best.device)
        first = torch.full_like(self.nodes, leaves.cost.numel())
        first = first.scatter_reduce(0, leaves.world, torch.where(leaves.cost == best[leaves.world], index,
                                                                  leaves.cost.numel()), "amin")
        actions = []
        node = first
        for level in reversed(self.levels[1:]):
            actions.append(level.action[node])
            node = level.parent[node]
        return PlanResult(torch.stack(actions[::-1], -1), best, self.nodes.clone(), passes, delta)
