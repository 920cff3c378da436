"""Geometry queries on a map, batched: collision, line of sight, the closest obstacle in view.

:class:`MapGeometry` precomputes, once per map, the lookup tables that make every query a few gathers:

* a collision grid ``collision_supersample`` times finer than the map: a fine cell collides when its centre
  lies within ``margin`` of the map bounds or of an occupied cell's square (the 2019 code tests a 6 x 6
  window of map cells instead: same margin, half a cell coarser);
* a polar obstacle table: for every map cell and each of ``num_bins`` global directions, the distance
  from the cell centre along that ray to where it enters the first occupied cell (within the sensor
  range; exact for a robot at the cell centre, off by at most half a cell diagonal elsewhere). The closest
  obstacle in the field of view is then a minimum over the bins the field of view covers, combined with an
  exact ray-rectangle test against the walls (the bounds shrunk by ``margin``, as in the 2019 code).
"""

from __future__ import annotations

import functools
import math

import torch
from torch import Tensor

from aia.envs.belief import range_bearing
from aia.envs.dynamics import wrap_angle
from aia.envs.maps import GridMap, load_map


class MapGeometry:
    """Batched geometric queries against one :class:`GridMap` on one device."""

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
        self.map = grid_map
        self.margin = margin
        self.sensor_range = sensor_range
        self.fov = fov
        self.device = torch.device(device)
        self.dtype = dtype
        self.resolution = grid_map.resolution
        self.size = torch.tensor([grid_map.width, grid_map.height], dtype=dtype, device=self.device)
        self.occupancy = grid_map.occupancy.to(self.device)
        self.has_obstacles = grid_map.has_obstacles

        self.fine_cell = grid_map.resolution / collision_supersample
        self.collision = _collision_grid(grid_map, margin, collision_supersample).to(self.device)
        self.free_cells = torch.nonzero(~self.collision.flatten()).squeeze(-1)
        if self.free_cells.numel() == 0:
            raise ValueError(f"map {grid_map.name!r} has no collision-free space with margin {margin}")

        self.num_bins = max(1, round(2 * math.pi / ray_spacing))
        self.bin_width = 2 * math.pi / self.num_bins
        self.fov_bins = max(1, min(self.num_bins, round(fov / self.bin_width)))
        self._nearest_cell: Tensor | None = None  # nearest_obstacle's table (nearest_obstacle_table)
        # The directions towards the walls x = margin, x = width - margin, y = margin, y = height - margin.
        self._wall_directions = torch.tensor([math.pi, 0.0, -math.pi / 2, math.pi / 2], dtype=dtype,
                                             device=self.device)
        self.ray_table = (
            # built on the CPU from the map's own grid, then moved
            _polar_obstacle_table(grid_map.occupancy, self.resolution, sensor_range, self.num_bins).to(
                self.device, dtype
            )
            if self.has_obstacles
            else None
        )

    # ------------------------------------------------------------------ cells
    def _cell_index(self, xy: Tensor, cell: float, shape: tuple[int, int]) -> Tensor:
        """Flat index of the cell holding each point (points outside are clamped to the border cells)."""
        ij = torch.floor(xy / cell).long()
        col = ij[..., 0].clamp(0, shape[1] - 1)
        row = ij[..., 1].clamp(0, shape[0] - 1)
        return row * shape[1] + col

    def in_collision(self, xy: Tensor) -> Tensor:
        """Whether each position ``[..., 2]`` is within ``margin`` of the bounds or of an occupied cell."""
        outside = ((xy < 0) | (xy > self.size)).any(-1)
        index = self._cell_index(xy, self.fine_cell, self.collision.shape)
        return self.collision.flatten()[index] | outside

    def sample_free(self, uniforms: Tensor) -> Tensor:
        """Positions uniform over the collision-free space, from ``[..., 3]`` uniforms in [0, 1)."""
        pick = (uniforms[..., 0] * self.free_cells.numel()).long().clamp_max(self.free_cells.numel() - 1)
        flat = self.free_cells[pick]
        ncols = self.collision.shape[1]
        centre = torch.stack(((flat % ncols), (flat // ncols)), dim=-1).to(self.dtype) + 0.5
        # Shrunk by 0.1 % so that rounding never lands a point on the edge of a neighbouring cell.
        return (centre + (uniforms[..., 1:3] - 0.5) * 0.999) * self.fine_cell

    # --------------------------------------------------------------- sight
    def in_view(self, pose: Tensor, points: Tensor) -> tuple[Tensor, Tensor]:
        """The sensing rule (SPEC 4): ``(seen [..., N], polar [..., N, 2])`` of ``points [..., N, 2]`` from
        ``pose [..., 3]``, where a point is seen when it lies within the sensor range, inside the field of
        view and behind no occupied cell; ``polar`` is its (range, bearing)."""
        polar = range_bearing(points, pose.unsqueeze(-2))
        seen = (polar[..., 0] <= self.sensor_range) & (polar[..., 1].abs() <= self.fov / 2)
        origin, points = torch.broadcast_tensors(pose[..., :2].unsqueeze(-2), points)
        return seen & self.line_of_sight(origin, points), polar

    def line_of_sight(self, origin: Tensor, target: Tensor) -> Tensor:
        """Whether the segment from ``origin [..., 2]`` to ``target [..., 2]`` crosses no occupied cell.

        The segment is sampled every half cell up to the sensor range (segments are at most that long
        when it matters); always True on a map without obstacles.
        """
        if not self.has_obstacles:
            return torch.ones(origin.shape[:-1], dtype=torch.bool, device=self.device)
        samples = math.ceil(2 * self.sensor_range / self.resolution) + 1
        fraction = torch.linspace(0.0, 1.0, samples, dtype=self.dtype, device=self.device)
        points = origin.unsqueeze(-2) + (target - origin).unsqueeze(-2) * fraction.unsqueeze(-1)
        index = self._cell_index(points, self.resolution, self.occupancy.shape)
        return ~self.occupancy.flatten()[index].any(-1)

    # ------------------------------------------------------------ obstacles
    def closest_obstacle(self, pose: Tensor) -> Tensor:
        """``[..., 2]`` (distance, bearing) of the closest obstacle point in the field of view and range.

        Obstacles are occupied cells and the walls (the bounds shrunk by ``margin``). Where nothing lies
        within range the result is ``(sensor_range, pi)``, SPEC 6's "no obstacle" value.
        """
        heading = pose[..., 2:3]
        first = torch.ceil((heading - 0.5 * self.fov) / self.bin_width).long()
        bins = torch.remainder(first + torch.arange(self.fov_bins, device=self.device), self.num_bins)
        angles = bins.to(self.dtype) * self.bin_width
        distance = self._wall_distance(pose[..., :2], angles)
        if self.ray_table is not None:
            cell = self._cell_index(pose[..., :2], self.resolution, self.occupancy.shape)
            table = self.ray_table[cell.unsqueeze(-1), bins]
            distance = torch.minimum(distance, table)
        best, arg = distance.min(-1)
        bearing = wrap_angle(torch.gather(angles, -1, arg.unsqueeze(-1)).squeeze(-1) - pose[..., 2])
        seen = best <= self.sensor_range
        return torch.stack(
            (torch.where(seen, best, self.sensor_range), torch.where(seen, bearing, math.pi)), dim=-1
        )

    def nearest_obstacle(self, xy: Tensor) -> tuple[Tensor, Tensor]:
        """``(distance [...], direction [...])`` from each position ``xy [..., 2]`` to the nearest obstacle in
        any direction and at any range: the nearest of the walls (the bounds shrunk by ``margin``) and the
        centres of the occupied cells (the nearest centre to the centre of ``xy``'s cell, from
        :meth:`nearest_obstacle_table`), ``direction`` the world-frame angle towards it.

        ttenv's targets ask this (its ``get_closest_obstacle`` over a full turn of rays to 1 km: the first
        wall or occupied cell along each ray, the closest of all).
        """
        x, y = xy[..., 0], xy[..., 1]
        walls = torch.stack((x - self.margin, (self.size[0] - self.margin) - x,
                             y - self.margin, (self.size[1] - self.margin) - y), -1)
        distance, side = walls.min(-1)
        direction = self._wall_directions[side]
        if self.has_obstacles:
            table = self.nearest_obstacle_table()
            centre = table[self._cell_index(xy, self.resolution, self.occupancy.shape)]
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

    def _wall_distance(self, xy: Tensor, angles: Tensor) -> Tensor:
        """Distance along each ray (``angles [..., R]``) from ``xy [..., 2]`` to the margin-shrunk bounds."""
        direction = torch.stack((torch.cos(angles), torch.sin(angles)), dim=-1)
        low = self.margin - xy.unsqueeze(-2)
        high = (self.size - self.margin) - xy.unsqueeze(-2)
        bound = torch.where(direction > 0, high, low)
        steps = torch.where(direction != 0, bound / direction, torch.full_like(bound, math.inf))
        return steps.min(-1).values.clamp_min(0.0)


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


def _collision_grid(grid_map: GridMap, margin: float, supersample: int) -> Tensor:
    """``[ny * s, nx * s]`` bool: fine cells whose centre is within ``margin`` of the bounds or of an occupied cell."""
    res = grid_map.resolution
    ny, nx = grid_map.shape
    fine = res / supersample
    xs = (torch.arange(nx * supersample, dtype=torch.float64) + 0.5) * fine
    ys = (torch.arange(ny * supersample, dtype=torch.float64) + 0.5) * fine
    py, px = torch.meshgrid(ys, xs, indexing="ij")
    width, height = nx * res, ny * res
    grid = (px < margin) | (px > width - margin) | (py < margin) | (py > height - margin)
    if not grid_map.has_obstacles:
        return grid
    # Map cell of each fine cell, then every map cell within reach of the margin: a short loop over
    # window offsets at build time, vectorised over the whole grid.
    col = torch.div(torch.arange(nx * supersample), supersample, rounding_mode="floor")
    row = torch.div(torch.arange(ny * supersample), supersample, rounding_mode="floor")
    reach = math.ceil(margin / res)
    occupancy = grid_map.occupancy
    for dr in range(-reach, reach + 1):
        for dc in range(-reach, reach + 1):
            r = (row + dr).clamp(0, ny - 1)
            c = (col + dc).clamp(0, nx - 1)
            occupied = occupancy[r][:, c]
            # Distance from the fine-cell centre to the square of map cell (r, c).
            x0, y0 = c.double() * res, r.double() * res
            dx = torch.clamp(torch.maximum(x0[None, :] - px, px - (x0[None, :] + res)), min=0.0)
            dy = torch.clamp(torch.maximum(y0[:, None] - py, py - (y0[:, None] + res)), min=0.0)
            grid |= occupied & (dx * dx + dy * dy < margin * margin)
    return grid


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
