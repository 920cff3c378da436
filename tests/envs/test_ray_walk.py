"""Tests of aia/envs/ray_walk.py: the walked rays equal the gathered ones ray by ray, the closest obstacle equals
the gathers' to the bit (eager and compiled), and the block distances equal a brute-force chessboard distance."""

from __future__ import annotations

import math

import numpy as np
import torch

from aia.envs.config import RandomMapConfig
from aia.envs.map_generator import RandomObstacles
from aia.envs.ray_walk import BLOCK
from aia.envs.sensing import WorldMapGeometry

MARGIN, RANGE, FOV, SPACING = 0.5, 10.0, math.radians(120), 0.05


def _maps() -> tuple[WorldMapGeometry, torch.Tensor]:
    """Six 20 m x 20 m maps at 0.2 m (101 x 101 cells: the last block is cut by the border): empty, one cell, a
    wall across, a dense random scatter and two generated layouts; and 400 poses in each, some inside obstacles
    and some at the border."""
    occ = torch.zeros(6, 101, 101, dtype=torch.bool)
    occ[1, 50, 50] = True
    occ[2, 30:90, 60] = True
    occ[3] = torch.rand(101, 101, generator=torch.Generator().manual_seed(3)) < 0.02
    layouts = RandomObstacles(RandomMapConfig(size=[20.2, 20.2], resolution=0.2, min_start_area=0.05), MARGIN)
    occ[4:] = layouts.generate(torch.tensor([11, 12]))[0]
    geometry = WorldMapGeometry(6, (20.2, 20.2), 0.2, MARGIN, RANGE, FOV, SPACING, 4, "cpu", torch.float32)
    geometry.set_maps(torch.arange(6), occ, torch.ones_like(occ))
    gen = torch.Generator().manual_seed(0)
    xy = torch.rand(6, 400, 2, generator=gen) * 20.2
    xy[:, :20] = xy[:, :20] * 0.02  # next to the lower-left corner
    heading = (torch.rand(6, 400, 1, generator=gen) * 2 - 1) * math.pi
    return geometry, torch.cat((xy, heading), -1)


def _bins(geometry: WorldMapGeometry, pose: torch.Tensor) -> torch.Tensor:
    first = torch.ceil((pose[..., 2:3] - 0.5 * geometry.fov) / geometry.bin_width).long()
    return torch.remainder(first + torch.arange(geometry.fov_bins), geometry.num_bins)


def test_each_walked_ray_is_the_gathered_ray():
    """One ray a call (nothing to prune against): every ray's first hit, or inf, is the gathered one."""
    geometry, pose = _maps()
    row, col = geometry._cell_rows_cols(pose[..., :2], geometry.resolution, geometry.shape)
    bins = _bins(geometry, pose)
    gathered = geometry._gathered_hits(row, col, bins)
    walked = torch.stack([geometry._walk.hits(geometry.occupancy, row, col, bins[..., f:f + 1],
                                              torch.full((6, 400, 1), math.inf))[..., 0]
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
    geometry._walk = None
    gathered = geometry.closest_obstacle(pose)
    gathered_compiled = torch.compile(geometry.closest_obstacle, fullgraph=True, dynamic=False)(pose)
    assert torch.equal(walked, gathered) and torch.equal(walked_compiled, gathered_compiled)
    assert (walked[..., 0] < RANGE).float().mean() > 0.5


def test_block_distances_are_chessboard_distances_between_blocks():
    geometry, _ = _maps()
    occ = geometry.occupancy
    B, ny, nx = occ.shape
    nby, nbx = math.ceil(ny / BLOCK), math.ceil(nx / BLOCK)
    padded = torch.zeros(B, nby * BLOCK, nbx * BLOCK, dtype=torch.bool)
    padded[:, :ny, :nx] = occ
    occupied_blocks = padded.view(B, nby, BLOCK, nbx, BLOCK).any(-1).any(-2)
    i, j = torch.meshgrid(torch.arange(nby), torch.arange(nbx), indexing="ij")
    chessboard = torch.maximum((i.reshape(-1, 1) - i.reshape(1, -1)).abs(), (j.reshape(-1, 1) - j.reshape(1, -1)).abs())
    for b in range(B):
        to_occupied = chessboard[:, occupied_blocks[b].flatten()]
        expected = to_occupied.min(-1).values if to_occupied.shape[1] else torch.full((nby * nbx,), 255)
        assert np.array_equal(geometry._walk.block_distance[b].flatten().numpy(), expected.clamp_max(255).numpy())
    # no occupied block; one at block (12, 12), the farthest (25, 25)
    assert geometry._walk.block_distance[0].eq(255).all() and geometry._walk.block_distance[1].max() == 13
