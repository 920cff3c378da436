"""Geometry queries on maps, batched: collision, line of sight, the closest obstacle in view.

Two geometries answer the same queries with the same definitions:

* :class:`MapGeometry`, one map for every world, precomputes once per map the tables that make every query a
  few gathers:

  - a collision grid ``collision_supersample`` times finer than the map: a fine cell collides when its centre
    lies within ``margin`` of the map bounds or of an occupied cell's square (:func:`_near_occupied`; the 2019
    code tests a 6 x 6 window of map cells instead: same margin, half a cell coarser);
  - a polar obstacle table: for every map cell and each of ``num_bins`` global directions, the distance from
    the cell centre along that ray to where it enters the first occupied cell (within the sensor range; exact
    for a robot at the cell centre, off by at most half a cell diagonal elsewhere). The closest obstacle in
    the field of view is then a minimum over the bins the field of view covers, combined with an exact
    ray-rectangle test against the walls (the bounds shrunk by ``margin``, as in the 2019 code).

* :class:`WorldMapGeometry`, one map per world (``occupancy [B, ny, nx]``, every map of one shape), replaced
  at any reset (:mod:`aia.envs.map_generator`). Its tables would cost more per episode than the queries they
  save (the collision grids of 4,096 maps of 181 x 181 cells are 2.1 GB, the ray tables 16 MB and about a
  second to build a map: over an hour per episode of 4,096 worlds), so it computes the same values from the
  occupancy when asked: the collision test of the fine cell a point falls
  in, and the ray table's entries along the bins in view (on the CPU, every query reads only the cells its answer
  needs: :mod:`aia.envs.cpu_map_queries`). Each result equals :class:`MapGeometry`'s on the
  world's own map (``tests/envs/test_sensing.py``).
"""

from __future__ import annotations

import copy
import functools
import math
from abc import ABC, abstractmethod
from collections.abc import Callable
from typing import TYPE_CHECKING

import torch
from torch import Tensor

from aia.envs.belief import range_bearing
from aia.envs.cpu_map_queries import CpuMapQueries
from aia.envs.dynamics import wrap_angle
from aia.envs.maps import GridMap, load_map

if TYPE_CHECKING:
    from aia.envs.map_generator import RandomObstacles

# occupied(row, col) -> bool: whether the map cells at integer indices (inside the grid) are occupied.
Occupied = Callable[[Tensor, Tensor], Tensor]


class Geometry(ABC):
    """What both geometries share: the map's frame, the sensor, the walls, and the queries built on a map's
    occupancy (line of sight, the closest obstacle in view).

    ``occupancy`` is ``[ny, nx]`` (one map) or ``[B, ny, nx]`` (one per world); :meth:`occupied` reads cells by
    flat index into each world's own grid either way (what the local-map observation gathers through).
    """

    def __init__(self, size: tuple[float, float], shape: tuple[int, int], resolution: float, margin: float,
                 sensor_range: float, fov: float, ray_spacing: float, collision_supersample: int,
                 device: torch.device | str, dtype: torch.dtype) -> None:
        self.margin = margin
        self.sensor_range = sensor_range
        self.fov = fov
        self.device = torch.device(device)
        self.dtype = dtype
        self.resolution = resolution
        self.shape = shape
        self.size = torch.tensor(size, dtype=dtype, device=self.device)
        self.supersample = collision_supersample
        self.fine_cell = resolution / collision_supersample
        self.fine_shape = (shape[0] * collision_supersample, shape[1] * collision_supersample)
        self.num_bins = max(1, round(2 * math.pi / ray_spacing))
        self.bin_width = 2 * math.pi / self.num_bins
        self.fov_bins = max(1, min(self.num_bins, round(fov / self.bin_width)))
        # The directions towards the walls x = margin, x = width - margin, y = margin, y = height - margin.
        self._wall_directions = torch.tensor([math.pi, 0.0, -math.pi / 2, math.pi / 2], dtype=dtype,
                                             device=self.device)

    has_obstacles: bool

    @abstractmethod
    def in_collision(self, xy: Tensor) -> Tensor:
        """Whether each position ``[..., 2]`` is within ``margin`` of the bounds or of an occupied cell."""

    @abstractmethod
    def free_start(self, xy: Tensor) -> Tensor:
        """Whether an episode may place a robot, target or belief at each position ``[..., 2]``."""

    @abstractmethod
    def sample_free(self, uniforms: Tensor) -> Tensor:
        """Positions ``[..., 2]`` where an episode may start, uniform over that space, from ``[..., 3]`` uniforms."""

    @abstractmethod
    def occupied(self, index: Tensor) -> Tensor:
        """Whether the map cells at flat indices ``index`` (into each world's own grid) are occupied."""

    @abstractmethod
    def _obstacle_hits(self, pose: Tensor, bins: Tensor, bound: Tensor,
                       last: tuple[Tensor, Tensor] | None = None) -> Tensor:
        """``[..., F]`` the smaller of ``bound [..., F]`` and the distance along each bin's ray from the centre of
        the robot's cell to the first occupied cell (none within the sensor range: ``bound``; leaving the grid is
        a hit). A geometry may leave a ray whose first hit lies beyond the minimum over ``[..., F]`` at its
        ``bound``: the minimum and its first index are what :meth:`closest_obstacle` reads. ``last``: see
        :meth:`closest_obstacle`."""

    def select(self, worlds: Tensor) -> Geometry:
        """This geometry for queries whose leading dimension runs over ``worlds [K]`` (world indices in any
        order, repeated or not; ARVI's tree nodes) for :meth:`in_collision`, :meth:`in_view` and
        :meth:`line_of_sight`: the same geometry where every world shares one map."""
        return self

    # ------------------------------------------------------------------ cells
    @staticmethod
    def _cell_rows_cols(xy: Tensor, cell: float, shape: tuple[int, int]) -> tuple[Tensor, Tensor]:
        """``(row, col)`` of the cell holding each point (points outside are clamped to the border cells)."""
        ij = torch.floor(xy / cell).long()
        return ij[..., 1].clamp(0, shape[0] - 1), ij[..., 0].clamp(0, shape[1] - 1)

    def _cell_index(self, xy: Tensor, cell: float, shape: tuple[int, int]) -> Tensor:
        """Flat index of the cell holding each point (points outside are clamped to the border cells)."""
        row, col = self._cell_rows_cols(xy, cell, shape)
        return row * shape[1] + col

    def _outside(self, xy: Tensor) -> Tensor:
        return ((xy < 0) | (xy > self.size)).any(-1)

    # --------------------------------------------------------------- sight
    def in_view(self, pose: Tensor, points: Tensor) -> tuple[Tensor, Tensor]:
        """The sensing rule (SPEC 4): ``(seen [..., N], polar [..., N, 2])`` of ``points [..., N, 2]`` from
        ``pose [..., 3]``, where a point is seen when it lies within the sensor range, inside the field of
        view and behind no occupied cell; ``polar`` is its (range, bearing)."""
        polar = range_bearing(points, pose.unsqueeze(-2))
        seen = (polar[..., 0] <= self.sensor_range) & (polar[..., 1].abs() <= self.fov / 2)
        origin, points = torch.broadcast_tensors(pose[..., :2].unsqueeze(-2), points)
        return self.line_of_sight(origin, points, seen), polar

    def line_of_sight(self, origin: Tensor, target: Tensor, wanted: Tensor | None = None) -> Tensor:
        """Whether the segment from ``origin [..., 2]`` to ``target [..., 2]`` crosses no occupied cell (and, with
        ``wanted [...]``, is wanted: False where it is not, whose segments a geometry may leave unread).

        The segment is sampled every half cell up to the sensor range (segments are at most that long
        when it matters): :meth:`_sight_fractions`; always True on a map without obstacles.
        """
        if not self.has_obstacles:
            clear = torch.ones(origin.shape[:-1], dtype=torch.bool, device=self.device)
            return clear if wanted is None else clear & wanted
        fraction = self._sight_fractions()
        points = origin.unsqueeze(-2) + (target - origin).unsqueeze(-2) * fraction.unsqueeze(-1)
        clear = ~self.occupied(self._cell_index(points, self.resolution, self.shape)).any(-1)
        return clear if wanted is None else clear & wanted

    def _sight_fractions(self) -> Tensor:
        """``[S]`` where along a segment :meth:`line_of_sight` samples it: every half cell of the sensor range."""
        samples = math.ceil(2 * self.sensor_range / self.resolution) + 1
        return torch.linspace(0.0, 1.0, samples, dtype=self.dtype, device=self.device)

    # ------------------------------------------------------------ obstacles
    def closest_obstacle(self, pose: Tensor, last: tuple[Tensor, Tensor] | None = None) -> Tensor:
        """``[..., 2]`` (distance, bearing) of the closest obstacle point in the field of view and range.

        Obstacles are occupied cells and the walls (the bounds shrunk by ``margin``). Where nothing lies
        within range the result is ``(sensor_range, pi)``, SPEC 6's "no obstacle" value. ``last``: the last
        step's ``(pose, result)``, whose closest obstacle is likely near this one's: a geometry that walks its
        rays walks the ray toward it first. It changes the work, never the result.
        """
        heading = pose[..., 2:3]
        first = torch.ceil((heading - 0.5 * self.fov) / self.bin_width).long()
        bins = torch.remainder(first + torch.arange(self.fov_bins, device=self.device), self.num_bins)
        angles = bins.to(self.dtype) * self.bin_width
        distance = self._wall_distance(pose[..., :2], angles)
        if self.has_obstacles:
            distance = self._obstacle_hits(pose, bins, distance, last)
        best, arg = distance.min(-1)
        bearing = wrap_angle(torch.gather(angles, -1, arg.unsqueeze(-1)).squeeze(-1) - pose[..., 2])
        seen = best <= self.sensor_range
        return torch.stack(
            (torch.where(seen, best, self.sensor_range), torch.where(seen, bearing, math.pi)), dim=-1
        )

    def _nearest_wall(self, xy: Tensor) -> tuple[Tensor, Tensor]:
        """``(distance [...], direction [...])`` from each position to the nearest wall (bounds shrunk by margin)."""
        x, y = xy[..., 0], xy[..., 1]
        walls = torch.stack((x - self.margin, (self.size[0] - self.margin) - x,
                             y - self.margin, (self.size[1] - self.margin) - y), -1)
        distance, side = walls.min(-1)
        return distance, self._wall_directions[side]

    def _wall_distance(self, xy: Tensor, angles: Tensor) -> Tensor:
        """Distance along each ray (``angles [..., R]``) from ``xy [..., 2]`` to the margin-shrunk bounds."""
        direction = torch.stack((torch.cos(angles), torch.sin(angles)), dim=-1)
        low = self.margin - xy.unsqueeze(-2)
        high = (self.size - self.margin) - xy.unsqueeze(-2)
        bound = torch.where(direction > 0, high, low)
        steps = torch.where(direction != 0, bound / direction, torch.full_like(bound, math.inf))
        return steps.min(-1).values.clamp_min(0.0)


class MapGeometry(Geometry):
    """Batched geometric queries against one :class:`GridMap` on one device (every world's map)."""

    def __init__(
        self,
        grid_map: GridMap,
        margin: float,
        sensor_range: float,
        fov: float,
        ray_spacing: float,
        collision_supersample: int = 4,
        device: torch.device | str = "cpu",
        dtype: torch.dtype = torch.float32,
    ) -> None:
        super().__init__((grid_map.width, grid_map.height), grid_map.shape, grid_map.resolution, margin,
                         sensor_range, fov, ray_spacing, collision_supersample, device, dtype)
        self.map = grid_map
        self.occupancy = grid_map.occupancy.to(self.device)
        self.has_obstacles = grid_map.has_obstacles
        self.collision = _collision_grid(grid_map, margin, collision_supersample).to(self.device)
        self.free_cells = torch.nonzero(~self.collision.flatten()).squeeze(-1)
        if self.free_cells.numel() == 0:
            raise ValueError(f"map {grid_map.name!r} has no collision-free space with margin {margin}")
        self._nearest_cell: Tensor | None = None  # nearest_obstacle's table (nearest_obstacle_table)
        self.ray_table = (
            # built on the CPU from the map's own grid, then moved
            _polar_obstacle_table(grid_map.occupancy, self.resolution, sensor_range, self.num_bins).to(
                self.device, dtype
            )
            if self.has_obstacles
            else None
        )

    def occupied(self, index: Tensor) -> Tensor:
        return self.occupancy.flatten()[index]

    def _obstacle_hits(self, pose: Tensor, bins: Tensor, bound: Tensor,
                       last: tuple[Tensor, Tensor] | None = None) -> Tensor:
        cell = self._cell_index(pose[..., :2], self.resolution, self.shape)
        return torch.minimum(bound, self.ray_table[cell.unsqueeze(-1), bins])

    def in_collision(self, xy: Tensor) -> Tensor:
        """Whether each position ``[..., 2]`` is within ``margin`` of the bounds or of an occupied cell."""
        index = self._cell_index(xy, self.fine_cell, self.fine_shape)
        return self.collision.flatten()[index] | self._outside(xy)

    def free_start(self, xy: Tensor) -> Tensor:
        """Whether an episode may place a robot, target or belief at each position ``[..., 2]``: collision-free."""
        return ~self.in_collision(xy)

    def sample_free(self, uniforms: Tensor) -> Tensor:
        """Positions uniform over the collision-free space, from ``[..., 3]`` uniforms in [0, 1)."""
        pick = (uniforms[..., 0] * self.free_cells.numel()).long().clamp_max(self.free_cells.numel() - 1)
        flat = self.free_cells[pick]
        ncols = self.collision.shape[1]
        centre = torch.stack(((flat % ncols), (flat // ncols)), dim=-1).to(self.dtype) + 0.5
        # Shrunk by 0.1 % so that rounding never lands a point on the edge of a neighbouring cell.
        return (centre + (uniforms[..., 1:3] - 0.5) * 0.999) * self.fine_cell

    def nearest_obstacle(self, xy: Tensor) -> tuple[Tensor, Tensor]:
        """``(distance [...], direction [...])`` from each position ``xy [..., 2]`` to the nearest obstacle in
        any direction and at any range: the nearest of the walls (the bounds shrunk by ``margin``) and the
        centres of the occupied cells (the nearest centre to the centre of ``xy``'s cell, from
        :meth:`nearest_obstacle_table`), ``direction`` the world-frame angle towards it.

        ttenv's targets ask this (its ``get_closest_obstacle`` over a full turn of rays to 1 km: the first
        wall or occupied cell along each ray, the closest of all).
        """
        distance, direction = self._nearest_wall(xy)
        if self.has_obstacles:
            table = self.nearest_obstacle_table()
            centre = table[self._cell_index(xy, self.resolution, self.shape)]
            delta = centre - xy
            cell_distance = torch.linalg.vector_norm(delta, dim=-1)
            closer = cell_distance < distance
            distance = torch.where(closer, cell_distance, distance)
            direction = torch.where(closer, torch.atan2(delta[..., 1], delta[..., 0]), direction)
        return distance, direction

    def nearest_obstacle_table(self) -> Tensor:
        """``[ny * nx, 2]`` the nearest occupied cell centre to each cell's, built on the first call (about a
        second for ``obstacles4``): a model that queries :meth:`nearest_obstacle` calls it when it is built, so
        that the table is not made inside a (compiled) step."""
        if self._nearest_cell is None:
            self._nearest_cell = _nearest_occupied(self.map).to(self.device, self.dtype)
        return self._nearest_cell


class WorldMapGeometry(Geometry):
    """Batched geometric queries where world ``b`` has its own map ``occupancy[b]`` (``[B, ny, nx]``, one shape
    and resolution for all), set by :meth:`set_maps` (at a reset; in place, so a compiled step keeps reading
    the same buffers). Queries take ``[B, ...]`` inputs, the leading dimension the world.

    The same results as :class:`MapGeometry` on each world's map, computed on demand: a collision is the test of
    the point's fine cell against the map cells within ``margin`` (``(2 ceil(margin / resolution) + 1)^2``
    cells), the closest obstacle the ray table's entries of the bins in view (``fov_bins`` rays of about
    ``2 range / resolution`` cells each), a line of sight the cells of its samples. A GPU gathers every one of
    those cells; the CPU reads only the cells an answer needs (:class:`aia.envs.cpu_map_queries.CpuMapQueries`).
    Episodes start in :attr:`start_cells`: the cells of each map whose whole square is collision-free, in the
    largest 4-connected group of them (:func:`aia.envs.map_generator.start_cells`), so that every start can reach
    every other.
    ``nearest_obstacle`` (ttenv v1's detour rule) needs a table per map and is not offered.
    """

    has_obstacles = True

    def __init__(self, num_worlds: int, size: tuple[float, float], resolution: float, margin: float,
                 sensor_range: float, fov: float, ray_spacing: float, collision_supersample: int = 4,
                 device: torch.device | str = "cpu", dtype: torch.dtype = torch.float32) -> None:
        nx, ny = round(size[0] / resolution), round(size[1] / resolution)
        super().__init__(size, (ny, nx), resolution, margin, sensor_range, fov, ray_spacing, collision_supersample,
                         device, dtype)
        self.num_worlds = num_worlds
        self.occupancy = torch.zeros(num_worlds, ny, nx, dtype=torch.bool, device=self.device)
        self.start_cells = torch.zeros(num_worlds, ny, nx, dtype=torch.bool, device=self.device)
        # [B, ny] the start cells in rows 0..i of each map (sample_free picks the row by a search, then the cell).
        self._start_rows = torch.zeros(num_worlds, ny, dtype=torch.int64, device=self.device)
        self._world_base = torch.arange(num_worlds, device=self.device) * (ny * nx)
        cols, rows, distances = _ray_offsets(self.num_bins, resolution, sensor_range)
        self._ray_cols, self._ray_rows = cols.to(self.device), rows.to(self.device)
        self._ray_distances = distances.to(self.device, dtype)
        # On the CPU the queries read only the cells their answers need (aia.envs.cpu_map_queries), elsewhere they
        # are gathered whole.
        self._cpu = (CpuMapQueries(num_worlds, self.shape, resolution, cols, rows, self._ray_distances)
                     if self.device.type == "cpu" else None)

    def set_maps(self, worlds: Tensor, occupancy: Tensor, start_cells: Tensor, row_starts: Tensor | None = None
                 ) -> None:
        """Give the worlds ``worlds`` (``[K]`` indices) the maps ``occupancy [K, ny, nx]`` with their
        ``start_cells [K, ny, nx]`` (each map's must hold a cell; ``row_starts [K, ny]``: their number per row,
        counted here when None)."""
        worlds = worlds.to(self.device)
        self.occupancy[worlds] = occupancy.to(self.device)
        self.start_cells[worlds] = start_cells.to(self.device)
        row_starts = start_cells.sum(-1) if row_starts is None else row_starts
        self._start_rows[worlds] = row_starts.to(self.device).cumsum(-1)
        if self._cpu is not None:
            self._cpu.update(self.occupancy, worlds)

    def draw_maps(self, worlds: Tensor, layouts: RandomObstacles, keys: Tensor) -> None:
        """New maps from ``layouts`` for the worlds ``worlds [K]``, whose episode keys are ``keys [K]``: on the CPU
        written in place (no copy of 134 MB per 4,096 maps of 181 x 181 cells), elsewhere drawn and copied."""
        if self.device.type != "cpu":
            self.set_maps(worlds, *layouts.generate(keys))
            return
        row_starts = torch.empty_like(self._start_rows)
        layouts.generate(keys, worlds, (self.occupancy, self.start_cells, row_starts),
                         (self._cpu.block_distance, self._cpu.block_cells))
        self._start_rows[worlds] = row_starts[worlds].cumsum(-1)

    def select(self, worlds: Tensor) -> WorldMapGeometry:
        view = copy.copy(self)
        view._world_base = worlds.to(self.device) * (self.shape[0] * self.shape[1])
        view._cpu = None  # the kernels read world q // (Q // B): the views' queries are gathered
        return view

    def grid_map(self, world: int) -> GridMap:
        """World ``world``'s current map as a :class:`GridMap` (on the CPU), for rendering and recording."""
        return GridMap(name=f"world {world}", resolution=self.resolution, occupancy=self.occupancy[world].cpu())

    def _per_world(self, index: Tensor) -> Tensor:
        """Flat indices into each world's grid ``[B, ...]`` -> indices into the stack of grids."""
        return index + self._world_base.view(-1, *([1] * (index.ndim - 1)))

    def occupied(self, index: Tensor) -> Tensor:
        return self.occupancy.flatten()[self._per_world(index)]

    def _occupied_cells(self, row: Tensor, col: Tensor) -> Tensor:
        return self.occupied(row * self.shape[1] + col)

    def _obstacle_hits(self, pose: Tensor, bins: Tensor, bound: Tensor,
                       last: tuple[Tensor, Tensor] | None = None) -> Tensor:
        row, col = self._cell_rows_cols(pose[..., :2], self.resolution, self.shape)
        if self._cpu is not None:
            return self._cpu.hits(row, col, bins, bound, self._lead_ray(pose, bins, last))
        return torch.minimum(bound, self._gathered_hits(row, col, bins))

    def _gathered_hits(self, row: Tensor, col: Tensor, bins: Tensor) -> Tensor:
        """``[B, F]`` every bin's first hit from cells ``(row [B], col [B])``, all of each ray's cells gathered."""
        rows = row[..., None, None] + self._ray_rows[bins]
        cols = col[..., None, None] + self._ray_cols[bins]
        (ny, nx), inside = self.shape, (rows >= 0) & (rows < self.shape[0]) & (cols >= 0) & (cols < self.shape[1])
        hit = self._occupied_cells(rows.clamp(0, ny - 1), cols.clamp(0, nx - 1)) | ~inside
        return torch.where(hit, self._ray_distances[bins], math.inf).amin(-1)

    def _lead_ray(self, pose: Tensor, bins: Tensor, last: tuple[Tensor, Tensor] | None) -> Tensor:
        """``[B, ...]`` the position in ``bins [B, ..., F]`` of the ray from ``pose`` toward the point of the last
        closest obstacle (``last``: its ``(pose, (range, bearing))``), -1 where that ray is out of view or without
        ``last``: the ray the walk takes first."""
        if last is None:
            return torch.full(bins.shape[:-1], -1, dtype=torch.int64, device=self.device)
        last_pose, polar = last
        angle = last_pose[..., 2] + polar[..., 1]
        point = last_pose[..., :2] + polar[..., :1] * torch.stack((torch.cos(angle), torch.sin(angle)), -1)
        offset = point - pose[..., :2]
        nearest = torch.round(torch.atan2(offset[..., 1], offset[..., 0]) / self.bin_width).long()
        lead = torch.remainder(nearest - bins[..., 0], self.num_bins)
        return torch.where(lead < bins.shape[-1], lead, -1)

    def in_collision(self, xy: Tensor) -> Tensor:
        """Whether each position ``[B, ..., 2]`` is within ``margin`` of the bounds or of an occupied cell of its
        world's map."""
        row, col = self._cell_rows_cols(xy, self.fine_cell, self.fine_shape)
        if self._cpu is not None:
            near = self._cpu.near_occupied(self.occupancy, row, col, self.margin, self.supersample)
        else:
            near = _near_occupied(self._occupied_cells, row, col, self.shape, self.resolution, self.margin,
                                  self.supersample)
        return near | self._outside(xy)

    def line_of_sight(self, origin: Tensor, target: Tensor, wanted: Tensor | None = None) -> Tensor:
        if self._cpu is None:
            return super().line_of_sight(origin, target, wanted)
        origin, target = torch.broadcast_tensors(origin, target)
        wanted = torch.ones(origin.shape[:-1], dtype=torch.bool) if wanted is None else wanted
        return self._cpu.line_of_sight(origin, target, wanted.expand(origin.shape[:-1]), self._sight_fractions())

    def free_start(self, xy: Tensor) -> Tensor:
        """Whether an episode may place a robot, target or belief at each position ``[B, ..., 2]``: in one of its
        world's :attr:`start_cells`."""
        row, col = self._cell_rows_cols(xy, self.resolution, self.shape)
        return self._occupied_starts(row * self.shape[1] + col) & ~self._outside(xy)

    def _occupied_starts(self, index: Tensor) -> Tensor:
        return self.start_cells.flatten()[self._per_world(index)]

    def sample_free(self, uniforms: Tensor) -> Tensor:
        """Positions ``[B, ..., 2]`` uniform over each world's :attr:`start_cells`, from ``[B, ..., 3]`` uniforms
        in [0, 1)."""
        B, nx = self.num_worlds, self.shape[1]
        flat_u = uniforms.reshape(B, -1, 3)
        count = self._start_rows[:, -1:]
        pick = (flat_u[..., 0] * count).long().minimum(count - 1)                          # [B, K]
        row = torch.searchsorted(self._start_rows, pick, right=True)                       # [B, K]
        before = torch.gather(self._start_rows, 1, (row - 1).clamp_min(0)) * (row > 0)
        cells = torch.gather(self.start_cells, 1, row[..., None].expand(-1, -1, nx))     # [B, K, nx]
        col = (cells.cumsum(-1) > (pick - before)[..., None]).to(torch.int8).argmax(-1)
        centre = torch.stack((col, row), -1).to(self.dtype) + 0.5
        # Shrunk by 0.1 % so that rounding never lands a point on the edge of a neighbouring cell.
        xy = (centre + (flat_u[..., 1:3] - 0.5) * 0.999) * self.resolution
        return xy.reshape(*uniforms.shape[:-1], 2)


@functools.lru_cache(maxsize=16)
def map_geometry(
    map_name: str,
    margin: float,
    sensor_range: float,
    fov: float,
    ray_spacing: float,
    collision_supersample: int,
    device: torch.device | str,
    dtype: torch.dtype,
) -> MapGeometry:
    """The :class:`MapGeometry` of a map by name or path, built once per process and set of parameters."""
    return MapGeometry(load_map(map_name), margin, sensor_range, fov, ray_spacing, collision_supersample, device, dtype)


def _near_occupied(occupied: Occupied, fine_row: Tensor, fine_col: Tensor, shape: tuple[int, int], resolution: float,
                   margin: float, supersample: int, obstacles: bool = True) -> Tensor:
    """Whether the centre of each fine cell ``(fine_row, fine_col)`` (integer tensors that broadcast together)
    lies within ``margin`` of the map's bounds or, when ``obstacles``, of the square of an occupied map cell:
    the collision rule, for the grid :class:`MapGeometry` precomputes and the points
    :class:`WorldMapGeometry` asks about (the same float64 arithmetic, so the same bits).

    The map cells within reach of the margin are a short loop over row offsets, each vectorised over the fine
    cells and the column offsets (a trailing dimension): 7 passes for ``obstacles4``'s 0.5 m margin at 0.2 m.
    """
    ny, nx = shape
    fine = resolution / supersample
    px = (fine_col.double() + 0.5) * fine
    py = (fine_row.double() + 0.5) * fine
    width, height = nx * resolution, ny * resolution
    near = (px < margin) | (px > width - margin) | (py < margin) | (py > height - margin)
    if not obstacles:
        return near
    col = torch.div(fine_col, supersample, rounding_mode="floor")
    row = torch.div(fine_row, supersample, rounding_mode="floor")
    reach = math.ceil(margin / resolution)
    offsets = torch.arange(-reach, reach + 1, device=fine_col.device)
    c = (col.unsqueeze(-1) + offsets).clamp(0, nx - 1)
    x0 = c.double() * resolution
    # Distance along x from the fine-cell centre to the square of map cell (., c), then along y for each row.
    dx = torch.clamp(torch.maximum(x0 - px.unsqueeze(-1), px.unsqueeze(-1) - (x0 + resolution)), min=0.0)
    for dr in range(-reach, reach + 1):
        r = (row + dr).clamp(0, ny - 1).unsqueeze(-1)
        y0 = r.double() * resolution
        dy = torch.clamp(torch.maximum(y0 - py.unsqueeze(-1), py.unsqueeze(-1) - (y0 + resolution)), min=0.0)
        near = near | (occupied(r, c) & (dx * dx + dy * dy < margin * margin)).any(-1)
    return near


def _collision_grid(grid_map: GridMap, margin: float, supersample: int) -> Tensor:
    """``[ny * s, nx * s]`` bool: fine cells whose centre is within ``margin`` of the bounds or of an occupied cell."""
    ny, nx = grid_map.shape
    fine_row = torch.arange(ny * supersample)[:, None]
    fine_col = torch.arange(nx * supersample)[None, :]
    occupancy = grid_map.occupancy
    return _near_occupied(lambda r, c: occupancy[r, c], fine_row, fine_col, grid_map.shape, grid_map.resolution,
                          margin, supersample, obstacles=grid_map.has_obstacles)


def _nearest_occupied(grid_map: GridMap, chunk: int = 4096) -> Tensor:
    """``[ny * nx, 2]`` the centre of the occupied cell nearest to each cell's centre (float64)."""
    res = grid_map.resolution
    ny, nx = grid_map.shape
    rows, cols = torch.meshgrid(torch.arange(ny), torch.arange(nx), indexing="ij")
    centres = (torch.stack((cols, rows), -1).reshape(-1, 2).double() + 0.5) * res
    occupied = centres[grid_map.occupancy.flatten()]
    nearest = torch.empty_like(centres)
    for start in range(0, centres.shape[0], chunk):
        block = centres[start:start + chunk]
        nearest[start:start + chunk] = occupied[torch.cdist(block, occupied).argmin(-1)]
    return nearest


def _polar_obstacle_table(occupancy: Tensor, resolution: float, max_range: float, num_bins: int) -> Tensor:
    """``[ny * nx, num_bins]`` distance from each cell centre along each global direction to where the ray
    enters the first occupied cell (``inf`` when none lies within ``max_range``; leaving the grid is a hit).

    Seen from a cell centre, the cells a ray crosses are the same integer offsets for every cell, so each
    crossed cell is one shifted slice of the (padded) occupancy grid for all cells at once.
    """
    ny, nx = occupancy.shape
    pad = math.ceil(max_range / resolution) + 1
    padded = torch.nn.functional.pad(occupancy, (pad, pad, pad, pad), value=True)
    table = torch.full((num_bins, ny, nx), math.inf)
    for b in range(num_bins):
        crossed = _ray_cells(b * 2 * math.pi / num_bins, resolution, max_range)
        # Write from the far end inwards so that the nearest hit is written last.
        for dc, dr, distance in reversed(crossed):
            table[b].masked_fill_(padded[pad + dr : pad + dr + ny, pad + dc : pad + dc + nx], distance)
    return table.permute(1, 2, 0).reshape(ny * nx, num_bins).contiguous()


def _ray_offsets(num_bins: int, resolution: float, max_range: float) -> tuple[Tensor, Tensor, Tensor]:
    """``(dcol, drow, distance)``, each ``[num_bins, L]``: the cells each bin's ray crosses (:func:`_ray_cells`),
    padded to the longest ray with the start cell at distance ``inf`` (never the nearest hit)."""
    rays = [_ray_cells(b * 2 * math.pi / num_bins, resolution, max_range) for b in range(num_bins)]
    length = max(len(ray) for ray in rays)
    cols = torch.zeros(num_bins, length, dtype=torch.int64)
    rows = torch.zeros(num_bins, length, dtype=torch.int64)
    distances = torch.full((num_bins, length), math.inf)
    for b, ray in enumerate(rays):
        cols[b, :len(ray)] = torch.tensor([dc for dc, _, _ in ray])
        rows[b, :len(ray)] = torch.tensor([dr for _, dr, _ in ray])
        distances[b, :len(ray)] = torch.tensor([d for _, _, d in ray])
    return cols, rows, distances


def _ray_cells(angle: float, resolution: float, max_range: float) -> list[tuple[int, int, float]]:
    """Cells ``(dcol, drow, entry distance)`` crossed by a ray from the centre of cell (0, 0), in order,
    up to ``max_range``, starting with that cell at distance 0 (grid traversal of Amanatides and Woo)."""
    direction = (math.cos(angle), math.sin(angle))
    step, next_boundary, spacing = [], [], []
    for d in direction:
        step.append(1 if d > 0 else -1)
        next_boundary.append(0.5 * resolution / abs(d) if abs(d) > 1e-12 else math.inf)
        spacing.append(resolution / abs(d) if abs(d) > 1e-12 else math.inf)
    cell = [0, 0]
    crossed = [(0, 0, 0.0)]  # the start cell itself (only ever occupied for a robot inside an obstacle)
    while True:
        axis = 0 if next_boundary[0] < next_boundary[1] else 1
        distance = next_boundary[axis]
        if distance > max_range:
            return crossed
        cell[axis] += step[axis]
        next_boundary[axis] += spacing[axis]
        crossed.append((cell[0], cell[1], distance))
