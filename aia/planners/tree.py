"""The search tree: the nodes of one depth for all worlds (:class:`Level`) and their expansion into the
collision-free children of the motion primitives (:class:`Expansion`)."""

from __future__ import annotations

import math

import numpy as np
import torch
from torch import Tensor

from aia.envs.dynamics import se2_step, unicycle_arc
from aia.envs.sensing import WorldMapGeometry
from aia.planners.model import TrackingModel, predict_cov, update_visible, visible_targets

FIELDS = ("pose", "cov", "logdet", "cost", "world", "parent", "action", "expanded")
# Rows a level's buffers hold at least once they hold any: fewer regrowths of a small tree (each copies every
# field), at about 0.4 MB per level for three targets.
_MIN_CAPACITY = 1024


class Level:
    """All nodes of all worlds at one depth, append-only (indices into it stay valid), in buffers that
    double when full so that appending copies only the new nodes. ``storage`` (a level's :attr:`storage`)
    lends it the buffers of an earlier call's level, already grown and in memory.

    Per node: ``pose [3]``, ``cov [N, 4, 4]`` and its per-target ``logdet [N]``, the cost ``g``, its world,
    its ``parent`` (index into the level above), the ``action`` leading to it, and whether it was
    ``expanded`` (its children are in the level below).
    """

    def __init__(self, nodes: dict[str, Tensor], storage: dict[str, Tensor] | None = None) -> None:
        self.size = nodes["cost"].shape[0]
        if storage is not None and all(_holds(storage[name], nodes[name], self.size) for name in FIELDS):
            self._buffers = dict(storage)
            for name in FIELDS:
                self._buffers[name][: self.size] = nodes[name]
        else:
            self._buffers = {name: nodes[name].clone() for name in FIELDS}

    def __getattr__(self, name: str) -> Tensor:
        if name in FIELDS:
            return self._buffers[name][: self.size]
        raise AttributeError(name)

    def append(self, nodes: dict[str, Tensor]) -> None:
        """Append ``nodes`` (a tensor per field but ``expanded``, which starts False)."""
        count = nodes["cost"].shape[0]
        for name, rows in self.reserve(count).items():
            rows.copy_(nodes[name])
        self.commit(count)

    def reserve(self, count: int) -> dict[str, Tensor]:
        """Room for ``count`` more nodes: a view per field but ``expanded`` of the rows past the last node, to be
        written in place and kept with :meth:`commit` (an expansion kernel writes its children there directly
        instead of into arrays of its own that would then be copied)."""
        if self.size + count > self._buffers["cost"].shape[0]:
            capacity = max(2 * self._buffers["cost"].shape[0], self.size + count, _MIN_CAPACITY)
            for name, buffer in self._buffers.items():
                grown = buffer.new_empty((capacity, *buffer.shape[1:]))  # rows past size: written before read
                grown[: self.size] = buffer[: self.size]
                self._buffers[name] = grown
        return {name: self._buffers[name][self.size : self.size + count] for name in FIELDS[:-1]}

    def commit(self, count: int) -> dict[str, Tensor]:
        """Keep the first ``count`` rows that :meth:`reserve` gave (not expanded yet); returns them, a view per
        field but ``expanded``."""
        start = self.size
        self._buffers["expanded"][start : start + count] = False
        self.size += count
        return {name: self._buffers[name][start : self.size] for name in FIELDS[:-1]}

    @property
    def storage(self) -> dict[str, Tensor]:
        """The level's buffers (a tensor per field, at least :attr:`size` rows), for a later level to reuse."""
        return self._buffers

    def empty(self, storage: dict[str, Tensor] | None = None) -> Level:
        """A level with no nodes, of the same dtypes, device and trailing shapes (in ``storage``, another level's
        :attr:`storage`, where it has them)."""
        return Level({name: self._buffers[name][:0] for name in FIELDS}, storage)


def _holds(buffer: Tensor, nodes: Tensor, count: int) -> bool:
    """Whether ``buffer`` can store ``count`` rows like ``nodes``."""
    return (buffer.shape[0] >= count and buffer.shape[1:] == nodes.shape[1:] and buffer.dtype == nodes.dtype
            and buffer.device == nodes.device)


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
        self._per_world = isinstance(model.geometry, WorldMapGeometry)  # a map per world, or one for all

    def extend(self, below: Level, level: Level, parents: Tensor, positions: Tensor, maps: Tensor
               ) -> dict[str, Tensor]:
        """Append the collision-free children of ``parents`` (indices into ``level``), the targets predicted at
        ``positions [W, N, 2]``, to ``below``, parent by parent and action by action; returns them (a view per
        field of :class:`Level` but ``expanded``). ``maps [W]``: each planned world's world of the env, whose map
        it plans on where the env's worlds have maps of their own. On the CPU (float64) one compiled kernel
        writes them into ``below`` (:mod:`aia.planners.expansion_cpu`), elsewhere :meth:`children_tensors`
        makes them: the same children."""
        if parents.device.type == "cpu" and level.cov.dtype == torch.float64:
            rows = below.reserve(parents.numel() * self.model.primitives.shape[0])
            return below.commit(self._children_kernel(level, parents, positions, maps, rows))
        children = self.children_tensors(level, parents, positions, maps)
        below.append(children)
        return children

    def _children_kernel(self, level: Level, parents: Tensor, positions: Tensor, maps: Tensor,
                         out: dict[str, Tensor]) -> int:
        """The kernel's children written to the first rows of ``out`` (a tensor per field but ``expanded``, a
        row per parent and action); returns how many."""
        from aia.planners.expansion_cpu import expand  # here: numba's import costs every command 0.3 s

        if self._kernel_constants is None:
            self._kernel_constants = self._make_kernel_constants()
        half_turn, constants = self._kernel_constants
        # the arcs' cosines and sines as se2_step computes them (the same tensor ops: the same bits)
        heading = level.pose.index_select(0, parents)[:, None, None, 2] + half_turn
        world_maps = maps.numpy() if self._per_world else np.zeros(maps.shape[0], dtype=np.int64)  # one map: map 0
        return expand(parents.numpy(), level.pose.numpy(), level.cov.numpy(), level.logdet.numpy(),
                      level.cost.numpy(), level.world.numpy(), world_maps, positions.contiguous().numpy(),
                      torch.cos(heading).numpy(), torch.sin(heading).numpy(),
                      {name: value.numpy() for name, value in out.items()}, **constants)

    def _make_kernel_constants(self) -> tuple[Tensor, dict]:
        """The arcs' half turns ``[A, K]`` and what else the CPU kernel reads of the model (numpy arrays, floats;
        the per-world maps as views of the env's buffers, which a reset rewrites in place)."""
        model, geometry = self.model, self.model.geometry
        half_turn, chord, turn = unicycle_arc(self.arc_velocity, model.dt)
        samples = math.ceil(2 * geometry.sensor_range / geometry.resolution) + 1
        occupancy = geometry.occupancy if self._per_world else geometry.occupancy[None]
        # per-world maps have no collision grid (a fine grid per world): the kernel tests the margin itself
        collision = torch.zeros(0, 0, dtype=torch.bool) if self._per_world else geometry.collision
        return half_turn, {
            "chord": chord.numpy(), "turn": turn.numpy(),
            "collision": collision.numpy(), "fine_cell": geometry.fine_cell,
            "supersample": geometry.supersample, "margin": geometry.margin,
            "size": tuple(geometry.size.double().tolist()),
            "occupancy": occupancy.numpy(), "obstacles": geometry.has_obstacles,
            "resolution": geometry.resolution,
            # line_of_sight's sample fractions, in the geometry's dtype as there
            "sight_fraction": torch.linspace(0.0, 1.0, samples, dtype=geometry.dtype).double().numpy(),
            "sensor_range": geometry.sensor_range, "half_fov": geometry.fov / 2, "min_range": self.min_range,
            "transition": model.transition.numpy(), "process_noise": model.process_noise.numpy(),
            "meas_noise": model.meas_noise.numpy(), "log_det_cap": model.log_det_cap}

    def children_tensors(self, level: Level, parents: Tensor, positions: Tensor, maps: Tensor
                         ) -> dict[str, Tensor]:
        """:meth:`children` in tensor ops on any device (what a GPU runs)."""
        model, geometry = self.model, self.model.geometry
        num_actions = model.primitives.shape[0]
        pose = level.pose.index_select(0, parents)
        arc = se2_step(pose[:, None, None, :], self.arc_velocity, model.dt)  # [P, A, K, 3]
        free = ~geometry.select(maps[level.world.index_select(0, parents)]).in_collision(arc[..., :2]).any(-1)
        child = free.flatten().nonzero().squeeze(-1)  # index over (parent, action) pairs
        local, action = child // num_actions, child % num_actions
        parent = parents.index_select(0, local)
        child_pose = arc[..., -1, :].reshape(-1, 3).index_select(0, child)
        world = level.world.index_select(0, parent)
        prior_logdet = level.logdet.index_select(0, parents)
        predicted, logdet = predict_cov(model, level.cov.index_select(0, parents), prior_logdet)
        target_xy = positions.index_select(0, world)
        visible = visible_targets(geometry.select(maps[world]), child_pose, target_xy, self.min_range)
        cov, logdet = update_visible(model, predicted.index_select(0, local), logdet.index_select(0, local), child_pose,
                                     target_xy, visible)
        cost = level.cost.index_select(0, parent) + logdet.sum(-1)
        return {"pose": child_pose, "cov": cov, "logdet": logdet, "cost": cost, "world": world, "parent": parent,
                "action": action}
