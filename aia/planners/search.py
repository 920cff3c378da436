"""The anytime schedule of ARVI (SPEC 10): a greedy chain, then passes over the same tree with ``delta``
shrinking by ``delta_step`` until a budget is spent, and the plan: the path of the lowest-cost leaf.

Passes that provably change nothing (``delta`` has not crossed any pairwise node distance of any level)
are skipped without being run, so the result equals the pass-by-pass schedule; levels whose input did not
change since the previous pass are reused. A call may plan several budget groups of worlds at once: each
group runs its own schedule on its own node and pass budgets, as if planned alone. See ``docs/planner.md``.
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

# Parents expanded between two readings of the clock under a time budget: about 12,000 children, some 10 ms.
_TIMED_CHUNK = 1024


class PlanResult(NamedTuple):
    """Plans of a batch of worlds (one budget group)."""

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
        geometry = env.geometry
        self.map_size = (geometry.shape[1] * geometry.resolution, geometry.shape[0] * geometry.resolution)
        # each depth's node buffers, kept from call to call (see _Search.run)
        self.storage: list[dict[str, Tensor]] = []

    def plan(self, pose: Tensor, mean: Tensor, cov: Tensor, worlds: Tensor | None = None) -> PlanResult:
        """Plans from robot ``pose [W, 3]`` and beliefs ``mean [W, N, 4]``, ``cov [W, N, 4, 4]`` (one budget
        group: ``max_nodes`` counts the nodes of all ``W`` worlds against ``W * max_nodes``). ``worlds [W]``:
        which of the env's worlds they are (default ``0 .. W - 1``), whose maps they plan on where the env's
        worlds have maps of their own."""
        zeros = torch.zeros(pose.shape[0], dtype=torch.long, device=pose.device)
        return self.plan_groups(pose, mean, cov, zeros, worlds)[0]

    def plan_groups(self, pose: Tensor, mean: Tensor, cov: Tensor, groups: Tensor, worlds: Tensor | None = None
                    ) -> list[PlanResult]:
        """Plans of several budget groups in one batch: ``groups [W]`` labels each world ``0 .. G - 1``
        (every label used); ``worlds`` as in :meth:`plan`. Result ``g`` holds group ``g``'s worlds in ascending
        order and equals :meth:`plan` of those worlds alone under a node or pass budget; the time budget is shared
        by the call."""
        groups = torch.as_tensor(groups, device=pose.device)
        if (groups.shape != pose.shape[:1] or groups.dtype.is_floating_point or groups.dtype == torch.bool
                or not torch.equal(groups.unique(), torch.arange(int(groups.max()) + 1, device=pose.device))):
            raise ValueError(f"groups must label the {pose.shape[0]} worlds 0 .. G - 1, every label used, got "
                             f"{groups.tolist()}")
        f64 = torch.float64
        # inference mode: a call is thousands of small ops, each a little cheaper without autograd's
        # bookkeeping (at one world 15-25 % of a call, 2026-12-02); the results leave it as plain tensors
        with torch.inference_mode():
            maps = torch.arange(pose.shape[0], device=pose.device) if worlds is None else worlds.to(pose.device)
            plans = _Search(self, pose.to(f64), mean.to(f64), cov.to(f64), maps, groups).run()
        return [plan._replace(actions=plan.actions.clone(), cost=plan.cost.clone(), nodes=plan.nodes.clone())
                for plan in plans]


class _Search:
    """One planning call: the tree, its per-level pruning state and the anytime loop, per budget group."""

    def __init__(self, planner: ARVIPlanner, pose: Tensor, mean: Tensor, cov: Tensor, maps: Tensor,
                 groups: Tensor | None = None) -> None:
        self.planner, self.cfg = planner, planner.config
        self.maps = maps  # [W] each planned world's world of the env (its map)
        self.start = time.perf_counter()
        num_worlds, device = pose.shape[0], pose.device
        self.num_worlds = num_worlds
        self.group = torch.zeros(num_worlds, dtype=torch.long, device=device) if groups is None else groups
        self.num_groups = int(self.group.max()) + 1
        self.members = [(self.group == g).nonzero().squeeze(-1) for g in range(self.num_groups)]
        means = [mean]
        for _ in range(self.cfg.horizon):
            means.append(belief.bmm(means[-1].unsqueeze(-2), planner.model.transition.mT).squeeze(-2))
        self.positions = [m[..., :2] for m in means]  # predicted target positions per depth
        no = torch.full((num_worlds,), -1, dtype=torch.long, device=device)
        storage = planner.storage + [None] * (self.cfg.horizon + 1 - len(planner.storage))
        root = Level({"pose": pose, "cov": cov, "logdet": belief.logdet(cov),
                      "cost": torch.zeros(num_worlds, dtype=torch.float64, device=device),
                      "world": torch.arange(num_worlds, device=device), "parent": no, "action": no,
                      "expanded": torch.zeros_like(no, dtype=torch.bool)}, storage[0])
        self.levels = [root] + [root.empty(storage[t]) for t in range(1, self.cfg.horizon + 1)]
        self.open = [torch.ones(num_worlds, dtype=torch.bool, device=device)] + [
            torch.zeros(0, dtype=torch.bool, device=device) for _ in range(self.cfg.horizon)]
        # critical[t][g]: below this delta, level t of group g changes
        self.critical = [[math.inf] * self.num_groups for _ in range(self.cfg.horizon + 1)]
        self.nodes = torch.zeros(num_worlds, dtype=torch.long, device=device)
        self.group_nodes = [0] * self.num_groups  # nodes generated per group, kept on the host

    # -------------------------------------------------------------- budgets
    def _out_of_time(self) -> bool:
        return self.cfg.time_budget is not None and time.perf_counter() - self.start >= self.cfg.time_budget

    def _out_of_nodes(self, group: int) -> bool:
        max_nodes = self.cfg.max_nodes
        return max_nodes is not None and self.group_nodes[group] >= max_nodes * self.members[group].numel()

    def _delta(self, k: int) -> float:
        return self.cfg.delta0 - self.cfg.delta_step * k

    def _next_pass(self, k: int, group: int) -> int | None:
        """The first pass after ``k`` whose delta falls below a critical distance of ``group`` (None: none
        ever will)."""
        critical = max(level[group] for level in self.critical[1:])
        if critical == -math.inf:
            return None
        nxt = max(k + 1, math.floor((self.cfg.delta0 - critical) / self.cfg.delta_step) + 1)
        # Guard against rounding in the division: step back while the previous pass already qualifies.
        while nxt - 1 > k and self._delta(nxt - 1) < critical:
            nxt -= 1
        return nxt

    # -------------------------------------------------------------- passes
    def run(self) -> list[PlanResult]:
        """The greedy chain, then each group's passes of the schedule until its budget is spent (the batch
        runs pass ``k`` for the groups whose next pass is ``k``); one plan per group."""
        groups = list(range(self.num_groups))
        self._pass(math.inf, math.inf, groups, check_budget=False)  # the greedy chain: keeps the best child only
        if math.isfinite(self.cfg.eps):  # the chain ignored eps: the first real pass recomputes every level
            self.critical = [[math.inf] * self.num_groups for _ in self.critical]
        limit = math.inf if self.cfg.max_passes is None else self.cfg.max_passes
        pending = dict.fromkeys(groups, 0)  # group -> its next pass (absent: its search has ended)
        covered = [0] * self.num_groups  # per group: passes of the schedule whose result the tree holds
        while any(k < limit for k in pending.values()):
            k = min(pending.values())
            running = [g for g, next_k in pending.items() if next_k == k]
            finished = self._pass(self._delta(k), self.cfg.eps, running, check_budget=True)
            if finished is None:  # out of time: every group ends here
                break
            for g in running:  # the groups that finished the pass come back with their next one; a group
                del pending[g]  # whose nodes ran out is frozen where it would have stopped alone
            for g in finished:
                nxt = self._next_pass(k, g)
                # The passes before the next one that changes something are covered too (None: all of them).
                reach = min(math.inf if nxt is None else nxt, self.cfg.max_passes or math.inf)
                covered[g] = k + 1 if math.isinf(reach) else reach
                if nxt is not None:
                    pending[g] = nxt
        # The levels' buffers serve the planner's next call: a level of a deep search holds hundreds of thousands of
        # nodes, and fresh buffers grew to that size by doubling, each new one's pages faulted in as first written
        # (small3, 25 worlds of 25,000 nodes: 0.36 of a 1.2 s call). The plans below copy what they keep.
        self.planner.storage = [level.storage for level in self.levels]
        return self._plans(covered)

    def _pass(self, delta: float, eps: float, groups: list[int], check_budget: bool) -> list[int] | None:
        """One pass over the levels at ``delta`` for ``groups``: those that completed it (a group whose node
        budget ran out before a level stops there), None when the time budget ran out.

        A level is recomputed for a group when the group's open set above it changed or ``delta`` fell below
        its critical distance (``critical`` is +inf until a level was pruned at a finite ``delta``)."""
        changed = dict.fromkeys(groups, False)
        for t in range(1, self.cfg.horizon + 1):
            if check_budget:
                if self._out_of_time():
                    return None
                changed = {g: c for g, c in changed.items() if not self._out_of_nodes(g)}
            due = [g for g, c in changed.items() if c or delta < self.critical[t][g] or math.isinf(delta)]
            if due:
                level_changed = self._prune_level(t, delta, eps, due, check_budget)
                if level_changed is None:
                    return None
                changed.update(level_changed)
        return list(changed)

    def _prune_level(self, t: int, delta: float, eps: float, groups: list[int], check_budget: bool = False
                     ) -> dict[int, bool] | None:
        """Expand the newly opened nodes of level ``t - 1`` and prune level ``t``, for the worlds of
        ``groups`` only (the others' nodes keep their state); per group, whether its open set changed. With
        ``check_budget`` and a time budget, None once the clock runs out within the level (the tree keeps the
        children made so far, unpruned)."""
        above, level = self.levels[t - 1], self.levels[t]
        active = None  # [W] whether a world takes part (None: all do)
        if len(groups) < self.num_groups:
            active = torch.zeros(self.num_groups, dtype=torch.bool, device=self.group.device)
            active[groups] = True
            active = active[self.group]
        open_above = self.open[t - 1] if active is None else self.open[t - 1] & active[above.world]
        fresh = (open_above & ~above.expanded).nonzero().squeeze(-1)
        timed = check_budget and self.cfg.time_budget is not None
        # under a time budget in chunks, the clock read between them: a level of a deep pass can hold a million
        # children, a second's work or more
        chunk = _TIMED_CHUNK if timed else max(1, fresh.numel())
        for start in range(0, fresh.numel(), chunk):
            if start and self._out_of_time():
                return None
            parents = fresh[start : start + chunk]
            children = self.planner.expansion.extend(level, above, parents, self.positions[t], self.maps)
            above.expanded[parents] = True
            self._count(children["world"])
        if timed and self._out_of_time():
            return None
        candidates = open_above.index_select(0, level.parent).nonzero().squeeze(-1)
        diag = level.cov[candidates].diagonal(dim1=-2, dim2=-1).flatten(1) if math.isfinite(eps) else None
        world = level.world[candidates]
        labels = self.group.index_select(0, world) if self.num_groups > 1 else None
        pruned = prune(level.cost[candidates], level.pose[candidates, :2], diag, world, delta, eps,
                       self.cfg.distance_offset, ((0.0, 0.0), self.planner.map_size), labels, self.num_groups)
        previous = self.open[t]
        opened = torch.zeros(level.size, dtype=torch.bool, device=candidates.device)
        if active is not None:  # the other groups' nodes stay as they are
            opened[: previous.numel()] = previous & ~active[level.world[: previous.numel()]]
        opened[candidates] = pruned.keep
        self.open[t] = opened
        for g in groups:
            self.critical[t][g] = pruned.criticals[g]
        # a group changed when it gained nodes or one of its nodes was opened or closed
        differs = torch.ones(level.size, dtype=torch.bool, device=candidates.device)
        differs[: previous.numel()] = previous != opened[: previous.numel()]
        if self.num_groups == 1:
            return {0: bool(differs.any())}
        hit = torch.zeros(self.num_groups, dtype=torch.bool, device=candidates.device)
        hit[self.group[level.world[differs]]] = True
        hit = hit.tolist()
        return {g: hit[g] for g in groups}

    def _count(self, world: Tensor) -> None:
        """Count new nodes of worlds ``world`` against their worlds and groups."""
        new = torch.bincount(world, minlength=self.num_worlds)
        self.nodes += new
        if self.num_groups == 1:
            self.group_nodes[0] += world.numel()
        else:
            per_group = torch.zeros(self.num_groups, dtype=torch.long, device=new.device).index_add_(0, self.group, new)
            self.group_nodes = [a + b for a, b in zip(self.group_nodes, per_group.tolist(), strict=True)]

    def _plans(self, covered: list[int]) -> list[PlanResult]:
        """Each group's plans: the path of its worlds' lowest-cost leaves, its counts and passes covered."""
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
        actions = torch.stack(actions[::-1], -1)
        return [PlanResult(actions[worlds], best[worlds], self.nodes[worlds], passes,
                           self._delta(passes - 1) if passes else math.inf)
                for worlds, passes in zip(self.members, covered, strict=True)]
