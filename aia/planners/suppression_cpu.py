"""Greedy suppression of :func:`aia.planners.pruning.prune` as one compiled CPU kernel (numba).

On the CPU the tensor formulation (close pairs from a grid, then parallel suppression rounds) spends most of a
planning call on tensor ops over candidate pairs: on small3, 50 worlds, 5,000 nodes per world, pruning took
70 % of a call (0.94 of 1.32 s, 4.8 M close pairs over 88 levels). This kernel visits each candidate once in
ascending ``(cost, index)`` order and scans only the candidates of the 3 x 3 neighbouring grid cells, so it
does the same suppression in one pass with no pair lists (``benchmarks/arvi.py`` gives the figures). Same
arithmetic as the tensor version (``dx * dx + dy * dy`` in float64, the same comparisons), so the same
candidates are kept and the same critical distances found.
"""

from __future__ import annotations

import math

import numba
import numpy as np


def suppress(cost: np.ndarray, xy: np.ndarray, cov_diag: np.ndarray | None, group: np.ndarray, sq_radius: float,
             eps: float, distance_offset: float, labels: np.ndarray | None, num_labels: int
             ) -> tuple[np.ndarray, list[float]]:
    """Which candidates greedy suppression keeps (``[M]`` bool) and, per label, the largest distance of a
    prunable pair (-inf if none): a pair of one ``group`` whose planar squared distance is ``<= sq_radius``
    and, when ``eps`` is finite, whose later candidate is ``eps``-redundant to the earlier one. ``cost``,
    ``xy [M, 2]`` and ``cov_diag [M, D]`` are float64, ``group`` and ``labels`` int64."""
    count = cost.shape[0]
    largest = np.full(num_labels, -math.inf)
    keep = np.ones(count, dtype=np.bool_)
    if count >= 2 and sq_radius >= 0:
        redundancy = math.isfinite(eps)
        diag = cov_diag if redundancy else np.zeros((count, 0))
        order = np.argsort(cost, kind="stable")  # ascending (cost, index): the order of the greedy pass
        _suppress(order, xy, np.ascontiguousarray(diag), group, np.zeros(count, dtype=np.int64) if labels is None
                  else labels, sq_radius, eps if redundancy else 0.0, redundancy, distance_offset, keep, largest)
    return keep, [math.sqrt(value) if value >= 0 else -math.inf for value in largest.tolist()]


@numba.njit(cache=True, nogil=True)
def _suppress(order: np.ndarray, xy: np.ndarray, diag: np.ndarray, group: np.ndarray, labels: np.ndarray,
              sq_radius: float, eps: float, redundancy: bool, distance_offset: float, keep: np.ndarray,
              largest: np.ndarray) -> None:  # pragma: no cover - compiled
    count = order.shape[0]
    rank = np.empty(count, dtype=np.int64)
    for r in range(count):
        rank[order[r]] = r
    # Grid cells at least a radius wide (one per group for an infinite radius), with a margin cell on every
    # side, keyed (group, column, row): a candidate's close pairs lie in the 3 x 3 cells around its own.
    finite = sq_radius < np.inf
    width = max(math.sqrt(sq_radius) * (1 + 1e-9), 1e-3) if finite else 1.0
    low_x, low_y = xy[:, 0].min(), xy[:, 1].min()
    columns = int((xy[:, 0].max() - low_x) / width) + 3 if finite else 3
    rows = int((xy[:, 1].max() - low_y) / width) + 3 if finite else 3
    key = np.empty(count, dtype=np.int64)
    for i in range(count):
        column = int(math.floor((xy[i, 0] - low_x) / width)) + 1 if finite else 1
        row = int(math.floor((xy[i, 1] - low_y) / width)) + 1 if finite else 1
        key[i] = (group[i] * columns + column) * rows + row
    by_key = np.argsort(key)
    sorted_key = key[by_key]
    # start[s, c] and stop[s, c]: the run of sorted keys in column offset c - 1 of the candidate at sorted
    # position s, rows -1 .. +1; the bounds only move forward as s does (two pointers per column offset).
    start = np.empty((count, 3), dtype=np.int64)
    stop = np.empty((count, 3), dtype=np.int64)
    for c in range(3):
        lo = 0
        hi = 0
        for s in range(count):
            centre = sorted_key[s] + (c - 1) * rows
            while lo < count and sorted_key[lo] < centre - 1:
                lo += 1
            while hi < count and sorted_key[hi] <= centre + 1:
                hi += 1
            start[s, c] = lo
            stop[s, c] = hi
    # The scan reads the candidates in key order: positions, ranks, diagonals and decisions stored that way.
    sx, sy, srank, sdiag = xy[by_key, 0], xy[by_key, 1], rank[by_key], diag[by_key]
    skeep = np.ones(count, dtype=np.bool_)
    position = np.empty(count, dtype=np.int64)
    for s in range(count):
        position[by_key[s]] = s
    for r in range(count):
        s = position[order[r]]
        x, y, label = sx[s], sy[s], labels[order[r]]
        kept = True
        for c in range(3):
            for t in range(start[s, c], stop[s, c]):
                if srank[t] >= r:  # not earlier than this candidate (or itself): that pair is seen from t
                    continue
                dx = x - sx[t]
                dy = y - sy[t]
                sq_distance = dx * dx + dy * dy
                if not sq_distance <= sq_radius:
                    continue
                if redundancy:
                    redundant = True
                    for d in range(sdiag.shape[1]):
                        if not sdiag[s, d] - sdiag[t, d] + eps >= 0:
                            redundant = False
                            break
                    if not redundant:
                        continue
                value = sq_distance + distance_offset
                if value > largest[label]:
                    largest[label] = value
                if skeep[t]:
                    kept = False
        skeep[s] = kept
    for s in range(count):
        keep[by_key[s]] = skeep[s]
