"""The first occupied cell along the rays in view, on per-world maps, on the CPU: a numba kernel that walks each ray
and jumps over the cells a coarse distance field proves free.

:class:`aia.envs.sensing.WorldMapGeometry` asks, every step and for every world, how far each ray in the field of
view goes before it enters an occupied cell. Done as gathers (every cell of every ray in view: 42 rays of up to
about 70 cells at the paper's 0.05 rad spacing, 10 m range and 0.2 m cells), it was about 45 of the 57 ms of a
compiled step of 4,096 worlds (``random_obstacles``); walked, it is 11 of 23 ms (2.4x the env's frames/s; about
170 cells read a world instead of 3,000; docs/speed.md). The walk reads cells in ray order and

* stops a ray at its first hit, and at the first cell farther than the nearest value found so far (the walls'
  distances included), which leaves the minimum over the rays and its first index as they were;
* jumps, from a free cell, over every cell within the Chebyshev radius that the *block distance* proves free:
  the map is cut into squares of ``BLOCK x BLOCK`` cells, and for each square the chessboard distance in squares to the
  nearest square holding an occupied cell (recomputed for the worlds whose maps change, at their reset). The
  cells a ray crosses are the same offsets from any start, and their ``|dcol|`` and ``|drow|`` never decrease,
  so the first cell beyond the radius is a lookup in two tables per ray.

Every hit is the gathered code's to the bit (same cells, same precomputed distances;
``tests/envs/test_ray_walk.py``). Inside a compiled step the second thread gains nothing (the compiled kernels'
OpenMP threads spin on the other core after their loops: the step takes the same time with the walk on one
thread; ``OMP_WAIT_POLICY=PASSIVE`` takes 15 % off it).
"""

from __future__ import annotations

import math

import numba
import numpy as np
import torch
from torch import Tensor

from aia.runtime.cpu_threads import in_shares

# Squares of 4 x 4 cells (2 ** BLOCK_SHIFT): 46 x 46 of them on a 181 x 181 map; finer squares prove more cells
# free but cost their map-time distance field more, coarser ones prove fewer. A constant of the kernels, so that
# finding a cell's square is a shift.
BLOCK_SHIFT = 2
BLOCK = 1 << BLOCK_SHIFT


class RayWalk:
    """The walk's tables for the rays ``(ray_cols, ray_rows, ray_distances)`` (each ``[num_bins, L]``, the cells
    of :func:`aia.envs.sensing._ray_offsets`, in order, padded with the start cell at ``inf``) on ``num_worlds``
    maps of ``shape``, and the maps' block distances (:meth:`update` after the maps change)."""

    def __init__(self, num_worlds: int, shape: tuple[int, int], ray_cols: Tensor, ray_rows: Tensor,
                 ray_distances: Tensor) -> None:
        self.cols, self.rows, self.distances = ray_cols.cpu(), ray_rows.cpu(), ray_distances.cpu()
        self.lengths = torch.isfinite(self.distances).sum(-1)
        self.first_col = _first_reaching(self.cols.abs(), self.lengths)
        self.first_row = _first_reaching(self.rows.abs(), self.lengths)
        blocks = (math.ceil(shape[0] / BLOCK), math.ceil(shape[1] / BLOCK))
        self.block_distance = torch.zeros(num_worlds, *blocks, dtype=torch.uint8)

    def update(self, occupancy: Tensor, worlds: Tensor) -> None:
        """Recompute the block distances of the worlds ``worlds [K]`` from their maps in ``occupancy [B, ny, nx]``."""
        occupied, out, rows = occupancy.numpy(), self.block_distance.numpy(), worlds.cpu().numpy().astype(np.int64)
        in_shares(lambda start, stop: _block_distances(occupied, rows[start:stop], out), rows.shape[0])

    def hits(self, occupancy: Tensor, row: Tensor, col: Tensor, bins: Tensor, bound: Tensor) -> Tensor:
        """``[B, ..., F]``: in world ``b``'s map, from the centre of each cell ``(row[b, ...], col[b, ...])``, along
        each ray ``bins[b, ..., F]``, the smaller of ``bound [B, ..., F]`` and the distance to where the ray
        enters its first occupied cell (leaving the grid is a hit). A ray whose first hit lies beyond its row's
        minimum may keep its ``bound`` instead: the minimum and its first index are exact."""
        F = bins.shape[-1]
        out = ray_walk(occupancy, self.block_distance, row.reshape(-1), col.reshape(-1), bins.reshape(-1, F),
                       bound.reshape(-1, F), self.cols, self.rows, self.distances, self.lengths, self.first_col,
                       self.first_row)
        return out.view(bound.shape)


def _first_reaching(offsets: Tensor, lengths: Tensor) -> Tensor:
    """``[num_bins, A + 1]``: for each ray and each ``a``, the index of its first cell with ``offsets >= a``
    (its length when none)."""
    reach = int(offsets.max()) + 1
    first = torch.empty(offsets.shape[0], reach + 1, dtype=torch.int64)
    for b, n in enumerate(lengths.tolist()):
        first[b] = torch.searchsorted(offsets[b, :n].contiguous(), torch.arange(reach + 1), side="left")
    return first


@torch.library.custom_op("aia::ray_walk", mutates_args=())
def ray_walk(occupancy: Tensor, block_distance: Tensor, row: Tensor, col: Tensor, bins: Tensor, bound: Tensor,
             cols: Tensor, rows: Tensor, distances: Tensor, lengths: Tensor, first_col: Tensor, first_row: Tensor
             ) -> Tensor:
    """:meth:`RayWalk.hits` of ``Q`` queries (``row``, ``col`` ``[Q]``, ``bins``, ``bound`` ``[Q, F]``), query ``q``
    in the map of world ``q // (Q // B)``: an operator of its own, opaque to ``torch.compile`` (a compiled step
    calls it)."""
    out = torch.empty_like(bound)
    args = tuple(t.contiguous().numpy() for t in (occupancy, block_distance, row, col, bins, bound, cols, rows,
                                                  distances, lengths, first_col, first_row))
    result, per_world = out.numpy(), row.shape[0] // occupancy.shape[0]
    in_shares(lambda start, stop: _walk(*args, per_world, result, start, stop), row.shape[0])
    return out


@ray_walk.register_fake
def _(occupancy, block_distance, row, col, bins, bound, cols, rows, distances, lengths, first_col, first_row):
    return torch.empty_like(bound)


@numba.njit(cache=True, nogil=True)
def _block_distances(occupied, worlds, out):  # pragma: no cover - compiled
    """For each world in ``worlds``: ``out[w]``, each block's chessboard distance in blocks to the nearest block
    with an occupied cell (0: its own; 255 at most), by the two passes of a 3 x 3 chamfer with unit weights over
    the blocks, bordered by a ring that is never nearer."""
    ny, nx = occupied.shape[1], occupied.shape[2]
    nby, nbx = out.shape[1], out.shape[2]
    far = np.empty((nby + 2, nbx + 2), dtype=np.int32)
    seen = np.empty(nbx << BLOCK_SHIFT, dtype=np.uint8)
    for w in worlds:
        far[:] = 255
        for i in range(nby):
            seen[:] = 0
            for r in range(i << BLOCK_SHIFT, min((i + 1) << BLOCK_SHIFT, ny)):
                for c in range(nx):
                    seen[c] |= occupied[w, r, c]
            for j in range(nbx):
                hit = 0
                for c in range(j << BLOCK_SHIFT, (j + 1) << BLOCK_SHIFT):
                    hit |= seen[c]
                if hit:
                    far[i + 1, j + 1] = 0
        for i in range(1, nby + 1):
            for j in range(1, nbx + 1):
                far[i, j] = min(far[i, j], far[i - 1, j - 1] + 1, far[i - 1, j] + 1, far[i - 1, j + 1] + 1,
                                far[i, j - 1] + 1)
        for i in range(nby, 0, -1):
            for j in range(nbx, 0, -1):
                far[i, j] = min(far[i, j], far[i + 1, j + 1] + 1, far[i + 1, j] + 1, far[i + 1, j - 1] + 1,
                                far[i, j + 1] + 1)
        for i in range(nby):
            for j in range(nbx):
                out[w, i, j] = min(far[i + 1, j + 1], 255)


@numba.njit(cache=True, nogil=True)
def _walk(occupied, block_distance, row, col, bins, bound, cols, rows, distances, lengths, first_col, first_row,
          per_world, out, start, stop):  # pragma: no cover - compiled
    ny, nx = occupied.shape[1], occupied.shape[2]
    col_reach, row_reach = first_col.shape[1], first_row.shape[1]
    for q in range(start, stop):
        w = q // per_world
        r0, c0 = row[q], col[q]
        best = bound[q, 0]
        for f in range(bins.shape[1]):
            best = min(best, bound[q, f])
        for f in range(bins.shape[1]):
            b = bins[q, f]
            value = bound[q, f]
            i, n = 0, lengths[b]
            while i < n:
                d = distances[b, i]
                if d > best:
                    break
                r, c = r0 + rows[b, i], c0 + cols[b, i]
                if r < 0 or r >= ny or c < 0 or c >= nx:
                    value = min(value, d)
                    break
                br, bc = r >> BLOCK_SHIFT, c >> BLOCK_SHIFT
                near = np.int64(block_distance[w, br, bc])
                if near == 0:  # a block with an occupied cell: this cell is read
                    if occupied[w, r, c]:
                        value = min(value, d)
                        break
                    i += 1
                    continue
                # The cells within this chessboard radius of (r, c) lie in free blocks and inside the grid.
                radius = min(((br + near) << BLOCK_SHIFT) - r, r + 1 - ((br - near + 1) << BLOCK_SHIFT),
                             ((bc + near) << BLOCK_SHIFT) - c, c + 1 - ((bc - near + 1) << BLOCK_SHIFT),
                             r + 1, ny - r, c + 1, nx - c)
                if radius <= 1:
                    i += 1
                    continue
                j = n
                a, e = abs(cols[b, i]) + radius, abs(rows[b, i]) + radius
                if a < col_reach:
                    j = min(j, first_col[b, a])
                if e < row_reach:
                    j = min(j, first_row[b, e])
                i = j
            out[q, f] = value
            best = min(best, value)
