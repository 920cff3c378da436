"""Tests of aia/envs/map_generator.py and env.map=random_obstacles: seeded layouts, independent of the batch,
starts in free connected space, one-line errors."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from scipy import ndimage

from aia.config.errors import ConfigError
from aia.envs import make_env
from aia.envs.config import RandomMapConfig
from aia.envs.map_generator import RandomObstacles, _rectangle, start_cells
from aia.envs.sensing import WorldMapGeometry

MARGIN = 0.5
# A small map keeps the tests quick: 12 m at 0.25 m, 3-5 obstacles.
SMALL = ["map=random_obstacles", "random_map.size=[12.0,12.0]", "random_map.resolution=0.25",
         "random_map.num_obstacles=[3,5]", "random_map.length=[1.0,4.0]", "sensor.range=6.0"]


def _layouts(**fields) -> RandomObstacles:
    defaults = dict(size=[12.0, 12.0], resolution=0.25, num_obstacles=[3, 5], length=[1.0, 4.0])
    return RandomObstacles(RandomMapConfig(**{**defaults, **fields}), MARGIN)


def test_layouts_are_seeded_and_independent_of_the_batch():
    layouts = _layouts()
    keys = torch.arange(16) * 7919 + 3
    occupancy, starts, row_starts = layouts.generate(keys)
    again, again_starts, _ = layouts.generate(keys[[5, 2, 11]])
    assert torch.equal(again, occupancy[[5, 2, 11]]) and torch.equal(again_starts, starts[[5, 2, 11]])
    assert torch.equal(row_starts, starts.sum(-1))
    # written in place into the rows of an env's buffers
    buffers = (torch.ones(20, 48, 48, dtype=torch.bool), torch.ones(20, 48, 48, dtype=torch.bool),
               torch.zeros(20, 48, dtype=torch.int64))
    layouts.generate(keys[[5, 2]], torch.tensor([19, 0]), buffers)
    assert torch.equal(buffers[0][[19, 0]], occupancy[[5, 2]]) and torch.equal(buffers[1][[19, 0]], starts[[5, 2]])
    assert buffers[0][1:19].all() and torch.equal(buffers[2][[19, 0]], row_starts[[5, 2]])
    assert occupancy.shape == (16, 48, 48) and occupancy.any((1, 2)).all()
    assert len({tuple(o.flatten().tolist()) for o in occupancy}) == 16  # a different layout per key


@pytest.mark.parametrize("shape", ["box", "l", "t"])
def test_each_shape_is_drawn(shape):
    occupancy, _, _ = _layouts(shapes=[shape], num_obstacles=[1, 1], length=[3.0, 3.0], width=[1.0, 1.0],
                            rotation_deg=0.0).generate(torch.arange(8))
    cells = occupancy.flatten(1).sum(1).float()
    # box: 3 x 1 m; l and t: two 3 x 1 m rectangles that share a 1 x 1 m square (16 cells a square metre), less
    # what sticks out of the map.
    full = {"box": 48, "l": 80, "t": 80}[shape]
    assert (cells <= full).all() and (cells == full).float().mean() >= 0.5


def _whole_square_free(occupancy: np.ndarray, resolution: float) -> np.ndarray:
    """Cells whose whole square lies at least MARGIN from the bounds and from every occupied square (brute force)."""
    ny, nx = occupancy.shape
    rows, cols = np.mgrid[0:ny, 0:nx]
    occ_rows, occ_cols = np.nonzero(occupancy)
    gap_x = np.maximum(np.abs(cols[..., None] - occ_cols) - 1, 0) * resolution
    gap_y = np.maximum(np.abs(rows[..., None] - occ_rows) - 1, 0) * resolution
    near = (gap_x**2 + gap_y**2 < MARGIN**2).any(-1)
    walls = ((cols * resolution < MARGIN) | ((cols + 1) * resolution > nx * resolution - MARGIN)
             | (rows * resolution < MARGIN) | ((rows + 1) * resolution > ny * resolution - MARGIN))
    return ~(near | walls)


def test_start_cells_are_the_largest_connected_group_of_free_cells():
    occupancy, starts, _ = _layouts(min_start_area=0.05).generate(torch.arange(4))
    assert torch.equal(starts, start_cells(occupancy, 0.25, MARGIN))
    for occ, start in zip(occupancy.numpy(), starts.numpy(), strict=True):
        labels, _ = ndimage.label(_whole_square_free(occ, 0.25))  # 4-connected groups
        sizes = np.bincount(labels.ravel())[1:]
        np.testing.assert_array_equal(start, labels == sizes.argmax() + 1)


@pytest.mark.parametrize("angle", [0.0, math.pi / 2, -math.pi, 3e-9, 2e-6, 0.3, -2.2, math.pi / 4])
def test_a_rectangles_runs_are_its_cells_whose_centre_it_holds(angle):
    """The runs are, row by row, the first to the last cell of the bounding box whose centre passes the rectangle's
    test (brute force over every cell), for angles along the axes, near them (each side of the steep cut) and
    between; thin rectangles (under a cell wide) and ones that stick out of the map included."""
    resolution, shape = 0.2, (60, 70)
    generator = np.random.default_rng(7)
    for _ in range(40):
        cx, cy = generator.uniform(-1.0, 15.0), generator.uniform(-1.0, 13.0)
        lx, ly = generator.uniform(-1.0, 1.0, 2)
        hx, hy = generator.uniform(0.05, 3.0), generator.uniform(0.05, 1.0)
        grid = np.zeros(shape, dtype=np.bool_)
        runs = np.zeros((shape[0], 3), dtype=np.int64)
        n = _rectangle(grid, runs, 0, resolution, cx, cy, angle, lx, ly, hx, hy)
        c, s = math.cos(angle), math.sin(angle)
        wx, wy = cx + lx * c - ly * s, cy + lx * s + ly * c
        ex, ey = abs(c) * hx + abs(s) * hy, abs(s) * hx + abs(c) * hy
        rows, cols = np.mgrid[0:shape[0], 0:shape[1]]
        dx, dy = (cols + 0.5) * resolution - wx, (rows + 0.5) * resolution - wy
        inside = (np.abs(dx * c + dy * s) <= hx) & (np.abs(-dx * s + dy * c) <= hy)
        inside &= (cols >= math.ceil((wx - ex) / resolution - 0.5)) & (cols <= math.floor((wx + ex) / resolution - 0.5))
        inside &= (rows >= math.ceil((wy - ey) / resolution - 0.5)) & (rows <= math.floor((wy + ey) / resolution - 0.5))
        expected = [(r, np.flatnonzero(inside[r])[0], np.flatnonzero(inside[r])[-1]) for r in range(shape[0])
                    if inside[r].any()]
        assert [tuple(run) for run in runs[:n].tolist()] == expected
        hull = np.zeros(shape, dtype=np.bool_)
        for r, lo, hi in expected:
            hull[r, lo:hi + 1] = True
        np.testing.assert_array_equal(grid, hull)


def test_drawn_block_fields_are_the_grids_fields():
    """The block fields a CPU env's maps get as they are drawn (from their runs) equal those made from their grids."""
    layouts = _layouts()
    drawn = WorldMapGeometry(6, (12.0, 12.0), 0.25, MARGIN, 6.0, 2.0, 0.05)
    drawn.draw_maps(torch.arange(6), layouts, torch.arange(6) * 31 + 1)
    from_grids = WorldMapGeometry(6, (12.0, 12.0), 0.25, MARGIN, 6.0, 2.0, 0.05)
    from_grids.set_maps(torch.arange(6), drawn.occupancy, drawn.start_cells)
    assert drawn._cpu.block_distance.min() == 0 and drawn._cpu.block_cells.ne(0).any()
    assert torch.equal(drawn._cpu.block_distance, from_grids._cpu.block_distance)
    assert torch.equal(drawn._cpu.block_cells, from_grids._cpu.block_cells)
    assert torch.equal(drawn._start_rows, from_grids._start_rows)


def test_env_maps_per_world_episode_and_batch():
    env = make_env("random_obstacles", batch_size=4, seed=5, overrides=SMALL, transforms=False)
    big = make_env("random_obstacles", batch_size=8, seed=5, overrides=SMALL, transforms=False)
    td, big_td = env.reset(), big.reset()
    maps = env.geometry.occupancy.clone()
    assert torch.equal(maps, big.geometry.occupancy[:4])
    assert torch.equal(td["robot_pose"], big_td["robot_pose"][:4])
    geometry = env.geometry
    assert geometry.free_start(td["robot_pose"][:, :2]).all() and geometry.free_start(td["target_state"][..., :2]).all()
    # a partial reset draws new maps for the reset worlds only
    reset = torch.tensor([True, False, True, False])
    env.reset(env.state.clone().set("_reset", reset[:, None]))
    assert torch.equal(env.geometry.occupancy[~reset], maps[~reset])
    now = env.geometry.occupancy
    assert not torch.equal(now[0], maps[0]) and not torch.equal(now[2], maps[2])
    assert torch.equal(env.world_map(1).occupancy, maps[1]) and torch.equal(env.map.occupancy, now[0])


def test_rollout_on_random_maps_keeps_every_world_in_its_free_space():
    env = make_env("random_obstacles", batch_size=4, seed=1, overrides=[*SMALL, "num_targets=2", "max_steps=15"])
    rollout = env.rollout(20, break_when_any_done=False)  # crosses a reset: new maps at step 15
    base = env.base_env
    assert rollout["next", "observation"].isfinite().all()
    assert rollout["next", "collision"].any() and not base.geometry.in_collision(env.state["robot_pose"][:, :2]).any()
    assert not base.geometry.in_collision(env.state["target_state"][..., :2]).any()
    assert (rollout["next", "obstacle_polar"][..., 0] < 6.0).any()


@pytest.mark.parametrize("override, key", [
    ("random_map.num_obstacles=[3,2]", "env.random_map.num_obstacles"),
    ("random_map.length=[0.0,2.0]", "env.random_map.length"),
    ("random_map.shapes=[box,circle]", "env.random_map.shapes"),
    ("random_map.size=[12.1,12.0]", "env.random_map.size"),
    ("random_map.min_start_area=1.5", "env.random_map.min_start_area"),
    ("random_map.rotation_deg=-1", "env.random_map.rotation_deg"),
    ("target.collision_rule=detour", "env.target.collision_rule"),
])
def test_bad_random_map_settings(override, key):
    with pytest.raises(ConfigError) as info:
        make_env("random_obstacles", overrides=[*SMALL, override])
    assert str(info.value).startswith(key) and "\n" not in str(info.value)


def test_a_layout_that_cannot_leave_room_is_one_line():
    crowded = [*SMALL, "random_map.num_obstacles=[40,40]", "random_map.width=[1.0,2.0]", "random_map.attempts=2",
               "random_map.min_start_area=0.5"]
    env = make_env("random_obstacles", batch_size=2, seed=0, overrides=crowded)
    with pytest.raises(ConfigError, match=r"^env.random_map='2 of 2 worlds': expected layouts whose") as info:
        env.reset()
    assert "\n" not in str(info.value)
