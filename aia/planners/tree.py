"""The search tree: the nodes of one depth for all worlds (:class:`Level`) and their expansion into the
collision-free children of the motion primitives (:class:`Expansion`)."""

from __future__ import annotations

import math

import torch
from torch import Tensor

from aia.envs.dynamics import se2_step, unicycle_arc
from aia.planners.model import TrackingModel, predict_cov, update_visible, visible_targets

FIELDS = ("pose", "cov", "logdet", "cost", "world", "parent", "action", "expanded")
# Rows a level's buffers hold at least once they hold any: fewer regrowths of a small tree (each copies every
# field), at about 0.4 MB per level for three targets.
_MIN_CAPACITY = 1024


class Level:
    """All nodes of all worlds at one depth, append-only (indices into it stay valid), in buffers that
    double when full so that appending copies only the new nodes.

    Per node: ``pose [3]``, ``cov [N, 4, 4]`` and its per-target ``logdet [N]``, the cost ``g``, its world,
    its ``parent`` (index into the level above), the ``action`` leading to it, and whether it was
    ``expanded`` (its children are in the level below).
    """

    def __init__(self, nodes: dict[str, Tensor]) -> None:
        self.size = nodes["cost"].shape[0]
        self._buffers = {name: nodes[name].clone() for name in FIELDS}

    def __getattr__(self, name: str) -> Tensor:
        if name in FIELDS:
            return self._buffers[name][: self.size]
        raise AttributeError(name)

    def append(self, nodes: dict[str, Tensor]) -> None:
        """Append ``nodes`` (a tensor per field but ``expanded``, which starts False)."""
        count = nodes["cost"].shape[0]
        if self.size + count > self._buffers["cost"].shape[0]:
            capacity = max(2 * self._buffers["cost"].shape[0], self.size + count, _MIN_CAPACITY)
            for name, buffer in self._buffers.items():
                grown = buffer.new_empty((capacity, *buffer.shape[1:]))  # rows past size: written before read
                grown[: self.size] = buffer[: self.size]
                self._buffers[name] = grown
        for name in FIELDS[:-1]:
            self._buffers[name][self.size : self.size + count] = nodes[name]
        self._buffers["expanded"][self.size : self.size + count] = False
        self.size += count

    def empty(self) -> Level:
        """A level with no nodes, of the same dtypes, device and trailing shapes."""
        return Level({name: self._buffers[name][:0] for name in FIELDS})


class Expansion:
    """Children of tree nodes: each motion primitive for one step, dropped when any of ``arc_checks`` points
    along its arc collides, then the filter's covariance step (prediction with the det cap, the Kalman
    update of the targets visible from the child's pose) and the child's cost ``g``."""

    def __init__(self, model: TrackingModel, arc_checks: int, min_range: float) -> None:
        self.model, self.min_range = model, min_range
        fractions = torch.arange(1, arc_checks + 1, dtype=torch.float64, device=model.primitives.device) / arc_checks
        # [A, K, 2]: the primitive's (v, w) scaled so that one step of dt ends at each checked point.
        self.arc_velocity = model.primitives.unsqueeze(1) * fractions.unsqueeze(-1)
        # what the CPU kernel reads of the model (made on first use): the arcs' half turns, and the rest
        self._kernel_constants: tuple[Tensor, dict] | None = None

    def children(self, level: Level, parents: Tensor, positions: Tensor) -> dict[str, Tensor]:
        """The collision-free children of ``parents`` (indices into ``level``), the targets predicted at
        ``positions [W, N, 2]``: a tensor per field of :class:`Level` but ``expanded``, parent by parent and
        action by action. On the CPU (float64) one compiled kernel makes them
        (:mod:`aia.planners.expansion_cpu`), elsewhere :meth:`children_tensors`: the same children."""
        if parents.device.type == "cpu" and level.cov.dtype == torch.float64:
            return self._children_kernel(level, parents, positions)
        return self.children_tensors(level, parents, positions)

    def _children_kernel(self, level: Level, parents: Tensor, positions: Tensor) -> dict[str, Tensor]:
        from aia.planners.expansion_cpu import expand  # here: numba's import costs every command 0.3 s

        if self._kernel_constants is None:
            self._kernel_constants = self._make_kernel_constants()
        half_turn, constants = self._kernel_constants
        # the arcs' cosines and sines as se2_step computes them (the same tensor ops: the same bits)
        heading = level.pose.index_select(0, parents)[:, None, None, 2] + half_turn
        children = expand(parents.numpy(), level.pose.numpy(), level.cov.numpy(), level.logdet.numpy(),
                          level.cost.numpy(), level.world.numpy(), positions.contiguous().numpy(),
                          torch.cos(heading).numpy(), torch.sin(heading).numpy(), **constants)
        return {name: torch.from_numpy(value) for name, value in children.items()}

    def _make_kernel_constants(self) -> tuple[Tensor, dict]:
        """The arcs' half turns ``[A, K]`` and what else the CPU kernel reads of the model (numpy arrays, floats)."""
        model, geometry = self.model, self.model.geometry
        half_turn, chord, turn = unicycle_arc(self.arc_velocity, model.dt)
        samples = math.ceil(2 * geometry.sensor_range / geometry.resolution) + 1
        return half_turn, {
            "chord": chord.numpy(), "turn": turn.numpy(),
            "collision": geometry.collision.numpy(), "fine_cell": geometry.fine_cell,
            "size": tuple(geometry.size.double().tolist()),
            "occupancy": geometry.occupancy.numpy(), "obstacles": geometry.has_obstacles,
            "resolution": geometry.resolution,
            # line_of_sight's sample fractions, in the geometry's dtype as there
            "sight_fraction": torch.linspace(0.0, 1.0, samples, dtype=geometry.dtype).double().numpy(),
            "sensor_range": geometry.sensor_range, "half_fov": geometry.fov / 2, "min_range": self.min_range,
            "transition": model.transition.numpy(), "process_noise": model.process_noise.numpy(),
            "meas_noise": model.meas_noise.numpy(), "log_det_cap": model.log_det_cap}

    def children_tensors(self, level: Level, parents: Tensor, positions: Tensor) -> dict[str, Tensor]:
        """:meth:`children` in tensor ops on any device (what a GPU runs)."""
        model = self.model
        num_actions = model.primitives.shape[0]
        pose = level.pose.index_select(0, parents)
        arc = se2_step(pose[:, None, None, :], self.arc_velocity, model.dt)  # [P, A, K, 3]
        free = ~model.geometry.in_collision(arc[..., :2]).any(-1)
        child = free.flatten().nonzero().squeeze(-1)  # index over (parent, action) pairs
        local, action = child // num_actions, child % num_actions
        parent = parents.index_select(0, local)
        child_pose = arc[..., -1, :].reshape(-1, 3).index_select(0, child)
        world = level.world.index_select(0, parent)
        prior_logdet = level.logdet.index_select(0, parents)
        predicted, logdet = predict_cov(model, level.cov.index_select(0, parents), prior_logdet)
        target_xy = positions.index_select(0, world)
        visible = visible_targets(model, child_pose, target_xy, self.min_range)
        cov, logdet = update_visible(model, predicted.index_select(0, local), logdet.index_select(0, local), child_pose,
                                     target_xy, visible)
        cost = level.cost.index_select(0, parent) + logdet.sum(-1)
        return {"pose": child_pose, "cov": cov, "logdet": logdet, "cost": cost, "world": world, "parent": parent,
                "action": action}
