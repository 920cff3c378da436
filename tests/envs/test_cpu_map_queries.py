"""Tests of aia/envs/cpu_map_queries.py: the walked rays equal the gathered ones ray by ray, the closest obstacle equals
the gathers' to the bit (eager and compiled), the block distances equal a brute-force chessboard distance, and the
collisions and lines of sight equal the fixed-map grid and the gathered samples."""

from __future__ import annotations

import math

import numpy as np
import torch

from aia.envs.config import RandomMapConfig
from aia.envs.cpu_map_queries import BLOCK
from aia.envs.map_generator import RandomObstacles
from aia.envs.maps import GridMap
from aia.envs.sensing import MapGeometry, WorldMapGeometry

MARGIN, RANGE, FOV, SPACING = 0.5, 10.0, math.radians(120), 0.05


def _maps(dtype: torch.dtype = torch.float32) -> tuple[WorldMapGeometry, torch.Tensor]:
    """Six 20 m x 20 m maps at 0.2 m (101 x 101 cells: the last block is cut by the border): empty, one cell, a
    wall across, a dense random scatter and two generated layouts; and 400 poses in each, some inside obstacles
    and some at the border."""
    occ = torch.zeros(6, 101, 101, dtype=torch.bool)
    occ[1, 50, 50] = True
    occ[2, 30:90, 60] = True
    occ[3] = torch.rand(101, 101, generator=torch.Generator().manual_seed(3)) < 0.02
    layouts = RandomObstacles(RandomMapConfig(size=[20.2, 20.2], resolution=0.2, min_start_area=0.05), MARGIN)
    occ[4:] = layouts.generate(torch.tensor([11, 12]))[0]
    geometry = WorldMapGeometry(6, (20.2, 20.2), 0.2, MARGIN, RANGE, FOV, SPACING, 4, "cpu", dtype)
    geometry.set_maps(torch.arange(6), occ, torch.ones_like(occ))
    gen = torch.Generator().manual_seed(0)
    xy = torch.rand(6, 400, 2, generator=gen) * 20.2
    xy[:, :20] = xy[:, :20] * 0.02  # next to the lower-left corner
    heading = (torch.rand(6, 400, 1, generator=gen) * 2 - 1) * math.pi
    return geometry, torch.cat((xy, heading), -1).to(dtype)


def _bins(geometry: WorldMapGeometry, pose: torch.Tensor) -> torch.Tensor:
    first = torch.ceil((pose[..., 2:3] - 0.5 * geometry.fov) / geometry.bin_width).long()
    return torch.remainder(first + torch.arange(geometry.fov_bins), geometry.num_bins)


def test_each_walked_ray_is_the_gathered_ray():
    """One ray a call (nothing to prune against): every ray's first hit, or inf, is the gathered one."""
    geometry, pose = _maps()
    row, col = geometry._cell_rows_cols(pose[..., :2], geometry.resolution, geometry.shape)
    bins = _bins(geometry, pose)
    gathered = geometry._gathered_hits(row, col, bins)
    no_lead = torch.full((6, 400), -1)
    walked = torch.stack([geometry._cpu.hits(row, col, bins[..., f:f + 1],
                                              torch.full((6, 400, 1), math.inf), no_lead)[..., 0]
                          for f in range(bins.shape[-1])], -1)
    assert torch.equal(walked, gathered)
    finite = torch.isfinite(gathered)
    assert 0.05 < finite.float().mean() < 0.95  # hits and misses


def test_closest_obstacle_walked_equals_gathered_eager_and_compiled():
    """The same bits as the gathers, in eager mode and inside ``torch.compile`` (where inductor's wall arithmetic
    may round differently from eager's, the same for both)."""
    geometry, pose = _maps()
    walked = geometry.closest_obstacle(pose)
    walked_compiled = torch.compile(geometry.closest_obstacle, fullgraph=True, dynamic=False)(pose)
    geometry._cpu = None
    gathered = geometry.closest_obstacle(pose)
    gathered_compiled = torch.compile(geometry.closest_obstacle, fullgraph=True, dynamic=False)(pose)
    assert torch.equal(walked, gathered) and torch.equal(walked_compiled, gathered_compiled)
    assert (walked[..., 0] < RANGE).float().mean() > 0.5


def test_the_lead_ray_changes_no_closest_obstacle():
    """Whatever ray the walk takes first (toward the true closest obstacle, a point beside it, anywhere, or none),
    the minimum and its first index are the same, in eager mode and compiled (each against itself: inductor's
    wall arithmetic may round differently from eager's); and the lead is the ray toward the last obstacle."""
    geometry, pose = _maps()
    walked = geometry.closest_obstacle(pose)
    anywhere = torch.rand(6, 400, 2, generator=torch.Generator().manual_seed(1)) * torch.tensor([10.0, math.pi])
    compiled = torch.compile(geometry.closest_obstacle, fullgraph=True, dynamic=False)
    walked_compiled = compiled(pose, (pose, torch.zeros_like(anywhere)))  # toward the robot: a ray, not the best
    moved = pose + torch.tensor([0.7, -0.4, 0.3])
    for last in ((pose, walked), (moved, walked), (pose, anywhere), (moved, anywhere)):
        assert torch.equal(geometry.closest_obstacle(pose, last), walked)
        assert torch.equal(compiled(pose, last), walked_compiled)
    bins = _bins(geometry, pose)
    lead = geometry._lead_ray(pose, bins, (pose, walked))
    seen = (walked[..., 0] < RANGE) & (walked[..., 0] > 0)  # at distance 0 the point is the robot's
    assert (lead[seen] >= 0).all()
    lead_angle = torch.gather(bins, -1, lead.clamp_min(0)[..., None])[..., 0] * geometry.bin_width
    offset = torch.remainder(lead_angle - pose[..., 2] - walked[..., 1] + math.pi, 2 * math.pi) - math.pi
    assert (offset[seen].abs() <= geometry.bin_width / 2 + 1e-5).all()
    assert (geometry._lead_ray(pose, bins, None) == -1).all()


def _blocks(occupancy: torch.Tensor) -> torch.Tensor:
    """``[B, nby, nbx, BLOCK * BLOCK]`` each block's cells, row by row (the grid padded with free cells)."""
    B, ny, nx = occupancy.shape
    nby, nbx = math.ceil(ny / BLOCK), math.ceil(nx / BLOCK)
    padded = torch.zeros(B, nby * BLOCK, nbx * BLOCK, dtype=torch.bool)
    padded[:, :ny, :nx] = occupancy
    return padded.view(B, nby, BLOCK, nbx, BLOCK).permute(0, 1, 3, 2, 4).reshape(B, nby, nbx, BLOCK * BLOCK)


def test_block_distances_are_chessboard_distances_between_blocks():
    geometry, _ = _maps()
    occupied_blocks = _blocks(geometry.occupancy).any(-1)
    B, nby, nbx = occupied_blocks.shape
    i, j = torch.meshgrid(torch.arange(nby), torch.arange(nbx), indexing="ij")
    chessboard = torch.maximum((i.reshape(-1, 1) - i.reshape(1, -1)).abs(), (j.reshape(-1, 1) - j.reshape(1, -1)).abs())
    for b in range(B):
        to_occupied = chessboard[:, occupied_blocks[b].flatten()]
        expected = to_occupied.min(-1).values if to_occupied.shape[1] else torch.full((nby * nbx,), 255)
        assert np.array_equal(geometry._cpu.block_distance[b].flatten().numpy(), expected.clamp_max(255).numpy())
    # no occupied block; one at block (12, 12), the farthest (25, 25)
    assert geometry._cpu.block_distance[0].eq(255).all() and geometry._cpu.block_distance[1].max() == 13


def test_collision_of_every_fine_cell_is_the_fixed_maps_grid():
    """At the centre of every fine cell of each map, the kernel's collision is the fixed-map geometry's collision
    grid on that map (the points on the margin's edge included)."""
    geometry, _ = _maps()
    ny, nx = geometry.fine_shape
    rows, cols = torch.meshgrid(torch.arange(ny), torch.arange(nx), indexing="ij")
    centres = (torch.stack((cols, rows), -1).reshape(-1, 2).float() + 0.5) * geometry.fine_cell
    collision = geometry.in_collision(centres.expand(6, -1, -1))
    for b in range(6):
        fixed = MapGeometry(GridMap("world", 0.2, geometry.occupancy[b]), MARGIN, RANGE, FOV, SPACING, 4)
        assert torch.equal(collision[b], fixed.collision.flatten()), b
    assert 0.05 < collision[3].float().mean() < 0.95


def test_line_of_sight_equals_the_gathered_samples():
    """Segments of every length from every kind of place: the kernel's answer is the gathered samples' where
    wanted, False elsewhere."""
    geometry, pose = _maps()
    gen = torch.Generator().manual_seed(5)
    target = pose[..., :2] + (torch.rand(6, 400, 2, generator=gen) * 2 - 1) * torch.rand(6, 400, 1, generator=gen) * 8
    wanted = torch.rand(6, 400, generator=gen) < 0.8
    kernel = geometry.line_of_sight(pose[..., :2], target, wanted)
    geometry._cpu = None
    gathered = geometry.line_of_sight(pose[..., :2], target)
    assert torch.equal(kernel, gathered & wanted)
    assert 0.1 < gathered[3].float().mean() < 0.9


def test_block_cells_are_the_occupied_cells_bits():
    geometry, _ = _maps()
    expected = (_blocks(geometry.occupancy).long() << torch.arange(BLOCK * BLOCK)).sum(-1)
    assert torch.equal(geometry._cpu.block_cells.long() & 0xFFFF, expected)
    assert (expected >= 1 << 15).any()  # the sign bit in use


def test_float64_worlds_walk_and_sight_as_gathered():
    """The kernels' float64 entries: the closest obstacle and the lines of sight of a float64 env."""
    geometry, pose = _maps(torch.float64)
    target = pose[..., :2].flip(1)
    walked, sight = geometry.closest_obstacle(pose), geometry.line_of_sight(pose[..., :2], target)
    geometry._cpu = None
    assert torch.equal(walked, geometry.closest_obstacle(pose))
    assert torch.equal(sight, geometry.line_of_sight(pose[..., :2], target))
    assert walked.dtype == torch.float64 and 0.1 < sight.float().mean() < 0.9
