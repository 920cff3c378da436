"""ARVI, Anytime Reduced Value Iteration (SPEC 10), batched over worlds, and the policy that runs it.

A node of the search tree holds a robot pose, the belief covariance of every target (float64) and its
cost ``g``, the sum over its levels of ``log det`` of the joint (block-diagonal) covariance. A child
applies one motion primitive (dropped when a point along its arc collides), then the filter's covariance
step: prediction, and the Kalman update for each target whose predicted mean is visible from the child's
pose. Targets are predicted on the mean only (``mu_t = A^t mu_0``); no measurement is simulated.

Reduced value iteration prunes each level: candidates are visited in ascending ``g`` and one is kept
unless an already kept node of its level lies within ``delta`` of it and, when ``eps`` is finite, the
candidate's covariance is ``eps``-redundant with respect to that node's. The anytime loop runs a greedy
chain, then passes over the same tree with ``delta`` shrinking by ``delta_step`` per pass, until a budget
is spent, and returns the path of the lowest-cost leaf at depth ``horizon``.

All nodes of all worlds of a level are one set of tensors; pruning is a mask computed in a few parallel
rounds. Passes that provably change nothing (``delta`` has not crossed any pairwise node distance of any
level) are skipped without being run, so the result equals the pass-by-pass schedule; levels whose input
did not change since the previous pass are reused. See ``docs/planner.md``.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass
from typing import NamedTuple, Optional

import torch
from omegaconf import DictConfig, OmegaConf
from omegaconf.errors import OmegaConfBaseException
from tensordict import TensorDictBase
from tensordict.nn import TensorDictModuleBase
from torch import Tensor

from aia.envs import belief
from aia.envs.dynamics import se2_step
from aia.envs.sensing import MapGeometry
from aia.envs.tracking import TargetTrackingEnv


# ---------------------------------------------------------------------------------------------- config
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


# ------------------------------------------------------------------------------------ the filter model
class TrackingModel(NamedTuple):
    """What the planner knows of a setting: the env's own motion, filter and sensor model (float64)."""

    primitives: Tensor  # [A, 2] (v, w)
    dt: float
    transition: Tensor  # [4, 4] A
    process_noise: Tensor  # [4, 4] W of the belief
    meas_noise: Tensor  # [2, 2] V
    log_det_cap: float  # the env's det cap (inf: none)
    geometry: MapGeometry  # collision and the sensing rule (range, field of view, line of sight)

    @classmethod
    def from_env(cls, env: TargetTrackingEnv) -> TrackingModel:
        """The model of ``env`` (its very tensors, cast to float64)."""
        cfg, f64 = env.config, torch.float64
        return cls(env.primitives.to(f64), cfg.dt, env.transition.to(f64), env.belief_noise.to(f64),
                   env.meas_noise.to(f64), env.log_det_cap, env.geometry)


def visible_targets(model: TrackingModel, pose: Tensor, positions: Tensor, min_range: float = 0.0) -> Tensor:
    """``[..., N]`` whether each target position ``[..., N, 2]`` is seen from ``pose [..., 3]``: the env's
    sensing rule (:meth:`MapGeometry.in_view`, SPEC 4), and at least ``min_range`` away."""
    visible, polar = model.geometry.in_view(pose, positions)
    return visible & (polar[..., 0] >= min_range) if min_range > 0 else visible


def predict_cov(model: TrackingModel, cov: Tensor) -> Tensor:
    """The env's covariance prediction ``A Sigma A^T + W`` with its det cap (:func:`belief.cap_det`)."""
    return belief.cap_det(cov, belief.predict_cov(cov, model.transition, model.process_noise), model.log_det_cap)


def update_visible(model: TrackingModel, predicted: Tensor, pose: Tensor, positions: Tensor, visible: Tensor) -> Tensor:
    """Kalman covariance update of the ``visible`` targets, the Jacobian taken at ``positions [..., N, 2]``
    seen from ``pose [..., 3]``; the others keep their ``predicted [..., N, 4, 4]`` covariance."""
    jacobian = belief.measurement_jacobian(positions, pose.unsqueeze(-2))
    updated, _ = belief.update_cov(predicted, jacobian, model.meas_noise)
    return torch.where(visible[..., None, None], updated, predicted)


# ------------------------------------------------------------------------------------------- pruning
class Pruned(NamedTuple):
    """Result of :func:`prune`."""

    keep: Tensor  # [M] bool, in the order of the candidates
    critical: float  # largest distance <= delta of a prunable pair (-inf if none): below it, the result changes


def prune(cost: Tensor, xy: Tensor, cov_diag: Tensor | None, group: Tensor, delta: float, eps: float = math.inf,
          distance_offset: float = 1.0) -> Pruned:
    """Greedy suppression in ascending ``cost`` within each group (world) of ``M`` candidates.

    A candidate is kept unless a kept candidate of its group with a lower cost (ties: the earlier one) lies
    within ``delta`` (distance ``sqrt(dx^2 + dy^2 + distance_offset)``) and, when ``eps`` is finite, the
    candidate is ``eps``-redundant with respect to it: ``diag(S_n - S_m) + eps >= 0`` with ``cov_diag [M, D]``
    the covariance diagonals. The lowest-cost candidate of every group is always kept. Solved in parallel
    rounds over the pairs within ``delta``: a candidate is decided once all that could suppress it are.
    """
    rank = torch.empty_like(group)
    order = torch.argsort(cost, stable=True)
    order = order[torch.argsort(group[order], stable=True)]
    rank[order] = torch.arange(order.numel(), device=cost.device)
    later, earlier, sq_distance = _close_pairs(xy, group, rank, delta * delta - distance_offset)
    sq_distance = sq_distance + distance_offset
    if math.isfinite(eps) and later.numel():
        redundant = (cov_diag[later] - cov_diag[earlier] + eps >= 0).all(-1)
        later, earlier, sq_distance = later[redundant], earlier[redundant], sq_distance[redundant]
    critical = math.sqrt(sq_distance.max().item()) if sq_distance.numel() else -math.inf

    # Status 0: dropped, 1: undecided, 2: kept. A candidate whose earlier close neighbours include a kept one
    # is dropped; one whose earlier close neighbours are all dropped is kept.
    status = torch.ones_like(cost, dtype=torch.uint8)
    while True:
        undecided = status == 1
        if not undecided.any():
            break
        blocking = torch.zeros_like(status).scatter_reduce_(0, later, status[earlier], "amax")
        status = torch.where(undecided, 2 - blocking, status)  # 0 -> kept (2), 1 -> undecided (1), 2 -> dropped (0)
    return Pruned(status == 2, critical)


# Up to this many candidates, close pairs come from the full distance matrix (fewer tensor ops); above it,
# from a grid of cells (memory and time linear in the number of close pairs).
_DENSE_PAIRS_MAX = 512


def _close_pairs(xy: Tensor, group: Tensor, rank: Tensor, sq_radius: float) -> tuple[Tensor, Tensor, Tensor]:
    """Pairs ``(later, earlier)`` of candidates of one group with ``rank[earlier] < rank[later]`` whose planar
    squared distance (also returned) is ``<= sq_radius``."""
    if sq_radius < 0 or xy.shape[0] < 2:
        return group[:0], group[:0], xy[:0, 0]
    if xy.shape[0] <= _DENSE_PAIRS_MAX:
        sq_distance = (xy.unsqueeze(1) - xy.unsqueeze(0)).square().sum(-1)
        close = (sq_distance <= sq_radius) & (group.unsqueeze(1) == group.unsqueeze(0))
        later, earlier = (close & (rank.unsqueeze(1) > rank.unsqueeze(0))).nonzero(as_tuple=True)
        return later, earlier, sq_distance[later, earlier]
    later, earlier = _grid_neighbours(xy, group, math.sqrt(sq_radius))
    forward = rank.index_select(0, earlier) < rank.index_select(0, later)
    later, earlier = later[forward], earlier[forward]
    sq_distance = (xy.index_select(0, later) - xy.index_select(0, earlier)).square().sum(-1)
    close = sq_distance <= sq_radius
    return later[close], earlier[close], sq_distance[close]


def _grid_neighbours(xy: Tensor, group: Tensor, radius: float) -> tuple[Tensor, Tensor]:
    """All pairs ``(a, b)`` of points of one group in the same or adjacent cells of a grid ``radius`` wide (a
    superset of the pairs within ``radius``), found by sorting the points by cell and searching each point's
    3 x 3 neighbourhood."""
    if math.isfinite(radius) and radius > 0:
        cell = torch.floor(xy / radius).long()
        cell = cell - cell.min(0).values + 1  # >= 1, so that every neighbour cell index is >= 0
    else:  # an infinite radius: one cell per group
        cell = torch.ones_like(xy, dtype=torch.long)
    rows = int(cell[:, 1].max()) + 2
    columns = int(cell[:, 0].max()) + 2
    key = (group * columns + cell[:, 0]) * rows + cell[:, 1]
    sorted_key, by_key = torch.sort(key)
    shift = torch.tensor([-1, 0, 1], device=xy.device)
    neighbour = (key[:, None, None] + shift[:, None] * rows + shift[None, :]).flatten()  # [M * 9]
    first = torch.searchsorted(sorted_key, neighbour)
    count = torch.searchsorted(sorted_key, neighbour, right=True) - first
    start = torch.cumsum(count, 0) - count
    within = torch.arange(int(count.sum()), device=xy.device) - start.repeat_interleave(count)
    a = torch.arange(xy.shape[0], device=xy.device).repeat_interleave(9).repeat_interleave(count)
    return a, by_key[first.repeat_interleave(count) + within]


# ---------------------------------------------------------------------------------------------- tree
@dataclass
class _Level:
    """All nodes of all worlds at one depth; append-only, so indices into it stay valid."""

    pose: Tensor  # [M, 3]
    cov: Tensor  # [M, N, 4, 4]
    cost: Tensor  # [M]
    world: Tensor  # [M]
    parent: Tensor  # [M] index into the level above
    action: Tensor  # [M]
    expanded: Tensor  # [M] bool: its children are in the level below

    def append(self, other: _Level) -> None:
        for name in _LEVEL_FIELDS:
            setattr(self, name, torch.cat((getattr(self, name), getattr(other, name))))

    def empty(self) -> _Level:
        """A level with no nodes, of the same dtypes, device and trailing shapes."""
        return _Level(*(getattr(self, name)[:0] for name in _LEVEL_FIELDS))


_LEVEL_FIELDS = ("pose", "cov", "cost", "world", "parent", "action", "expanded")


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
        k = self.config.arc_checks
        fractions = torch.arange(1, k + 1, dtype=torch.float64, device=self.device) / k
        # [A, K, 2]: the primitive's (v, w) scaled so that one step of dt ends at each checked point.
        self._arc_velocity = self.model.primitives.unsqueeze(1) * fractions.unsqueeze(-1)

    @torch.no_grad()
    def plan(self, pose: Tensor, mean: Tensor, cov: Tensor) -> PlanResult:
        """Plans from robot ``pose [W, 3]`` and beliefs ``mean [W, N, 4]``, ``cov [W, N, 4, 4]``."""
        f64 = torch.float64
        search = _Search(self, pose.to(f64), mean.to(f64), cov.to(f64))
        return search.run()

    def expand(self, level: _Level, parents: Tensor, positions: Tensor) -> _Level:
        """The collision-free children of ``parents`` (indices into ``level``), the targets predicted at
        ``positions [W, N, 2]``."""
        model = self.model
        num_actions = model.primitives.shape[0]
        pose = level.pose.index_select(0, parents)
        arc = se2_step(pose[:, None, None, :], self._arc_velocity, model.dt)  # [P, A, K, 3]
        free = ~model.geometry.in_collision(arc[..., :2]).any(-1)
        child = free.flatten().nonzero().squeeze(-1)  # index over (parent, action) pairs
        local, action = child // num_actions, child % num_actions
        parent = parents.index_select(0, local)
        child_pose = arc[..., -1, :].reshape(-1, 3).index_select(0, child)
        world = level.world.index_select(0, parent)
        predicted = predict_cov(model, level.cov.index_select(0, parents)).index_select(0, local)
        target_xy = positions.index_select(0, world)
        visible = visible_targets(model, child_pose, target_xy, self.config.min_range)
        cov = update_visible(model, predicted, child_pose, target_xy, visible)
        cost = level.cost.index_select(0, parent) + belief.logdet(cov).sum(-1)
        return _Level(child_pose, cov, cost, world, parent, action, torch.zeros_like(cost, dtype=torch.bool))


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
        root = _Level(pose, cov, torch.zeros(num_worlds, dtype=torch.float64, device=device),
                      torch.arange(num_worlds, device=device), no, no, torch.zeros_like(no, dtype=torch.bool))
        self.levels = [root] + [root.empty() for _ in range(self.cfg.horizon)]
        self.open = [torch.ones(num_worlds, dtype=torch.bool, device=device)] + [
            torch.zeros(0, dtype=torch.bool, device=device) for _ in range(self.cfg.horizon)]
        self.critical = [math.inf] * (self.cfg.horizon + 1)
        self.nodes = torch.zeros(num_worlds, dtype=torch.long, device=device)

    # -------------------------------------------------------------- budgets
    def _out_of_budget(self) -> bool:
        cfg = self.cfg
        if cfg.time_budget is not None and time.perf_counter() - self.start >= cfg.time_budget:
            return True
        return cfg.max_nodes is not None and self.nodes.sum().item() >= cfg.max_nodes * self.num_worlds

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
            children = self.planner.expand(above, fresh, self.positions[t])
            above.expanded[fresh] = True
            level.append(children)
            self.nodes += torch.bincount(children.world, minlength=self.num_worlds)
        candidates = self.open[t - 1][level.parent].nonzero().squeeze(-1)
        diag = level.cov[candidates].diagonal(dim1=-2, dim2=-1).flatten(1) if math.isfinite(eps) else None
        pruned = prune(level.cost[candidates], level.pose[candidates, :2], diag, level.world[candidates], delta, eps,
                       self.cfg.distance_offset)
        opened = torch.zeros_like(level.expanded)
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


# ---------------------------------------------------------------------------------------------- policy
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
