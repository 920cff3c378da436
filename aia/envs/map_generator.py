"""Random obstacle maps: a new layout per world and episode (``env.map=random_obstacles``).

A layout is drawn from the world's episode key (:class:`aia.rng.WorldStream` ``MAP``), so a world's maps depend on
the seed, its index and its episode count only, never on the batch or on the other worlds. Each of
``num_obstacles`` obstacles (uniform in ``[min, max]``) is one of our procedural ``shapes``, made of
rectangles of ``length`` and ``width`` (each uniform in its ``[min, max]``), turned by a uniform angle within
``+-rotation_deg`` about its centre, which is uniform over the map (an obstacle may stick out of the bounds):

* ``box``: ``length x width``;
* ``l``: two arms, ``length x width`` and ``width x length2`` (a second length draw), joined at a corner;
* ``t``: a bar ``length x width`` and a stem ``width x length2`` down from its middle (the stem's top the bar's).

A cell is occupied when its centre lies in a rectangle (the map loader's rule for rotated boxes).

Episodes start in the layout's *start cells* (:func:`start_cells`): the cells whose whole square is
collision-free (at least ``margin`` from the bounds and from every occupied cell's square, so every point in
them is free) and that belong to the largest 4-connected group of such cells (any two are joined by a free
path, so the robot can reach every target's start). A layout whose start cells cover less than
``min_start_area`` of the map is drawn again from the next counter of the world's stream, up to ``attempts``
times; then the reset fails with a one-line :class:`~aia.config.errors.ConfigError`.

The layouts are one numba kernel, run in torch's CPU threads, each a share of the worlds, and it works on runs
of cells, not on cells: each rectangle's run in a row is found around where the row crosses its sides; the runs,
widened by the margin in their neighbouring rows, block bits of 64 cells; the free runs between them are joined
into groups by union-find; and on the CPU the map's block fields (:func:`aia.envs.cpu_map_queries.block_fields`)
are made from its runs while it is drawn. New maps for 4,096 worlds (181 x 181 cells, 4-8 obstacles), the
draws and the block fields included: 0.103-0.130 s against 0.138-0.181 s cell by cell, three runs of each in
turn (``benchmarks/map_generation.py``); on one thread, 31-37 against 45-48 us a map without the fields.
"""

from __future__ import annotations

import math

import numba
import numpy as np
import torch
from numba.cpython.unsafe.numbers import trailing_zeros
from torch import Tensor

from aia import rng
from aia.config.errors import ConfigError
from aia.envs.config import RANDOM_SHAPES
from aia.envs.cpu_map_queries import block_fields, block_scratch, grid_runs, runs_scratch
from aia.runtime.cpu_threads import (
    array1,
    array2,
    array3,
    descriptor,
    in_chunks,
    integer,
    kernel_entry,
    real,
    run_kernel,
)

# The uniforms one obstacle takes: shape, centre x and y, angle, length, second length, width.
_OBSTACLE_DRAWS = 7


class RandomObstacles:
    """Draws the layouts of :mod:`aia.envs.map_generator` for a :class:`~aia.envs.config.RandomMapConfig`."""

    def __init__(self, config, margin: float) -> None:
        self.config = config
        self.resolution = float(config.resolution)
        self.size = (float(config.size[0]), float(config.size[1]))
        self.shape = (round(self.size[1] / self.resolution), round(self.size[0] / self.resolution))
        self.margin = margin
        self.draws = 1 + _OBSTACLE_DRAWS * int(config.num_obstacles[1])
        self.min_cells = max(1, math.ceil(config.min_start_area * self.shape[0] * self.shape[1]))
        self._shapes = torch.tensor([RANDOM_SHAPES.index(s) for s in config.shapes], dtype=torch.int64)
        self._half_widths = torch.from_numpy(margin_rows(margin, self.resolution))
        self._wall_cells = math.ceil(margin / self.resolution)

    def generate(self, keys: Tensor, worlds: Tensor | None = None, out: tuple[Tensor, Tensor, Tensor] | None = None,
                 fields: tuple[Tensor, Tensor] | None = None) -> tuple[Tensor, Tensor, Tensor]:
        """``(occupancy [K, ny, nx], start_cells [K, ny, nx], row_starts [K, ny])`` (bool, bool, int64; on the CPU:
        each map, its start cells, their number in each row) for the episode keys ``keys [K]``.

        With ``out`` (CPU tensors ``[B, ...]`` of those shapes) key ``i``'s map is written in place into row
        ``worlds[i]`` of each, and ``out`` returned: an env's buffers, filled without a copy. With ``fields``
        (``block_distance``, ``block_cells`` of a :class:`~aia.envs.cpu_map_queries.CpuMapQueries` of the env's
        worlds) the maps' block fields are written there too, made from each map's runs as it is drawn.
        """
        keys = keys.cpu()
        if out is None:
            out = (torch.empty(keys.shape[0], *self.shape, dtype=torch.bool), torch.empty(keys.shape[0], *self.shape,
                   dtype=torch.bool), torch.empty(keys.shape[0], self.shape[0], dtype=torch.int64))
            worlds = torch.arange(keys.shape[0])
        worlds, todo = worlds.cpu().to(torch.int64), torch.arange(keys.shape[0])
        cfg = self.config
        shape_args = (self._shapes, int(cfg.num_obstacles[0]), int(cfg.num_obstacles[1]), float(cfg.length[0]),
                      float(cfg.length[1]), float(cfg.width[0]), float(cfg.width[1]), math.radians(cfg.rotation_deg),
                      self.resolution, self._half_widths, self._wall_cells, *out)
        if fields is None:  # no fields wanted: rows of none
            fields = (torch.empty(0, 1, 1, dtype=torch.uint8), torch.empty(0, 1, 1, dtype=torch.int16))
        for attempt in range(cfg.attempts):
            u = rng.uniform(keys[todo], torch.full_like(todo, attempt), rng.WorldStream.MAP, self.draws, torch.float64)
            rows, counts = worlds[todo].contiguous(), torch.empty(todo.shape[0], dtype=torch.int64)
            # Each layout rasterised by torch's CPU threads (aia.runtime.cpu_threads), a chunk of worlds at a time.
            run_kernel(_layouts_entry, todo.shape[0], (u.contiguous(), rows, *shape_args, *fields, counts))
            todo = todo[counts < self.min_cells]
            if todo.numel() == 0:
                return out
        raise ConfigError("env.random_map", f"{todo.numel()} of {keys.shape[0]} worlds",
                          f"layouts whose connected start cells cover min_start_area={cfg.min_start_area} of the map "
                          f"within attempts={cfg.attempts} draws (fewer, shorter or thinner obstacles)")


def start_cells(occupancy: Tensor, resolution: float, margin: float) -> Tensor:
    """``[K, ny, nx]`` the start cells (see the module docstring) of any maps ``occupancy [K, ny, nx]``."""
    grid = np.ascontiguousarray(occupancy.cpu().numpy().astype(np.bool_))
    starts = np.empty_like(grid)
    row_starts = np.empty(grid.shape[:2], dtype=np.int64)
    _start_cells_all(grid, margin_rows(margin, resolution), math.ceil(margin / resolution), starts, row_starts)
    return torch.from_numpy(starts)


def margin_rows(margin: float, resolution: float) -> np.ndarray:
    """``[2 R + 1]``: for each row offset ``drow`` in ``-R..R``, the largest ``|dcol|`` such that the square of cell
    ``(drow, dcol)`` lies within ``margin`` of the square of cell ``(0, 0)`` (the gap is ``max(|d| - 1, 0)`` cells
    along each axis; -1: none). An occupied cell makes those cells unfit to start in."""
    reach = math.ceil(margin / resolution) + 1
    widths = [max((dc for dc in range(reach + 1)
                   if (max(abs(dr) - 1, 0) ** 2 + max(dc - 1, 0) ** 2) * resolution**2 < margin**2), default=-1)
              for dr in range(-reach, reach + 1)]
    return np.array(widths, dtype=np.int64)


@numba.njit(cache=True, nogil=True)
def _layouts(u, worlds, shapes, count_lo, count_hi, length_lo, length_hi, width_lo, width_hi, rotation, resolution,
             half_widths, wall_cells, occupancy, starts, row_starts, block_distance, block_cells, counts, first,
             last):  # pragma: no cover - compiled
    """For each ``i`` in ``first..last - 1``: rasterise the layout of row ``i`` of ``u`` into ``occupancy[worlds[i]]``
    and its start cells into ``starts[worlds[i]]`` (their number per row into ``row_starts[worlds[i]]``), its
    number of start cells into ``counts[i]`` and, where ``block_distance`` has rows (a CPU env's
    :class:`~aia.envs.cpu_map_queries.CpuMapQueries` fields), its block fields into row ``worlds[i]`` of
    ``block_distance`` and ``block_cells``."""
    ny, nx = occupancy.shape[1], occupancy.shape[2]
    runs = np.empty((2 * count_hi * ny, 3), dtype=np.int64)  # the occupied runs: row, first, last
    scratch = _start_scratch(ny, nx)
    far, bits = block_scratch(block_distance.shape[1], block_distance.shape[2])
    for i in range(first, last):
        grid = occupancy[worlds[i]]
        grid[:] = False
        draws = u[i]
        n = 0
        count = count_lo + min(int(draws[0] * (count_hi - count_lo + 1)), count_hi - count_lo)
        for k in range(count):
            d = draws[1 + 7 * k: 8 + 7 * k]
            shape = shapes[min(int(d[0] * shapes.shape[0]), shapes.shape[0] - 1)]
            cx, cy = d[1] * nx * resolution, d[2] * ny * resolution
            angle = (2.0 * d[3] - 1.0) * rotation
            a = length_lo + d[4] * (length_hi - length_lo)
            b = length_lo + d[5] * (length_hi - length_lo)
            w = width_lo + d[6] * (width_hi - width_lo)
            if shape == 0:    # box
                n = _rectangle(grid, runs, n, resolution, cx, cy, angle, 0.0, 0.0, a / 2, w / 2)
            elif shape == 1:  # l: arms along x and y from a corner, centred on its bounding box
                sx, sy = max(a, w) / 2, max(b, w) / 2
                n = _rectangle(grid, runs, n, resolution, cx, cy, angle, a / 2 - sx, w / 2 - sy, a / 2, w / 2)
                n = _rectangle(grid, runs, n, resolution, cx, cy, angle, w / 2 - sx, b / 2 - sy, w / 2, b / 2)
            else:             # t: a bar and a stem down from its middle, centred on its bounding box
                sy = (w - max(b, w)) / 2
                n = _rectangle(grid, runs, n, resolution, cx, cy, angle, 0.0, -sy, a / 2, w / 2)
                n = _rectangle(grid, runs, n, resolution, cx, cy, angle, 0.0, (w - b) / 2 - sy, w / 2, b / 2)
        counts[i] = _start_cells(runs[:n], half_widths, wall_cells, starts[worlds[i]], row_starts[worlds[i]],
                                 scratch)
        if block_distance.shape[0]:
            block_fields(runs[:n], block_distance[worlds[i]], block_cells[worlds[i]], far, bits)


@numba.njit(cache=True)
def _start_cells_all(occupancy, half_widths, wall_cells, starts, row_starts):  # pragma: no cover - compiled
    ny, nx = occupancy.shape[1:]
    runs = runs_scratch(ny, nx)
    scratch = _start_scratch(ny, nx)
    for i in range(occupancy.shape[0]):
        _start_cells(runs[:grid_runs(occupancy[i], runs)], half_widths, wall_cells, starts[i], row_starts[i], scratch)


# Below this |cos| or |sin| of a rectangle's angle, a row's cells are all tested (see _rectangle).
_STEEP = 1e-6


@numba.njit(cache=True, nogil=True)
def _rectangle(grid, runs, n, resolution, cx, cy, angle, lx, ly, hx, hy):  # pragma: no cover - compiled
    """Occupy the cells whose centre lies in the rectangle of half extents ``(hx, hy)`` centred at ``(lx, ly)``
    in the frame of an obstacle at ``(cx, cy)`` turned by ``angle`` (a run of cells in each row it covers: the
    rectangle is convex); append the runs to ``runs`` from row ``n`` and return the new number of runs.

    A row's run is the first and the last cell of its bounding box whose centre passes the test. Both lie within
    a cell of where the row's line crosses the rectangle's sides, so only the cells around those crossings are
    tested (2-6 a row, against the whole box: 11 -> 5 us for 8 boxes); where a side is within ``_STEEP``
    of the rows' or columns' direction every cell of the box is tested, as the crossing is then ill-conditioned."""
    c, s = math.cos(angle), math.sin(angle)
    wx, wy = cx + lx * c - ly * s, cy + lx * s + ly * c
    ex, ey = abs(c) * hx + abs(s) * hy, abs(s) * hx + abs(c) * hy
    ny, nx = grid.shape
    # the cells whose centre (i + 0.5) * resolution lies within the rectangle's bounding box
    col0 = max(0, int(math.ceil((wx - ex) / resolution - 0.5)))
    col1 = min(nx - 1, int(math.floor((wx + ex) / resolution - 0.5)))
    row0 = max(0, int(math.ceil((wy - ey) / resolution - 0.5)))
    row1 = min(ny - 1, int(math.floor((wy + ey) / resolution - 0.5)))
    steep = min(abs(c), abs(s)) < _STEEP
    for r in range(row0, row1 + 1):
        dy = (r + 0.5) * resolution - wy
        first, last = col0, col1
        if not steep:
            # |dx c + dy s| <= hx and |dy c - dx s| <= hy, solved for dx, in columns (widened by a cell each way)
            a0, a1 = (-hx - dy * s) / c, (hx - dy * s) / c
            b0, b1 = (dy * c - hy) / s, (dy * c + hy) / s
            low = max(min(a0, a1), min(b0, b1))
            high = min(max(a0, a1), max(b0, b1))
            first = max(first, int(math.ceil(max((wx + low) / resolution - 0.5, col0 - 2.0))) - 1)
            last = min(last, int(math.floor(min((wx + high) / resolution - 0.5, col1 + 2.0))) + 1)
        lo, hi = nx, -1
        for col in range(first, last + 1):
            if _inside(col, resolution, wx, dy, c, s, hx, hy):
                lo = col
                break
        for col in range(last, lo - 1, -1):
            if _inside(col, resolution, wx, dy, c, s, hx, hy):
                hi = col
                break
        if lo <= hi:
            grid[r, lo:hi + 1] = True
            runs[n, 0], runs[n, 1], runs[n, 2] = r, lo, hi
            n += 1
    return n


@numba.njit(inline="always", nogil=True)
def _inside(col, resolution, wx, dy, c, s, hx, hy):  # pragma: no cover - compiled
    """Whether the centre of cell ``col`` of a row ``dy`` from the rectangle's centre lies in the rectangle."""
    dx = (col + 0.5) * resolution - wx
    return abs(dx * c + dy * s) <= hx and abs(-dx * s + dy * c) <= hy


@numba.njit(cache=True, nogil=True)
def _start_scratch(ny, nx):  # pragma: no cover - compiled
    """The scratch arrays :func:`_start_cells` takes for maps of ``ny x nx`` cells: a bit per cell of the blocked
    cells, and the free runs' rows, first and last columns and union-find parents."""
    free = ny * ((nx + 1) // 2)
    return (np.empty((ny, (nx + 63) >> 6), dtype=np.uint64), np.empty(free, dtype=np.int64),
            np.empty(free, dtype=np.int64), np.empty(free, dtype=np.int64), np.empty(free, dtype=np.int64))


_ALL_BITS = np.uint64(0xFFFFFFFFFFFFFFFF)


@numba.njit(inline="always", nogil=True)
def _bit_range(first, last):  # pragma: no cover - compiled
    """The uint64 whose bits ``first..last`` (``0 <= first <= last <= 63``) are set."""
    return (_ALL_BITS >> np.uint64(63 - last)) & (_ALL_BITS << np.uint64(first))


@numba.njit(inline="always", nogil=True)
def _block(row, lo, hi, nx):  # pragma: no cover - compiled
    """Set the bits of columns ``lo..hi`` (clipped to the map's ``nx``) in a row's words ``row``."""
    lo, hi = max(lo, 0), min(hi, nx - 1)
    for w in range(lo >> 6, (hi >> 6) + 1):
        base = w << 6
        row[w] |= _bit_range(max(lo, base) - base, min(hi, base + 63) - base)


@numba.njit(cache=True, nogil=True)
def _start_cells(runs, half_widths, wall_cells, starts, row_starts, scratch):  # pragma: no cover - compiled
    """Write into ``starts [ny, nx]`` the start cells of the map whose occupied cells are ``runs`` (``[n, 3]``: row,
    first and last column), their number per row into ``row_starts [ny]``, and return their number. ``scratch``:
    :func:`_start_scratch`.

    Computed on bits and runs, not cell by cell: each occupied run blocks itself and, widened by
    ``half_widths[drow]``, the rows ``drow`` away (the margin), as bits of 64 cells a word; a row's free runs are
    read off the words' unblocked bits within the walls' margin by counting trailing zeros; the largest
    4-connected group is found by union-find over the free runs (32 -> 14 us a map against marking and scanning
    a grid of cells)."""
    ny, nx = starts.shape
    blocked, run_row, run_lo, run_hi, parent = scratch
    reach = (half_widths.shape[0] - 1) // 2
    blocked[:] = 0
    for k in range(runs.shape[0]):
        r, lo, hi = runs[k, 0], runs[k, 1], runs[k, 2]
        _block(blocked[r], lo, hi, nx)
        for dr in range(-reach, reach + 1):
            h = half_widths[dr + reach]
            if h >= 0 and 0 <= r + dr < ny:
                _block(blocked[r + dr], lo - h, hi + h, nx)
    # Each row's free runs, left to right, joined to the overlapping runs of the row above.
    made, previous, previous_end = 0, 0, 0
    left, right = wall_cells, nx - 1 - wall_cells
    for r in range(wall_cells, ny - wall_cells):
        row_start, j, open_lo = made, previous, -1
        for w in range(blocked.shape[1]):
            base = w << 6
            first, last = max(left, base), min(right, base + 63)
            free = ~blocked[r, w] & _bit_range(first - base, last - base) if first <= last else np.uint64(0)
            bit = 0
            while bit < 64:
                if open_lo < 0:
                    rest = free & (_ALL_BITS << np.uint64(bit))
                    if rest == 0:
                        break
                    bit = np.int64(trailing_zeros(rest))
                    open_lo = base + bit
                rest = ~free & (_ALL_BITS << np.uint64(bit))
                if rest == 0:  # the run goes on in the next word
                    break
                bit = np.int64(trailing_zeros(rest))
                made, j = _join(r, open_lo, base + bit - 1, run_row, run_lo, run_hi, parent, made, j, previous_end)
                open_lo = -1
        if open_lo >= 0:
            made, j = _join(r, open_lo, right, run_row, run_lo, run_hi, parent, made, j, previous_end)
        previous, previous_end = row_start, made
    starts[:] = False
    row_starts[:] = 0
    if made == 0:
        return 0
    size = np.zeros(made, dtype=np.int64)
    for k in range(made):
        size[_root(parent, k)] += run_hi[k] - run_lo[k] + 1
    best = np.argmax(size)
    for k in range(made):
        if _root(parent, k) == best:
            row_starts[run_row[k]] += run_hi[k] - run_lo[k] + 1
            starts[run_row[k], run_lo[k]:run_hi[k] + 1] = True
    return size[best]


@numba.njit(inline="always", nogil=True)
def _join(r, lo, hi, run_row, run_lo, run_hi, parent, made, j, previous_end):  # pragma: no cover - compiled
    """Add the free run ``lo..hi`` of row ``r`` as run ``made``, united with the runs ``j..previous_end - 1`` of the
    row above that it overlaps (those before ``j`` end left of it); return ``(made + 1, j)`` for the next run."""
    run_row[made], run_lo[made], run_hi[made], parent[made] = r, lo, hi, made
    while j < previous_end and run_hi[j] < lo:
        j += 1
    m = j
    while m < previous_end and run_lo[m] <= hi:
        a, b = _root(parent, m), _root(parent, made)
        if a != b:
            parent[max(a, b)] = min(a, b)
        m += 1
    return made + 1, j


@numba.njit(cache=True, nogil=True)
def _root(parent, k):  # pragma: no cover - compiled
    while parent[k] != k:
        parent[k] = parent[parent[k]]
        k = parent[k]
    return k


# The kernel's entry (compiled on its first run).
@kernel_entry("float64[2]", "int64[1]", "int64[1]", "int", "int", "float", "float", "float", "float", "float",
              "float", "int64[1]", "int", "bool[3]", "bool[3]", "int64[2]", "uint8[3]", "int16[3]", "int64[1]")
def _layouts_entry(data):  # pragma: no cover - compiled
    """:func:`_layouts` of the arguments ``(u, worlds, *shape arguments, occupancy, starts, row_starts,
    block_distance, block_cells, counts)``, chunk by chunk of the layouts."""
    d = descriptor(data)
    u, worlds, shapes = array2(d, 0, np.float64), array1(d, 1, np.int64), array1(d, 2, np.int64)
    occupancy, starts, row_starts = array3(d, 13, np.bool_), array3(d, 14, np.bool_), array2(d, 15, np.int64)
    block_distance, block_cells, counts = array3(d, 16, np.uint8), array3(d, 17, np.int16), array1(d, 18, np.int64)
    in_chunks(d, _layouts, (u, worlds, shapes, integer(d, 3), integer(d, 4), real(d, 5), real(d, 6), real(d, 7),
                            real(d, 8), real(d, 9), real(d, 10), array1(d, 11, np.int64), integer(d, 12), occupancy,
                            starts, row_starts, block_distance, block_cells, counts))
