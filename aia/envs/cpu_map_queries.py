"""Per-world map queries on the CPU (the maps of :class:`aia.envs.sensing.WorldMapGeometry`): numba kernels that
read only the cells an answer needs, run on torch's CPU threads (:mod:`aia.runtime.cpu_threads`) and called from
a compiled step as operators of their own (``aia::ray_walk``, ``aia::near_occupied``, ``aia::line_of_sight``).

What makes them cheap is one distance field per map, over squares of ``BLOCK x BLOCK`` cells: each square's
chessboard distance in squares to the nearest square holding an occupied cell (made for the worlds whose maps
change, at their reset, from the maps' runs of occupied cells: :func:`block_fields`; :func:`free_radius` turns it
into a radius of cells around any cell that holds no obstacle), and each square's occupied cells as the bits of an
int16. The grids of 4,096 maps (134 MB) do not fit in the caches; their distance fields and bits (8.7 and 17 MB)
do.

* **The closest obstacle in view** (:func:`ray_walk`): the first occupied cell along each ray in the field of
  view. Gathered whole (42 rays of up to about 70 cells at the paper's 0.05 rad spacing, 10 m range and 0.2 m
  cells), it was about 45 of the 57 ms of a compiled step of 4,096 worlds; the walk reads about 170 cells a world
  instead of 3,000. It reads cells in ray order and stops a ray at its first hit, and at the first cell farther
  than the nearest value found so far (the walls' distances included), which leaves the minimum over the rays and
  its first index as they were; from a free cell it jumps over every cell within its free radius. It walks first
  the ray toward the last step's closest obstacle, which is most often near this step's: the other rays then stop
  sooner (the walk of 4,096 worlds, 8 steps of an episode in 8 interleaved rounds: 4.72-5.46 -> 3.97-5.18 ms).
  The cells a ray crosses are the same offsets from any start, and their ``|dcol|`` and ``|drow|`` never
  decrease, so the first cell beyond a radius is a lookup in two tables per ray.
* **Collision** (:func:`near_occupied`): the map cells within ``margin`` of a point are read only when neither its
  cell's free radius nor the squares around it clear them.
* **Line of sight** (:func:`line_of_sight`): the samples of a segment are read in order to the first occupied
  one, only for the segments asked about (those in range and field of view), skipping the cells of free squares.

Every answer is the gathered code's to the bit (the same cells, the same float arithmetic as eager torch;
``tests/envs/test_cpu_map_queries.py``).
"""

from __future__ import annotations

import math

import numba
import numpy as np
import torch
from torch import Tensor

from aia.runtime.cpu_threads import (
    array1,
    array2,
    array3,
    descriptor,
    in_chunks,
    in_float_dtype,
    integer,
    kernel_entry,
    real,
    run_kernel,
)

# Squares of 4 x 4 cells (2 ** BLOCK_SHIFT): 46 x 46 of them on a 181 x 181 map; finer squares prove more cells
# free but cost their map-time distance field more, coarser ones prove fewer. A constant of the kernels, so that
# finding a cell's square is a shift, and a square's 16 cells are the bits of an int16.
BLOCK_SHIFT = 2
BLOCK = 1 << BLOCK_SHIFT


class CpuMapQueries:
    """The queries of ``num_worlds`` maps of ``shape`` cells of ``resolution`` metres: their block distances
    (:meth:`update` after maps are set from grids; generated maps get theirs as they are drawn,
    :meth:`aia.envs.map_generator.RandomObstacles.generate`) and the tables of the rays ``(ray_cols, ray_rows,
    ray_distances)`` (each ``[num_bins, L]``, the cells of :func:`aia.envs.sensing._ray_offsets`, in order, padded
    with the start cell at ``inf``). A query's leading dimension is the world: ``[B, ...]``, world ``b``'s map for
    row ``b``.

    ``block_distance [B, nby, nbx]`` holds each block's chessboard distance in blocks to the nearest block with an
    occupied cell, ``block_cells [B, nby, nbx]`` its occupied cells as bits (:func:`occupied_cell`), which the
    walk and the lines of sight read instead of the grids."""

    def __init__(self, num_worlds: int, shape: tuple[int, int], resolution: float, ray_cols: Tensor,
                 ray_rows: Tensor, ray_distances: Tensor) -> None:
        self.shape, self.resolution = shape, resolution
        self.distances = ray_distances.cpu()
        self.lengths = torch.isfinite(self.distances).sum(-1)
        # The walk's tables in int16, to stay in the core's caches (a ray of up to 32,767 cells).
        self.cols, self.rows = ray_cols.cpu().to(torch.int16), ray_rows.cpu().to(torch.int16)
        self.first_col = _first_reaching(ray_cols.abs(), self.lengths).to(torch.int16)
        self.first_row = _first_reaching(ray_rows.abs(), self.lengths).to(torch.int16)
        self.reach_distance = _reach_distances(self.distances, self.lengths, self.first_col, self.first_row)
        blocks = (math.ceil(shape[0] / BLOCK), math.ceil(shape[1] / BLOCK))
        self.block_distance = torch.zeros(num_worlds, *blocks, dtype=torch.uint8)
        self.block_cells = torch.zeros(num_worlds, *blocks, dtype=torch.int16)

    def update(self, occupancy: Tensor, worlds: Tensor) -> None:
        """Recompute the block distances and cells of the worlds ``worlds [K]`` from their maps in ``occupancy [B, ny,
        nx]``."""
        worlds = worlds.cpu().to(torch.int64).contiguous()
        run_kernel(_block_distances_entry, worlds.shape[0],
                   (occupancy.contiguous(), worlds, self.block_distance, self.block_cells))

    def hits(self, row: Tensor, col: Tensor, bins: Tensor, bound: Tensor, lead: Tensor) -> Tensor:
        """``[B, ..., F]``: in world ``b``'s map, from the centre of each cell ``(row[b, ...], col[b, ...])``, along
        each ray ``bins[b, ..., F]``, the smaller of ``bound [B, ..., F]`` and the distance to where the ray
        enters its first occupied cell (leaving the grid is a hit). A ray whose first hit lies beyond its row's
        minimum may keep its ``bound`` instead: the minimum and its first index are exact.

        ``lead [B, ...]``: the position in ``F`` of the ray to walk first (-1: none), e.g. the one toward the last
        step's closest obstacle. It changes which rays stop early, never the minimum or its first index."""
        F = bins.shape[-1]
        out = ray_walk(self.block_distance, self.block_cells, *self.shape, row.reshape(-1), col.reshape(-1),
                       bins.reshape(-1, F), bound.reshape(-1, F), lead.reshape(-1), self.cols, self.rows,
                       self.distances, self.lengths, self.first_col, self.first_row, self.reach_distance)
        return out.view(bound.shape)

    def near_occupied(self, occupancy: Tensor, fine_row: Tensor, fine_col: Tensor, margin: float,
                      supersample: int) -> Tensor:
        """``[B, ...]``: whether the centre of each fine cell ``(fine_row, fine_col)`` (``[B, ...]``, cells
        ``supersample`` times finer than the map's) lies within ``margin`` of the bounds or of an occupied cell's
        square of its world's map: :func:`aia.envs.sensing._near_occupied`, bit for bit."""
        out = near_occupied(occupancy, self.block_distance, fine_row.reshape(-1), fine_col.reshape(-1),
                            self.resolution, margin, supersample)
        return out.view(fine_row.shape)

    def line_of_sight(self, origin: Tensor, target: Tensor, wanted: Tensor, fraction: Tensor) -> Tensor:
        """``[B, ...]``: where ``wanted [B, ...]``, whether no sample ``origin + (target - origin) * fraction[k]``
        (``[B, ..., 2]``) of the segment lies in an occupied cell of its world's map (False elsewhere):
        :meth:`aia.envs.sensing.Geometry.line_of_sight`, bit for bit."""
        cell = torch.tensor([self.resolution], dtype=origin.dtype)
        out = line_of_sight(self.block_cells, *self.shape, origin.reshape(-1, 2), target.reshape(-1, 2),
                            wanted.reshape(-1), fraction.cpu(), cell)
        return out.view(wanted.shape)


def _first_reaching(offsets: Tensor, lengths: Tensor) -> Tensor:
    """``[num_bins, A + 1]``: for each ray and each ``a``, the index of its first cell with ``offsets >= a``
    (its length when none)."""
    reach = int(offsets.max()) + 1
    first = torch.empty(offsets.shape[0], reach + 1, dtype=torch.int64)
    for b, n in enumerate(lengths.tolist()):
        first[b] = torch.searchsorted(offsets[b, :n].contiguous(), torch.arange(reach + 1), side="left")
    return first


def _reach_distances(distances: Tensor, lengths: Tensor, first_col: Tensor, first_row: Tensor) -> Tensor:
    """``[A]``: for each chessboard radius ``a``, the nearest any ray enters its first cell beyond ``a`` of its start
    (``inf`` where none has one): a bound on every ray's hit from a cell whose free radius is ``a``."""
    reach = min(first_col.shape[1], first_row.shape[1])
    index = torch.minimum(first_col[:, :reach], first_row[:, :reach]).long()  # [num_bins, A]
    entry = torch.gather(distances, 1, index.clamp_max(distances.shape[1] - 1))
    return torch.where(index < lengths[:, None], entry, math.inf).amin(0)


@torch.library.custom_op("aia::ray_walk", mutates_args=())
def ray_walk(block_distance: Tensor, block_cells: Tensor, ny: int, nx: int, row: Tensor, col: Tensor, bins: Tensor,
             bound: Tensor, lead: Tensor, cols: Tensor, rows: Tensor, distances: Tensor, lengths: Tensor,
             first_col: Tensor, first_row: Tensor, reach_distance: Tensor) -> Tensor:
    """:meth:`CpuMapQueries.hits` of ``Q`` queries (``row``, ``col``, ``lead`` ``[Q]``, ``bins``, ``bound``
    ``[Q, F]``), query ``q`` in the map (``ny x nx`` cells) of world ``q // (Q // B)``: an operator of its own,
    opaque to ``torch.compile`` (a compiled step calls it)."""
    out = torch.empty_like(bound)
    args = tuple(t.contiguous() for t in (row, col, bins, bound, lead, cols, rows, distances, lengths, first_col,
                                          first_row, reach_distance))
    run_kernel(_walk_entry, row.shape[0], (block_distance, block_cells, ny, nx, *args,
                                           row.shape[0] // block_distance.shape[0], out, bound.element_size()))
    return out


@ray_walk.register_fake
def _(block_distance, block_cells, ny, nx, row, col, bins, bound, lead, cols, rows, distances, lengths, first_col,
      first_row, reach_distance):
    return torch.empty_like(bound)


@torch.library.custom_op("aia::near_occupied", mutates_args=())
def near_occupied(occupancy: Tensor, block_distance: Tensor, fine_row: Tensor, fine_col: Tensor, resolution: float,
                  margin: float, supersample: int) -> Tensor:
    """:meth:`CpuMapQueries.near_occupied` of ``Q`` points (``fine_row``, ``fine_col`` ``[Q]``), point ``q`` in the
    map of world ``q // (Q // B)``: an operator of its own, opaque to ``torch.compile``."""
    out = torch.empty(fine_row.shape, dtype=torch.bool)
    run_kernel(_near_occupied_entry, fine_row.shape[0],
               (occupancy.contiguous(), block_distance, fine_row.contiguous(), fine_col.contiguous(), resolution,
                margin, supersample, out))
    return out


@near_occupied.register_fake
def _(occupancy, block_distance, fine_row, fine_col, resolution, margin, supersample):
    return torch.empty(fine_row.shape, dtype=torch.bool, device=fine_row.device)


@torch.library.custom_op("aia::line_of_sight", mutates_args=())
def line_of_sight(block_cells: Tensor, ny: int, nx: int, origin: Tensor, target: Tensor, wanted: Tensor,
                  fraction: Tensor, cell: Tensor) -> Tensor:
    """:meth:`CpuMapQueries.line_of_sight` of ``Q`` segments (``origin``, ``target`` ``[Q, 2]``, ``wanted [Q]``),
    segment ``q`` in the map (``ny x nx`` cells) of world ``q // (Q // B)``, with the cell size ``cell [1]`` in
    their dtype."""
    out = torch.empty(wanted.shape, dtype=torch.bool)
    run_kernel(_sight_entry, wanted.shape[0], (block_cells, ny, nx, origin.contiguous(), target.contiguous(),
                                               wanted.contiguous(), fraction.contiguous(), cell, out,
                                               origin.element_size()))
    return out


@line_of_sight.register_fake
def _(block_cells, ny, nx, origin, target, wanted, fraction, cell):
    return torch.empty(wanted.shape, dtype=torch.bool, device=wanted.device)


@numba.njit(cache=True, nogil=True)
def _block_distances(occupied, worlds, out, cells, start, stop):  # pragma: no cover - compiled
    """For each world ``w`` in ``worlds[start:stop]``: :func:`block_fields` of the runs of ``occupied[w]``."""
    runs = runs_scratch(occupied.shape[1], occupied.shape[2])
    far, bits = block_scratch(out.shape[1], out.shape[2])
    for w in worlds[start:stop]:
        block_fields(runs[:grid_runs(occupied[w], runs)], out[w], cells[w], far, bits)


@numba.njit(cache=True, nogil=True)
def runs_scratch(ny, nx):  # pragma: no cover - compiled
    """The ``runs`` array :func:`grid_runs` fills for grids of ``ny x nx`` cells: a row holds at most
    ``ceil(nx / 2)`` runs."""
    return np.empty((ny * ((nx + 1) // 2), 3), dtype=np.int64)


@numba.njit(cache=True, nogil=True)
def grid_runs(grid, runs):  # pragma: no cover - compiled
    """Write the occupied runs of ``grid [ny, nx]`` (row, first and last column of each, row by row, left to right)
    into ``runs`` (:func:`runs_scratch`) and return their number."""
    ny, nx = grid.shape
    n = 0
    for r in range(ny):
        col = 0
        while col < nx:
            if grid[r, col]:
                lo = col
                while col < nx and grid[r, col]:
                    col += 1
                runs[n, 0], runs[n, 1], runs[n, 2] = r, lo, col - 1
                n += 1
            col += 1
    return n


@numba.njit(cache=True, nogil=True)
def block_scratch(nby, nbx):  # pragma: no cover - compiled
    """The scratch arrays :func:`block_fields` takes for maps of ``nby x nbx`` blocks."""
    return np.empty((nby + 2, nbx + 2), dtype=np.int32), np.empty((nby, nbx), dtype=np.int32)


@numba.njit(cache=True, nogil=True)
def block_fields(runs, distance, cells, far, bits):  # pragma: no cover - compiled
    """A map's :attr:`CpuMapQueries.block_cells` into ``cells [nby, nbx]`` and :attr:`CpuMapQueries.block_distance`
    into ``distance [nby, nbx]`` from its occupied cells, given as ``runs [n, 3]`` (row, first and last column;
    in any order, overlaps allowed): each block's occupied cells as bits (:func:`occupied_cell`), and its chessboard
    distance in blocks to the nearest block with an occupied cell (0: its own; 255 at most) by the two passes of a
    3 x 3 chamfer with unit weights over the blocks, bordered by a ring that is never nearer. ``far`` and ``bits``:
    :func:`block_scratch`.

    Made from the runs, not the grid: a generated map's runs are at hand while it is drawn (a grid of 181 x 181
    cells has about 150), so new maps for 4,096 worlds skip reading their 134 MB of grids again."""
    nby, nbx = distance.shape
    far[:] = 255
    bits[:] = 0
    for k in range(runs.shape[0]):
        r, lo, hi = runs[k, 0], runs[k, 1], runs[k, 2]
        shift = (r & (BLOCK - 1)) << BLOCK_SHIFT
        row_bits = bits[r >> BLOCK_SHIFT]
        for j in range(lo >> BLOCK_SHIFT, (hi >> BLOCK_SHIFT) + 1):
            first, last = max(lo, j << BLOCK_SHIFT), min(hi, (j << BLOCK_SHIFT) + BLOCK - 1)
            row_bits[j] |= (((1 << (last - first + 1)) - 1) << (first & (BLOCK - 1))) << shift
    for i in range(nby):
        for j in range(nbx):
            value = bits[i, j]
            cells[i, j] = np.int16(value if value < 1 << 15 else value - (1 << 16))
            if value:
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
            distance[i, j] = min(far[i + 1, j + 1], 255)


@numba.njit(cache=True, nogil=True)
def _walk(block_distance, block_cells, ny, nx, row, col, bins, bound, lead, cols, rows, distances, lengths,
          first_col, first_row, reach_distance, per_world, out, start, stop):  # pragma: no cover - compiled
    for q in range(start, stop):
        w = q // per_world
        r0, c0 = row[q], col[q]
        best = bound[q, 0]
        for f in range(bins.shape[1]):
            best = min(best, bound[q, f])
        # Every ray starts in the robot's cell: its free radius, once for all of them. When every ray's first cell
        # beyond it lies farther than the nearest value, each keeps its bound.
        origin_radius = free_radius(block_distance, w, r0, c0, ny, nx)
        if origin_radius < reach_distance.shape[0] and reach_distance[origin_radius] > best:
            out[q] = bound[q]
            continue
        # The lead ray first: a near hit there stops the others sooner.
        first = lead[q]
        for k in range(-1, bins.shape[1]):
            f = first if k < 0 else k
            if f < 0 or (k >= 0 and k == first):
                continue
            b = bins[q, f]
            value = bound[q, f]
            i, n = 0, lengths[b]
            if origin_radius > 1:
                i = _beyond(first_col, first_row, b, 0, 0, origin_radius, n)
            while i < n:
                d = distances[b, i]
                if d > best:
                    break
                r, c = r0 + rows[b, i], c0 + cols[b, i]
                if r < 0 or r >= ny or c < 0 or c >= nx:
                    value = min(value, d)
                    break
                radius = free_radius(block_distance, w, r, c, ny, nx)
                if radius == 0:  # a block with an occupied cell: this cell is read
                    if occupied_cell(block_cells, w, r, c):
                        value = min(value, d)
                        break
                    i += 1
                elif radius == 1:
                    i += 1
                else:
                    i = _beyond(first_col, first_row, b, cols[b, i], rows[b, i], radius, n)
            out[q, f] = value
            best = min(best, value)


@numba.njit(inline="always", nogil=True)
def _cell_bit(r, c):  # pragma: no cover - compiled
    """The bit of cell ``(r, c)`` in its block's :attr:`CpuMapQueries.block_cells` (row-major in the block)."""
    return ((r & (BLOCK - 1)) << BLOCK_SHIFT) | (c & (BLOCK - 1))


@numba.njit(inline="always", nogil=True)
def occupied_cell(block_cells, w, r, c):  # pragma: no cover - compiled
    """Whether cell ``(r, c)`` (inside the grid) of world ``w``'s map is occupied, read from its block's bits (the
    blocks' 17 MB for 4,096 maps stay in the caches where the grids' 134 MB do not)."""
    return (block_cells[w, r >> BLOCK_SHIFT, c >> BLOCK_SHIFT] >> _cell_bit(r, c)) & 1 != 0


@numba.njit(inline="always", nogil=True)
def free_radius(block_distance, w, r, c, ny, nx):  # pragma: no cover - compiled
    """The chessboard radius around cell ``(r, c)`` (inside the grid) whose cells all lie in free blocks and inside
    the grid (at least 1 when the cell's block is free); 0 when its block holds an occupied cell."""
    br, bc = r >> BLOCK_SHIFT, c >> BLOCK_SHIFT
    near = np.int64(block_distance[w, br, bc])
    if near == 0:
        return 0
    return min(((br + near) << BLOCK_SHIFT) - r, r + 1 - ((br - near + 1) << BLOCK_SHIFT),
               ((bc + near) << BLOCK_SHIFT) - c, c + 1 - ((bc - near + 1) << BLOCK_SHIFT),
               r + 1, ny - r, c + 1, nx - c)


@numba.njit(inline="always", nogil=True)
def _beyond(first_col, first_row, b, dcol, drow, radius, n):  # pragma: no cover - compiled
    """The index of ray ``b``'s first cell beyond chessboard ``radius`` of its cell ``(drow, dcol)`` (``n``: none):
    the ray's ``|dcol|`` and ``|drow|`` never decrease, so it is the first reaching either bound."""
    j = n
    a, e = abs(dcol) + radius, abs(drow) + radius
    if a < first_col.shape[1]:
        j = min(j, first_col[b, a])
    if e < first_row.shape[1]:
        j = min(j, first_row[b, e])
    return j


@numba.njit(cache=True, nogil=True)
def _near_occupied(occupied, block_distance, fine_row, fine_col, resolution, margin, supersample, out, start,
                   stop):  # pragma: no cover - compiled
    """``out[q]`` for ``q`` in ``start..stop - 1``: :func:`fine_cell_near_occupied` of fine cell ``q`` in the map of
    world ``q // (Q // B)``."""
    ny, nx = occupied.shape[1], occupied.shape[2]
    per_world = fine_row.shape[0] // occupied.shape[0]
    reach = math.ceil(margin / resolution)
    for q in range(start, stop):
        w = q // per_world
        row, col = fine_row[q] // supersample, fine_col[q] // supersample
        # The cells within reach are free when the squares they lie in are (at most 3 x 3 squares at the
        # paper's margin, against 7 x 7 cells).
        clear = free_radius(block_distance, w, row, col, ny, nx) > reach
        if not clear:
            clear = True
            for br in range(max(row - reach, 0) >> BLOCK_SHIFT, (min(row + reach, ny - 1) >> BLOCK_SHIFT) + 1):
                for bc in range(max(col - reach, 0) >> BLOCK_SHIFT, (min(col + reach, nx - 1) >> BLOCK_SHIFT) + 1):
                    clear = clear and block_distance[w, br, bc] > 0
        out[q] = fine_cell_near_occupied(occupied[w], fine_row[q], fine_col[q], resolution, supersample, margin,
                                         reach + 1 if clear else 0)


@numba.njit(cache=True, nogil=True)
def fine_cell_near_occupied(occupied, fine_row, fine_col, resolution, supersample, margin,
                            free):  # pragma: no cover - compiled
    """:func:`aia.envs.sensing._near_occupied` for the fine cell ``(fine_row, fine_col)`` (inside the grid) on the
    map ``occupied [ny, nx]``, in its float64 arithmetic: whether its centre lies within ``margin`` of the bounds or
    of an occupied cell's square. ``free``: a chessboard radius around its map cell known to hold no occupied cell
    (:func:`free_radius`; 0 where none is known), which spares reading the cells within the margin's reach."""
    ny, nx = occupied.shape
    fine = resolution / supersample
    px = (np.float64(fine_col) + 0.5) * fine
    py = (np.float64(fine_row) + 0.5) * fine
    if px < margin or px > nx * resolution - margin or py < margin or py > ny * resolution - margin:
        return True
    reach = math.ceil(margin / resolution)
    if free > reach:
        return False
    row, col = fine_row // supersample, fine_col // supersample
    for dr in range(-reach, reach + 1):
        r = min(max(row + dr, 0), ny - 1)
        y0 = r * resolution
        dy = max(max(y0 - py, py - (y0 + resolution)), 0.0)
        for dc in range(-reach, reach + 1):
            c = min(max(col + dc, 0), nx - 1)
            if occupied[r, c]:
                x0 = c * resolution
                dx = max(max(x0 - px, px - (x0 + resolution)), 0.0)
                if dx * dx + dy * dy < margin * margin:
                    return True
    return False


@numba.njit(cache=True, nogil=True)
def _sight(block_cells, ny, nx, origin, target, wanted, fraction, cell, out, start,
           stop):  # pragma: no cover - compiled
    """``out[q]`` for ``q`` in ``start..stop - 1``: whether segment ``q`` is wanted and none of its samples lies in an
    occupied cell of the map (``ny x nx`` cells) of world ``q // (Q // B)``, in the dtype of ``origin`` (as eager
    torch computes it)."""
    per_world = origin.shape[0] // block_cells.shape[0]
    size = cell[0]
    for q in range(start, stop):
        clear = wanted[q]
        if clear:
            w = q // per_world
            ox, oy = origin[q, 0], origin[q, 1]
            dx, dy = target[q, 0] - ox, target[q, 1] - oy
            for k in range(fraction.shape[0]):
                c = min(max(math.floor((ox + dx * fraction[k]) / size), 0), nx - 1)
                r = min(max(math.floor((oy + dy * fraction[k]) / size), 0), ny - 1)
                if occupied_cell(block_cells, w, r, c):
                    clear = False
                    break
        out[q] = clear


# The kernels' entries (compiled on their first run).
@kernel_entry("bool[3]", "int64[1]", "uint8[3]", "int16[3]")
def _block_distances_entry(data):  # pragma: no cover - compiled
    """:func:`_block_distances` of the arguments ``(occupied, worlds, out, cells)``, chunk by chunk of ``worlds``."""
    d = descriptor(data)
    occupied, worlds, out = array3(d, 0, np.bool_), array1(d, 1, np.int64), array3(d, 2, np.uint8)
    in_chunks(d, _block_distances, (occupied, worlds, out, array3(d, 3, np.int16)))


@numba.njit(inline="always", nogil=True)
def _walk_share(data, dtype):  # pragma: no cover - compiled
    """:func:`_walk` of the arguments of :func:`ray_walk` and ``(per_world, out)``, chunk by chunk of the queries,
    with ``bound``, ``distances`` and ``out`` of ``dtype``."""
    d = descriptor(data)
    block_distance, block_cells = array3(d, 0, np.uint8), array3(d, 1, np.int16)
    row, col, bins, bound = array1(d, 4, np.int64), array1(d, 5, np.int64), array2(d, 6, np.int64), array2(d, 7, dtype)
    lead, cols, rows = array1(d, 8, np.int64), array2(d, 9, np.int16), array2(d, 10, np.int16)
    distances, lengths = array2(d, 11, dtype), array1(d, 12, np.int64)
    first_col, first_row, reach_distance = array2(d, 13, np.int16), array2(d, 14, np.int16), array1(d, 15, dtype)
    per_world, out = integer(d, 16), array2(d, 17, dtype)
    in_chunks(d, _walk, (block_distance, block_cells, integer(d, 2), integer(d, 3), row, col, bins, bound, lead, cols,
                         rows, distances, lengths, first_col, first_row, reach_distance, per_world, out))


@kernel_entry("uint8[3]", "int16[3]", "int", "int", "int64[1]", "int64[1]", "int64[2]", "real[2]", "int64[1]",
              "int16[2]", "int16[2]", "real[2]", "int64[1]", "int16[2]", "int16[2]", "real[1]", "int", "real[2]",
              "real_size")
def _walk_entry(data):  # pragma: no cover - compiled
    """:func:`_walk_share` in the dtype whose size in bytes is argument 18."""
    in_float_dtype(data, 18, _walk_share)


@kernel_entry("bool[3]", "uint8[3]", "int64[1]", "int64[1]", "float", "float", "int", "bool[1]")
def _near_occupied_entry(data):  # pragma: no cover - compiled
    """:func:`_near_occupied` of the arguments of :func:`near_occupied` and ``out``, chunk by chunk of the points."""
    d = descriptor(data)
    occupied, block_distance = array3(d, 0, np.bool_), array3(d, 1, np.uint8)
    fine_row, fine_col, out = array1(d, 2, np.int64), array1(d, 3, np.int64), array1(d, 7, np.bool_)
    in_chunks(d, _near_occupied, (occupied, block_distance, fine_row, fine_col, real(d, 4), real(d, 5), integer(d, 6),
                                  out))


@numba.njit(inline="always", nogil=True)
def _sight_share(data, dtype):  # pragma: no cover - compiled
    """:func:`_sight` of the arguments of :func:`line_of_sight` and ``out``, chunk by chunk of the segments, with
    ``origin``, ``target``, ``fraction`` and ``cell`` of ``dtype``."""
    d = descriptor(data)
    block_cells, ny, nx = array3(d, 0, np.int16), integer(d, 1), integer(d, 2)
    origin, target, wanted = array2(d, 3, dtype), array2(d, 4, dtype), array1(d, 5, np.bool_)
    fraction, cell, out = array1(d, 6, dtype), array1(d, 7, dtype), array1(d, 8, np.bool_)
    in_chunks(d, _sight, (block_cells, ny, nx, origin, target, wanted, fraction, cell, out))


@kernel_entry("int16[3]", "int", "int", "real[2]", "real[2]", "bool[1]", "real[1]", "real[1]", "bool[1]", "real_size")
def _sight_entry(data):  # pragma: no cover - compiled
    """:func:`_sight_share` in the dtype whose size in bytes is argument 9."""
    in_float_dtype(data, 9, _sight_share)
