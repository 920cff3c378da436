"""Reduced value iteration's pruning: greedy suppression of the candidates of a level that lie within
``delta`` of a better kept one; in one compiled pass on the CPU, in parallel rounds over the close pairs
elsewhere."""

from __future__ import annotations

import math
from typing import NamedTuple

import torch
from torch import Tensor

# Up to this many candidate pairs, close pairs come from the full distance matrix (fewer tensor ops); above
# it, from a grid of cells (memory and time linear in the number of close pairs).
_DENSE_PAIRS_MAX = 1 << 16
# Grid cells are 1 / _REACH of the radius wide, so a candidate's close pairs lie within _REACH cells of its
# own (5 x 5 cells cover 6.25 r^2 around it, against 9 r^2 for 3 x 3 cells a radius wide).
_REACH = 2
# Cells are never narrower than this (m), so that a vanishing radius cannot overflow the cell keys.
_MIN_CELL = 1e-3


class Pruned(NamedTuple):
    """Result of :func:`prune`."""

    keep: Tensor  # [M] bool, in the order of the candidates
    # per label: largest distance <= delta of a prunable pair of its candidates (-inf if none); below it, the
    # label's result changes
    criticals: list[float]

    @property
    def critical(self) -> float:
        """The largest critical distance over all labels."""
        return max(self.criticals)


def prune(cost: Tensor, xy: Tensor, cov_diag: Tensor | None, group: Tensor, delta: float, eps: float = math.inf,
          distance_offset: float = 1.0, bounds: tuple[tuple[float, float], tuple[float, float]] | None = None,
          labels: Tensor | None = None, num_labels: int = 1) -> Pruned:
    """Greedy suppression in ascending ``cost`` within each group (world) of ``M`` candidates.

    A candidate is kept unless a kept candidate of its group with a lower cost (ties: the earlier one) lies
    within ``delta`` (distance ``sqrt(dx^2 + dy^2 + distance_offset)``) and, when ``eps`` is finite, the
    candidate is ``eps``-redundant with respect to it: ``diag(S_n - S_m) + eps >= 0`` with ``cov_diag [M, D]``
    the covariance diagonals. The lowest-cost candidate of every group is always kept. ``bounds`` (low and
    high corner) contain every position (default: taken from ``xy``). ``labels [M]`` (``0 .. num_labels - 1``,
    one per group at most; default: all 0) split the critical distance by label. On the CPU (float64) one
    compiled pass does it (:mod:`aia.planners.suppression_cpu`), elsewhere :func:`prune_tensors`: the same
    result.
    """
    if cost.device.type == "cpu" and cost.dtype == xy.dtype == torch.float64 and (
            cov_diag is None or cov_diag.dtype == torch.float64):  # the kernel's arithmetic is float64's
        from aia.planners.suppression_cpu import suppress  # here: numba's import costs every command 0.3 s

        keep, criticals = suppress(cost.numpy(), xy.contiguous().numpy(),
                                   None if cov_diag is None else cov_diag.contiguous().numpy(), group.numpy(),
                                   delta * delta - distance_offset, eps, distance_offset,
                                   None if labels is None else labels.numpy(), num_labels)
        return Pruned(torch.from_numpy(keep), criticals)
    return prune_tensors(cost, xy, cov_diag, group, delta, eps, distance_offset, bounds, labels, num_labels)


def prune_tensors(cost: Tensor, xy: Tensor, cov_diag: Tensor | None, group: Tensor, delta: float,
                  eps: float = math.inf, distance_offset: float = 1.0,
                  bounds: tuple[tuple[float, float], tuple[float, float]] | None = None, labels: Tensor | None = None,
                  num_labels: int = 1) -> Pruned:
    """:func:`prune` in tensor ops on any device (what a GPU runs): the close pairs, then parallel rounds in
    which a candidate is decided once all that could suppress it are."""
    later, earlier, sq_distance = _close_pairs(xy, group, cost, delta * delta - distance_offset, bounds)
    sq_distance = sq_distance + distance_offset
    if math.isfinite(eps) and later.numel():
        redundant = (cov_diag[later] - cov_diag[earlier] + eps >= 0).all(-1)
        later, earlier, sq_distance = later[redundant], earlier[redundant], sq_distance[redundant]
    criticals = _criticals(sq_distance, None if labels is None else labels.index_select(0, later), num_labels)
    # Status 0: dropped, 1: undecided, 2: kept. A candidate whose earlier close neighbours include a kept one
    # is dropped; one whose earlier close neighbours are all dropped is kept.
    status = torch.ones_like(cost, dtype=torch.uint8)
    zeros = torch.zeros_like(status)
    while True:
        undecided = status == 1
        if not undecided.any():
            break
        blocking = zeros.scatter_reduce(0, later, status.index_select(0, earlier), "amax")
        status = torch.where(undecided, 2 - blocking, status)  # 0 -> kept (2), 1 -> undecided (1), 2 -> dropped (0)
    return Pruned(status == 2, criticals)


def _criticals(sq_distance: Tensor, labels: Tensor | None, num_labels: int) -> list[float]:
    """Per label, the square root of the largest of the pairs' ``sq_distance`` (-inf: no pair)."""
    if labels is None:
        largest = [sq_distance.max().item()] if sq_distance.numel() else [-math.inf]
    else:
        largest = sq_distance.new_full((num_labels,), -math.inf).scatter_reduce(0, labels, sq_distance, "amax").tolist()
    return [math.sqrt(value) if value >= 0 else -math.inf for value in largest]


def _close_pairs(xy: Tensor, group: Tensor, cost: Tensor, sq_radius: float,
                 bounds: tuple[tuple[float, float], tuple[float, float]] | None) -> tuple[Tensor, Tensor, Tensor]:
    """Pairs ``(later, earlier)`` of candidates of one group, ``earlier`` first in ascending ``(cost, index)``,
    whose planar squared distance (also returned) is ``<= sq_radius``."""
    count = xy.shape[0]
    if sq_radius < 0 or count < 2:
        return group[:0], group[:0], xy[:0, 0]
    if count * count <= _DENSE_PAIRS_MAX:
        index = torch.arange(count, device=xy.device)
        first, second = ((group[:, None] == group[None, :]) & (index[:, None] > index[None, :])).nonzero(as_tuple=True)
    else:
        first, second = _grid_pairs(xy, group, sq_radius, bounds)
    difference = xy.index_select(0, first) - xy.index_select(0, second)
    sq_distance = difference[:, 0].square() + difference[:, 1].square()
    close = sq_distance <= sq_radius
    first, second, sq_distance = first[close], second[close], sq_distance[close]
    first_cost, second_cost = cost.index_select(0, first), cost.index_select(0, second)
    # first > second: first is the later one unless its cost is lower.
    first_later = first_cost >= second_cost
    return torch.where(first_later, first, second), torch.where(first_later, second, first), sq_distance


def _grid_pairs(xy: Tensor, group: Tensor, sq_radius: float,
                bounds: tuple[tuple[float, float], tuple[float, float]] | None) -> tuple[Tensor, Tensor]:
    """Pairs ``(a, b)``, ``a > b``, of points of one group within ``_REACH`` cells of each other on a grid
    of cells ``sqrt(sq_radius) / _REACH`` wide (one cell per group for an infinite radius): a superset of the
    pairs within the radius, found by sorting the points by cell and searching, for each point, the runs
    of keys of the ``2 _REACH + 1`` neighbouring columns."""
    device, span = xy.device, 2 * _REACH + 1
    if math.isfinite(sq_radius):
        low, high = bounds if bounds is not None else (xy.amin(0).tolist(), xy.amax(0).tolist())
        width = max(math.sqrt(sq_radius) / _REACH * (1 + 1e-9), _MIN_CELL)  # a hair wide against rounding
        cell = torch.floor((xy - torch.tensor(low, dtype=xy.dtype, device=device)) / width).long() + _REACH
        columns, rows = (int((b - a) / width) + span for a, b in zip(low, high, strict=True))
    else:
        cell, columns, rows = torch.full_like(xy, _REACH, dtype=torch.long), span, span
    key = (group * columns + cell[:, 0]) * rows + cell[:, 1]
    sorted_key, by_key = torch.sort(key)
    column = key[:, None] + torch.arange(-_REACH, _REACH + 1, device=device) * rows  # [M, span]
    first = torch.searchsorted(sorted_key, (column - _REACH).flatten())
    count = torch.searchsorted(sorted_key, (column + _REACH).flatten(), right=True) - first
    start = torch.cumsum(count, 0) - count
    within = torch.arange(int(count.sum()), device=device) - start.repeat_interleave(count)
    a = torch.arange(xy.shape[0], device=device).repeat_interleave(span).repeat_interleave(count)
    b = by_key[first.repeat_interleave(count) + within]
    once = a > b
    return a[once], b[once]
