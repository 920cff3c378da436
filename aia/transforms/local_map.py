"""``LocalMap``: the authors' ttenv map image around the robot (TargetTracking-v4 and -v5), batched over worlds.

The image is ``local_map`` ``[B, C, H, W]``: ``H`` counts cells forward from the robot, ``W`` cells across from
its left to its right (ttenv's ``local_map[c, r]``), ``im_size`` each, one map cell a pixel. Channel 0 is the
occupancy of the square in front of the robot, ``-1`` free and ``+1`` occupied or outside the map (ttenv's
``(occupied - 0.5) * 2``). With ``occupancy_visits``, channels 1-4 are the visit frequencies of the squares of the
same size left of, right of, in front of and behind it (ttenv's ``local_visit_map_surroundings``): ``+1`` on an
occupied or outside cell, the world's visit frequency ``- 1`` on a cell at least ``margin`` from the bounds
(ttenv's ``in_bound``), ``-1`` elsewhere.

Each world keeps a visit-frequency map of its grid. A step first decays it by ``0.7`` to the power
``dt * b / sensor_range`` (``b``: the mean speed of the beliefs, 0 for beliefs without a velocity), then sets to 1
the cells the sensor's rays cross: rays every ``ray_spacing`` over the field of view, each the Bresenham line of
cells from the robot's cell to the cell at the sensor's range, up to its first occupied or outside cell. A world
that resets starts from zeros and marks its first view (ttenv's ``reset_visit_freq_map``).

The decay is kept lazily (:class:`Visits`): each world's clock sums the logarithms of its decays, each cell holds
the clock of its last visit, and a cell's frequency is ``exp(clock - stamp)``, read only for the cells an image
shows. Multiplying every cell of every world each step moved 0.5 GB a step at 4,096 worlds of 181 x 181 cells;
the lazy frequencies equal ttenv's repeated products (float64 numpy) to the rounding of the dtype. On the CPU
the rays are walked by a numba kernel to their first occupied cell (:func:`mark_visits`).

A point lies in the cell ``floor(xy / resolution)``; ttenv rounds ``xy / resolution - 0.5`` half away from zero
(half to even at the rays' ends), which differs only for points exactly on a cell boundary.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, NamedTuple

import numba
import numpy as np
import torch
from tensordict import TensorDictBase
from torch import Tensor
from torchrl.data import Bounded, Composite
from torchrl.envs.transforms import Transform

from aia.envs.config import LOCAL_MAP_CHANNELS
from aia.runtime.compiling import compiled
from aia.runtime.cpu_threads import array1, array2, array3, descriptor, in_chunks, integer, kernel_entry, run_kernel

if TYPE_CHECKING:
    from aia.envs.sensing import Geometry

LOCAL_MAP_KEY = "local_map"
# Each image's square, as (lateral, forward) of its corner behind and left, in image sides from the robot:
# the occupancy in front; the visit frequencies left, right, in front of and behind that square (ttenv's order).
OCCUPANCY_SQUARE = ((-0.5, 0.0),)
VISIT_SQUARES = ((-1.5, 0.0), (0.5, 0.0), (-0.5, 1.0), (-0.5, -1.0))
# ttenv: the visit frequencies fall to this fraction while a belief at the mean belief speed crosses the sensor range.
VISIT_DECAY = 0.7
OBSTACLE_VISIT = 2.0  # ttenv's visit value of an occupied cell (then shifted by -1 with the others)


class Visits(NamedTuple):
    """Each world's visit frequencies, kept lazily: cell ``i`` of world ``b`` holds ``exp(clock[b] - stamps[b, i])``
    (``stamps [B, ny * nx + 1]``: each world's grid, flat, then one cell for the rays' other cells; ``inf`` for
    a cell never visited; ``clock [B]``: the sum of the logarithms of the world's decays)."""

    stamps: Tensor
    clock: Tensor

    @classmethod
    def empty(cls, worlds: int, cells: int, device: torch.device | str) -> Visits:
        """``worlds`` worlds' grids of ``cells`` cells, never visited; in float64, so that a clock far from 0 after a
        long episode still resolves a step's decay."""
        return cls(torch.full((worlds, cells + 1), math.inf, dtype=torch.float64, device=device),
                   torch.zeros(worlds, dtype=torch.float64, device=device))

    def frequencies(self) -> Tensor:
        """``[B, ny * nx + 1]`` the visit frequencies."""
        return torch.exp(self.clock[:, None] - self.stamps)

    def reset(self, worlds: Tensor) -> None:
        """Clear the worlds ``worlds [B]`` (bool): never visited, their clocks at 0."""
        self.stamps.masked_fill_(worlds.unsqueeze(-1), math.inf)
        self.clock.masked_fill_(worlds, 0.0)


class LocalMap(Transform):
    """Write the map image of ``geometry`` around ``robot_pose`` under ``out_key`` (default ``"local_map"``).

    ``layout`` is ``"occupancy"`` (ttenv v4, 1 channel) or ``"occupancy_visits"`` (v5, 5 channels, with the
    visit-frequency state per world, reset with the world). ``dt`` is the env's step, ``ray_spacing`` the angle
    between the sensor's rays that mark cells visited. ``compile=True`` computes the images through
    ``torch.compile`` (the visits' update stays eager: on the CPU its scatter is no faster compiled).
    """

    def __init__(self, geometry: Geometry, layout: str = "occupancy", im_size: int = 28, dt: float = 0.5,
                 ray_spacing: float = 0.05, out_key: str = LOCAL_MAP_KEY, compile: bool = False) -> None:
        if LOCAL_MAP_CHANNELS.get(layout, 0) == 0:
            layouts = [name for name, channels in LOCAL_MAP_CHANNELS.items() if channels]
            raise ValueError(f"layout={layout!r} is not one of {layouts}")
        super().__init__(in_keys=["robot_pose"], out_keys=[out_key])
        self.geometry = geometry
        self.channels = LOCAL_MAP_CHANNELS[layout]
        self.im_size = im_size
        self.dt = dt
        squares = OCCUPANCY_SQUARE + (VISIT_SQUARES if self.channels > 1 else ())
        self.squares = torch.tensor(squares, dtype=geometry.dtype, device=geometry.device)
        rays = math.ceil(geometry.fov / ray_spacing)  # numpy's arange(-fov / 2, fov / 2, ray_spacing)
        self.ray_angles = (torch.arange(rays, dtype=torch.float64) * ray_spacing - geometry.fov / 2).to(
            geometry.device, geometry.dtype)
        # the most cells a ray crosses along its longer axis, its first included
        self.ray_cells = math.floor(geometry.sensor_range / geometry.resolution) + 2
        self._visits: Visits | None = None
        self._map_images = compiled(map_images) if compile else map_images

    @property
    def visits(self) -> Tensor:
        """``[B, ny, nx]`` each world's visit frequencies (row = y cell)."""
        return self._visits.frequencies()[:, :-1].unflatten(1, self.geometry.shape)

    def _step(self, tensordict: TensorDictBase, next_tensordict: TensorDictBase) -> TensorDictBase:
        pose = next_tensordict.get("robot_pose")
        if self.channels > 1:
            decay = visit_decay(next_tensordict.get("belief_velocity", None), self.dt, self.geometry.sensor_range)
            everyone = torch.ones(pose.shape[0], dtype=torch.bool, device=pose.device)
            mark_visits(self._visits, self.geometry, pose, everyone, decay, self.ray_angles, self.ray_cells)
        next_tensordict.set(self.out_keys[0], self._images(pose))
        return next_tensordict

    def _reset(self, tensordict: TensorDictBase | None, tensordict_reset: TensorDictBase) -> TensorDictBase:
        pose = tensordict_reset.get("robot_pose")
        if self.channels > 1:
            reset = _reset_worlds(tensordict, pose)
            if self._visits is None:
                cells = self.geometry.shape[0] * self.geometry.shape[1]
                self._visits = Visits.empty(pose.shape[0], cells, pose.device)
            self._visits.reset(reset)
            mark_visits(self._visits, self.geometry, pose, reset, 1.0, self.ray_angles, self.ray_cells)
        tensordict_reset.set(self.out_keys[0], self._images(pose))
        return tensordict_reset

    def _images(self, pose: Tensor) -> Tensor:
        visits = self._visits if self.channels > 1 else None
        return self._map_images(self.geometry, pose, self.squares, self.im_size, visits)

    def transform_observation_spec(self, observation_spec: Composite) -> Composite:
        pose_spec = observation_spec["robot_pose"]
        shape = (*pose_spec.shape[:-1], self.channels, self.im_size, self.im_size)
        observation_spec[self.out_keys[0]] = Bounded(low=-1.0, high=1.0, shape=shape, dtype=pose_spec.dtype,
                                                     device=pose_spec.device)
        return observation_spec


def _reset_worlds(tensordict: TensorDictBase | None, pose: Tensor) -> Tensor:
    """``[B]`` the worlds a reset resets: its ``"_reset"`` entry, or every world without one."""
    reset = None if tensordict is None else tensordict.get("_reset", None)
    worlds = pose.shape[0]
    return torch.ones(worlds, dtype=torch.bool, device=pose.device) if reset is None else reset.reshape(worlds)


def square_points(pose: Tensor, squares: Tensor, im_size: int, resolution: float) -> tuple[Tensor, Tensor]:
    """``(x, y)``, each ``[B, S, H, W]``: the world positions of the pixel centres of each square (``squares [S,
    2]``: (lateral, forward) of its corner in image sides) around ``pose [B, 3]``; ``H`` forward, ``W`` from left
    to right."""
    side = im_size * resolution
    centres = (torch.arange(im_size, dtype=pose.dtype, device=pose.device) + 0.5) * resolution
    lateral = (squares[:, 0, None] * side + centres)[None, :, None, :]  # [1, S, 1, W], positive to the right
    forward = (squares[:, 1, None] * side + centres)[None, :, :, None]  # [1, S, H, 1]
    x, y, theta = (pose[:, i, None, None, None] for i in range(3))
    cos, sin = torch.cos(theta), torch.sin(theta)
    return x + forward * cos + lateral * sin, y + forward * sin - lateral * cos


def flat_cells(col: Tensor, row: Tensor, geometry: Geometry) -> tuple[Tensor, Tensor]:
    """``(index, inside)``: the flat index ``row * nx + col`` into a world's grid of the integer cells ``col``,
    ``row`` (clamped into the grid where ``inside`` is False)."""
    ny, nx = geometry.shape
    inside = (row >= 0) & (row < ny) & (col >= 0) & (col < nx)
    return row.clamp(0, ny - 1) * nx + col.clamp(0, nx - 1), inside


def map_images(geometry: Geometry, pose: Tensor, squares: Tensor, im_size: int,
               visits: Visits | None = None) -> Tensor:
    """``[B, C, H, W]`` the occupancy image of ``squares[0]`` and, with ``visits`` (each world's), the
    visit-frequency images of ``squares[1:]`` around ``pose [B, 3]``, in ttenv's values (module docstring)."""
    x, y = square_points(pose, squares, im_size, geometry.resolution)
    index, inside = flat_cells(torch.floor(x / geometry.resolution).long(), torch.floor(y / geometry.resolution).long(),
                               geometry)
    blocked = ~inside | geometry.occupied(index)
    if visits is None:
        return torch.where(blocked, 1.0, -1.0).to(pose.dtype)
    width, height = geometry.size - geometry.margin
    in_bound = (x >= geometry.margin) & (x <= width) & (y >= geometry.margin) & (y <= height)
    in_bound[:, 0] = False  # the occupancy square
    stamps = torch.gather(visits.stamps, 1, index.flatten(1)).view_as(index)
    frequency = torch.exp(visits.clock.view(-1, 1, 1, 1) - stamps).to(pose.dtype)
    return torch.where(blocked, OBSTACLE_VISIT - 1.0, torch.where(in_bound, frequency - 1.0, -1.0))


def visit_decay(belief_velocity: Tensor | None, dt: float, sensor_range: float) -> Tensor | float:
    """``[B]`` ttenv v5's decay of the visit frequencies, ``0.7 ** (dt * b / sensor_range)`` with ``b`` the mean
    belief speed over targets (``belief_velocity [B, N, 2]``); 1 without a belief velocity."""
    if belief_velocity is None:
        return 1.0
    speed = torch.linalg.vector_norm(belief_velocity, dim=-1).mean(-1)
    return torch.exp(dt * speed / sensor_range * math.log(VISIT_DECAY))


def bresenham(start: Tensor, end: Tensor, length: int) -> tuple[Tensor, Tensor, Tensor]:
    """``(x, y, on_line)``, each ``[..., length]``: the Bresenham line of integer cells from ``start [..., 2]`` to
    ``end [..., 2]`` as ttenv's ``bresenham2D`` draws it, padded to ``length`` cells.

    Step ``k`` along the longer axis (the x axis on a tie) moves ``ceil((k * minor - floor(major / 2)) / major)``
    cells along the other, ``major`` and ``minor`` the lengths of the longer and the shorter axis.
    """
    delta = end - start
    direction = torch.where(delta >= 0, 1, -1).unsqueeze(-2)
    span = delta.abs()
    steep = (span[..., 1] > span[..., 0]).unsqueeze(-1)
    major = torch.where(steep, span[..., 1:], span[..., :1])
    minor = torch.where(steep, span[..., :1], span[..., 1:])
    along = torch.arange(length, device=start.device)
    across = -torch.div(major // 2 - along * minor, major.clamp_min(1), rounding_mode="floor")
    along = along.expand_as(across)
    x = start[..., :1] + torch.where(steep, across, along) * direction[..., 0]
    y = start[..., 1:] + torch.where(steep, along, across) * direction[..., 1]
    return x, y, along <= major


def mark_visits(visits: Visits, geometry: Geometry, pose: Tensor, worlds: Tensor, decay: Tensor | float,
                ray_angles: Tensor, ray_cells: int) -> None:
    """Decay the visit frequencies of the ``worlds [B]`` (bool) by ``decay`` (``[B]`` or a number) and set to 1 the
    cells their sensor's rays (``ray_angles [R]`` from the heading, to the sensor's range) cross before their first
    occupied or outside cell, in place."""
    resolution = geometry.resolution
    start = torch.floor(pose[:, :2] / resolution).long()
    angle = pose[:, 2:3] + ray_angles
    reach = geometry.sensor_range * torch.stack((torch.cos(angle), torch.sin(angle)), dim=-1)
    end = torch.floor((pose[:, None, :2] + reach) / resolution).long()
    decay = torch.as_tensor(decay, dtype=visits.clock.dtype, device=visits.clock.device)
    visits.clock.add_(torch.where(worlds, torch.log(decay), 0.0))
    if pose.device.type == "cpu":
        occupancy = geometry.occupancy if geometry.occupancy.ndim == 3 else geometry.occupancy[None]
        run_kernel(_mark_entry, pose.shape[0], (occupancy.contiguous(), start.contiguous(), end.contiguous(),
                                                worlds.contiguous(), ray_cells, visits.stamps, visits.clock))
    else:
        stamp_rays(visits, geometry, start, end, worlds, ray_cells)


def stamp_rays(visits: Visits, geometry: Geometry, start: Tensor, end: Tensor, worlds: Tensor, ray_cells: int
               ) -> None:
    """Stamp with their world's clock the cells of the rays from the cells ``start [B, 2]`` to ``end [B, R, 2]``
    (their Bresenham lines of at most ``ray_cells`` cells) before their first occupied or outside cell, for the
    ``worlds [B]``: in tensor ops, every cell of every ray gathered (what a GPU runs; the CPU walks them)."""
    x, y, on_line = bresenham(start.unsqueeze(1).expand_as(end), end, ray_cells)
    index, inside = flat_cells(x, y, geometry)
    clear = (~inside | geometry.occupied(index)).cumsum(-1) == 0
    seen = on_line & clear & worlds[:, None, None]
    cells = torch.where(seen, index, visits.stamps.shape[1] - 1).flatten(1)
    visits.stamps.scatter_(1, cells, visits.clock[:, None].expand_as(cells))


@numba.njit(cache=True, nogil=True)
def _mark_rays(occupancy, start, end, worlds, ray_cells, stamps, clock, first, last):  # pragma: no cover - compiled
    """For each world ``b`` in ``first..last - 1`` that ``worlds`` marks: ``stamps[b]`` of the cells of each ray's
    Bresenham line from ``start[b]`` to ``end[b, r]`` (:func:`bresenham`, at most ``ray_cells`` cells) before its
    first occupied or outside cell set to ``clock[b]``; the map ``occupancy[b]`` (or ``[0]``, one for all)."""
    ny, nx = occupancy.shape[1], occupancy.shape[2]
    for b in range(first, last):
        if not worlds[b]:
            continue
        grid = occupancy[b if occupancy.shape[0] > 1 else 0]
        sx, sy = start[b, 0], start[b, 1]
        for r in range(end.shape[1]):
            dx, dy = end[b, r, 0] - sx, end[b, r, 1] - sy
            step_x, step_y = (1 if dx >= 0 else -1), (1 if dy >= 0 else -1)
            steep = abs(dy) > abs(dx)
            major, minor = (abs(dy), abs(dx)) if steep else (abs(dx), abs(dy))
            for along in range(min(major + 1, ray_cells)):
                across = -((major // 2 - along * minor) // max(major, 1))
                x = sx + (across if steep else along) * step_x
                y = sy + (along if steep else across) * step_y
                if x < 0 or x >= nx or y < 0 or y >= ny or grid[y, x]:
                    break
                stamps[b, y * nx + x] = clock[b]


@kernel_entry("bool[3]", "int64[2]", "int64[3]", "bool[1]", "int", "float64[2]", "float64[1]")
def _mark_entry(data):  # pragma: no cover - compiled
    """:func:`_mark_rays` of ``(occupancy, start, end, worlds, ray_cells, stamps, clock)``, chunk by chunk of the
    worlds."""
    d = descriptor(data)
    occupancy, start, end = array3(d, 0, np.bool_), array2(d, 1, np.int64), array3(d, 2, np.int64)
    worlds, stamps, clock = array1(d, 3, np.bool_), array2(d, 5, np.float64), array1(d, 6, np.float64)
    in_chunks(d, _mark_rays, (occupancy, start, end, worlds, integer(d, 4), stamps, clock))
