"""Tests of aia/envs/sensing.py: collision, line of sight, closest obstacle, free sampling, polar table; per-world
maps answering as each world's own map."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from aia.envs.config import RandomMapConfig
from aia.envs.map_generator import RandomObstacles, start_cells
from aia.envs.maps import GridMap, load_map
from aia.envs.sensing import MapGeometry, WorldMapGeometry

MARGIN, RANGE, FOV, SPACING = 0.5, 10.0, math.radians(120), 0.05


def _geometry(occupancy: torch.Tensor, resolution: float = 0.5, name: str = "hand") -> MapGeometry:
    grid_map = GridMap(name, resolution, occupancy)
    return MapGeometry(grid_map, MARGIN, RANGE, FOV, SPACING, 4, "cpu", torch.float32)


@pytest.fixture(scope="module")
def obstacles4() -> MapGeometry:
    return MapGeometry(load_map("obstacles4"), MARGIN, RANGE, FOV, SPACING, 4, "cpu", torch.float32)


@pytest.fixture(scope="module")
def one_cell() -> MapGeometry:
    """10 m x 10 m at 0.5 m with one occupied cell x in [5, 5.5], y in [5, 5.5]."""
    occ = torch.zeros(20, 20, dtype=torch.bool)
    occ[10, 10] = True
    return _geometry(occ)


@pytest.fixture(scope="module")
def column() -> MapGeometry:
    """10 m x 10 m at 0.5 m with a full-height occupied column x in [6, 6.5]."""
    occ = torch.zeros(20, 20, dtype=torch.bool)
    occ[:, 12] = True
    return _geometry(occ)


@pytest.fixture(scope="module")
def big_column() -> MapGeometry:
    """30 m x 30 m at 0.5 m with a full-height occupied column x in [12, 12.5]; the bounds are out of range
    from (15, 15)."""
    occ = torch.zeros(60, 60, dtype=torch.bool)
    occ[:, 24] = True
    return _geometry(occ)


@pytest.fixture(scope="module")
def empty() -> MapGeometry:
    return MapGeometry(load_map("empty"), MARGIN, RANGE, FOV, SPACING, 4, "cpu", torch.float32)


# ---------------------------------------------------------------- geometry
def test_table_sizes(obstacles4, empty):
    assert obstacles4.num_bins == 126
    assert obstacles4.fov_bins == 42
    assert obstacles4.collision.shape == (724, 724)
    assert obstacles4.ray_table.shape == (181 * 181, 126)
    assert empty.ray_table is None and not empty.has_obstacles


# --------------------------------------------------------------- collision
def test_collision_near_bounds(one_cell):
    collide = torch.tensor([[0.3, 2.0], [9.7, 2.0], [2.0, 0.3], [2.0, 9.7], [0.3, 0.3], [-1.0, 5.0],
                            [11.0, 5.0],                            [5.0, -0.1], [5.0, 10.2]])
    free = torch.tensor([[0.7, 2.0], [9.3, 2.0], [2.0, 0.7], [2.0, 9.3], [0.7, 0.7], [9.3, 9.3]])
    assert one_cell.in_collision(collide).all()
    assert not one_cell.in_collision(free).any()


def test_collision_near_occupied_cell(one_cell):
    # Occupied square [5, 5.5]^2. Distances to it: 0.3 -> collides, 0.8 -> free, on all four sides.
    collide = torch.tensor([[4.7, 5.25], [5.8, 5.25], [5.25, 4.7], [5.25, 5.8], [5.25, 5.25],
                            [4.7, 4.7]])  # last one: 0.42 m from the corner (5, 5)
    free = torch.tensor([[4.2, 5.25], [6.3, 5.25], [5.25, 4.2], [5.25, 6.3],
                         [4.6, 4.6]])  # last one: 0.57 m from the corner: the margin is round, not square
    assert one_cell.in_collision(collide).all()
    assert not one_cell.in_collision(free).any()


def test_collision_batched_shape(one_cell):
    xy = torch.tensor([[[4.7, 5.25], [4.2, 5.25]], [[0.3, 2.0], [2.0, 2.0]]])
    out = one_cell.in_collision(xy)
    assert out.shape == (2, 2)
    assert out.tolist() == [[True, False], [True, False]]


def _distance_to_obstacles(points: np.ndarray, occ: np.ndarray, res: float) -> np.ndarray:
    """Exact distance from each point to the nearest occupied cell square and to the map bounds."""
    rows, cols = np.nonzero(occ)
    x0, y0 = cols * res, rows * res
    dx = np.maximum(np.maximum(x0[None] - points[:, :1], points[:, :1] - (x0[None] + res)), 0)
    dy = np.maximum(np.maximum(y0[None] - points[:, 1:], points[:, 1:] - (y0[None] + res)), 0)
    d_cells = np.sqrt(dx**2 + dy**2).min(1)
    w, h = occ.shape[1] * res, occ.shape[0] * res
    d_bounds = np.minimum.reduce([points[:, 0], w - points[:, 0], points[:, 1], h - points[:, 1]])
    return np.minimum(d_cells, d_bounds)


def test_collision_matches_exact_distance_on_obstacles4(obstacles4):
    rng = np.random.default_rng(0)
    pts = rng.uniform(0, 36.2, size=(4000, 2))
    dist = _distance_to_obstacles(pts, obstacles4.map.occupancy.numpy(), 0.2)
    got = obstacles4.in_collision(torch.tensor(pts, dtype=torch.float32)).numpy()
    # The collision grid tests fine-cell centres (0.05 m cells): exact away from a 0.04 m band at the margin.
    sure = np.abs(dist - MARGIN) > 0.04
    assert sure.sum() > 3500
    np.testing.assert_array_equal(got[sure], dist[sure] < MARGIN)
    assert 0.2 < got.mean() < 0.6


# ----------------------------------------------------------- line of sight
def test_line_of_sight_wall():
    occ = torch.zeros(20, 20, dtype=torch.bool)
    occ[6:14, 10] = True  # wall x in [5, 5.5], y in [3, 7]
    geo = _geometry(occ)
    origin = torch.tensor([[2.0, 5.0], [2.0, 1.0], [2.0, 8.5], [2.0, 2.0], [5.25, 8.0], [2.0, 5.0]])
    target = torch.tensor([[8.0, 5.0], [8.0, 1.0], [8.0, 8.5], [8.0, 8.0], [5.25, 2.0], [4.5, 5.0]])
    # Through the wall; below it; above it; diagonal through it; along it; stopping short of it.
    assert geo.line_of_sight(origin, target).tolist() == [False, True, True, False, False, True]
    # Symmetric.
    assert geo.line_of_sight(target, origin).tolist() == [False, True, True, False, False, True]


def test_line_of_sight_obstacles4(obstacles4):
    origin = torch.tensor([[1.5, 12.0], [1.5, 20.0], [20.0, 12.0], [18.0, 18.0]])
    target = torch.tensor([[11.0, 12.0], [11.0, 20.0], [28.0, 12.0], [18.0, 5.0]])
    # Through box A; above it; through box B; clear vertical segment in the middle.
    assert obstacles4.line_of_sight(origin, target).tolist() == [False, True, False, True]


def test_line_of_sight_empty_map_always_clear(empty):
    out = empty.line_of_sight(torch.zeros(3, 2), torch.tensor([[5.0, 5.0], [100.0, 0.0], [0.0, 0.0]]))
    assert out.tolist() == [True, True, True]


# -------------------------------------------------------- closest obstacle
def test_closest_obstacle_column_ahead(column):
    out = column.closest_obstacle(torch.tensor([[2.0, 5.0, 0.0], [2.25, 5.25, 0.0], [2.0, 5.0, 0.3]]))
    assert out.shape == (3, 2)
    # 4.0 m from (2, 5) to x = 6, within one ray sample (resolution / 2) of the cell-centre table.
    assert abs(out[0, 0].item() - 4.0) <= 0.25 + 1e-5
    assert abs(out[0, 1].item()) <= column.bin_width / 2
    # From the cell centre (2.25, 5.25) the column is 3.75 m away.
    assert abs(out[1, 0].item() - 3.75) <= 0.25 + 1e-5
    # Turned 0.3 rad left, the closest point still lies straight along the x axis: bearing -0.3.
    assert out[2, 1].item() == pytest.approx(-0.3, abs=column.bin_width / 2)
    assert abs(out[2, 0].item() - 4.0) <= 0.25 + 1e-5


def test_closest_obstacle_behind_is_ignored(big_column):
    # Column 2.5 m behind, bounds 14.5 m ahead and >10 m up/down within the field of view: nothing in view.
    # (Heading 0.5 keeps the field of view within [-0.55, 1.55] rad, away from the column at angle pi.)
    poses = torch.tensor([[15.0, 15.0, 0.0], [15.0, 15.0, 0.5], [15.0, 15.0, -0.5]])
    out = big_column.closest_obstacle(poses)
    assert (out[:, 0] == RANGE).all()
    assert (out[:, 1] == torch.tensor(math.pi, dtype=torch.float32)).all()


def test_closest_obstacle_facing_column_distance(big_column):
    # Facing the column (x in [12, 12.5]) from 2.5 m: seen, within a cell of the true distance.
    out = big_column.closest_obstacle(torch.tensor([[15.0, 15.0, math.pi]]))
    assert out[0, 0].item() < RANGE
    assert abs(out[0, 0].item() - 2.5) <= 0.5 + 1e-5


def test_closest_obstacle_perpendicular_wall_bearing(big_column, obstacles4):
    out = big_column.closest_obstacle(torch.tensor([[15.0, 15.0, math.pi]]))
    assert abs(out[0, 1].item()) <= 2 * big_column.bin_width
    # The same on obstacles4: box A's right face (x = 9.4) straight ahead from (12, 12) heading pi.
    out = obstacles4.closest_obstacle(torch.tensor([[12.0, 12.0, math.pi]]))
    assert abs(out[0, 0].item() - 2.6) <= 0.3
    assert abs(out[0, 1].item()) <= 2 * obstacles4.bin_width


def test_closest_obstacle_nothing_in_range_exact(big_column, empty):
    cases = ((big_column, [15.0, 15.0, 0.0]), (empty, [50.5, 50.5, 0.3]), (empty, [95.0, 50.5, math.pi]))
    for geo, pose in cases:
        out = geo.closest_obstacle(torch.tensor([pose]))
        assert out[0, 0].item() == RANGE
        assert out[0, 1].item() == torch.tensor(math.pi, dtype=torch.float32).item()


def test_closest_obstacle_empty_map_wall(empty):
    poses = torch.tensor([[95.0, 50.5, 0.0], [95.0, 50.5, 0.5], [50.5, 96.0, math.pi / 2],
                          [4.0, 50.5, math.pi]])
    out = empty.closest_obstacle(poses)
    # The walls are the bounds shrunk by the margin: x = 100.5, y = 100.5, x = 0.5.
    assert out[0].tolist() == [5.5, 0.0]
    # Turned 0.5 rad left, the perpendicular foot is at bearing -0.5 (the bin at global angle 0).
    assert out[1, 0].item() == pytest.approx(5.5, abs=1e-5)
    assert out[1, 1].item() == pytest.approx(-0.5, abs=1e-6)
    # pi/2 falls between two bins (126 bins): the nearest ray is half a bin off the perpendicular.
    assert 4.5 - 1e-5 <= out[2, 0].item() <= 4.5 / math.cos(empty.bin_width / 2) + 1e-5
    assert abs(out[2, 1].item()) <= empty.bin_width / 2 + 1e-6
    assert out[3, 0].item() == pytest.approx(3.5, abs=1e-5)
    assert abs(out[3, 1].item()) <= empty.bin_width / 2


def test_closest_obstacle_corner_in_view(empty):
    # At (97, 97) facing the corner (heading pi/4): walls x = 100.5 and y = 100.5 are both 3.5 m away,
    # perpendicular feet at global angles 0 and pi/2, i.e. bearings -pi/4 and +pi/4 (inside the 120 deg view).
    out = empty.closest_obstacle(torch.tensor([[97.0, 97.0, math.pi / 4]]))
    assert out[0, 0].item() == pytest.approx(3.5, abs=1e-5)
    assert abs(abs(out[0, 1].item()) - math.pi / 4) <= empty.bin_width


def test_closest_obstacle_bounds_in_range(obstacles4):
    rng = np.random.default_rng(1)
    uni = torch.tensor(rng.uniform(size=(2000, 3)), dtype=torch.float32)
    xy = obstacles4.sample_free(uni)
    heading = torch.tensor(rng.uniform(-math.pi, math.pi, size=(2000, 1)), dtype=torch.float32)
    out = obstacles4.closest_obstacle(torch.cat((xy, heading), -1))
    seen = out[:, 1] != torch.tensor(math.pi)
    assert seen.float().mean().item() > 0.5
    assert (out[:, 0] > 0).all() and (out[:, 0] <= RANGE).all()
    # Seen obstacles lie in the field of view (a bin of slack); unseen ones report exactly the range.
    assert (out[seen, 1].abs() <= FOV / 2 + obstacles4.bin_width).all()
    assert (out[~seen, 0] == RANGE).all()
    # Every pose in obstacles4 sees something within 10 m in most directions: the map is 36 m wide.
    assert (out[seen, 0] < RANGE).float().mean().item() > 0.95


# -------------------------------------------------------------- sample_free
def test_sample_free_never_collides_and_covers(obstacles4):
    gen = torch.Generator().manual_seed(0)
    uni = torch.rand(10_000, 3, generator=gen)
    xy = obstacles4.sample_free(uni)
    assert xy.shape == (10_000, 2)
    assert not obstacles4.in_collision(xy).any()
    # Coverage: the expected share of the left half (x < 18.1) is its share of the free fine cells.
    free = ~obstacles4.collision
    cols = free.shape[1]
    expected_left = free[:, : cols // 2].sum().item() / free.sum().item()
    left = (xy[:, 0] < 18.1).float().mean().item()
    assert abs(left - expected_left) < 5 * math.sqrt(expected_left * (1 - expected_left) / 10_000)
    # Same for the lower half and for one quadrant.
    rows = free.shape[0]
    expected_low = free[: rows // 2].sum().item() / free.sum().item()
    assert abs((xy[:, 1] < 18.1).float().mean().item() - expected_low) < 0.025
    expected_q = free[: rows // 2, : cols // 2].sum().item() / free.sum().item()
    got_q = ((xy[:, 0] < 18.1) & (xy[:, 1] < 18.1)).float().mean().item()
    assert abs(got_q - expected_q) < 5 * math.sqrt(expected_q * (1 - expected_q) / 10_000)
    # Free space excludes the boxes: box A region never sampled.
    in_a = (xy[:, 0] > 2.6) & (xy[:, 0] < 9.4) & (xy[:, 1] > 7.4) & (xy[:, 1] < 17.0)
    assert not in_a.any()


def test_sample_free_lowest_uniforms(obstacles4):
    # Uniforms at 0 pick (to within the 0.1 % shrink) the lower-left corner of the first free fine cell.
    xy = obstacles4.sample_free(torch.zeros(1, 3))
    assert not obstacles4.in_collision(xy).any()
    first = obstacles4.free_cells[0].item()
    cols = obstacles4.collision.shape[1]
    assert xy[0].tolist() == pytest.approx([(first % cols) * 0.05, (first // cols) * 0.05], abs=3e-5)
    assert xy[0].tolist() == pytest.approx([1.1, 1.1], abs=3e-5)  # 0.6 m border + 0.5 m margin


def test_sample_free_highest_uniforms(obstacles4):
    top = 1.0 - 2.0**-24  # the largest value rng.uniform returns
    u = torch.tensor([[top, top, top], [0.5, top, top]])
    xy = obstacles4.sample_free(u)
    assert not obstacles4.in_collision(xy).any()


def test_sample_free_empty_map_margin(empty):
    gen = torch.Generator().manual_seed(1)
    xy = empty.sample_free(torch.rand(5000, 3, generator=gen))
    assert (xy >= 0.5).all() and (xy <= 100.5).all()
    assert not empty.in_collision(xy).any()
    assert xy[:, 0].mean().item() == pytest.approx(50.5, abs=5 * 29 / math.sqrt(5000))


# -------------------------------------------------------------- polar table
def _brute_force_ray(occ: np.ndarray, res: float, row: int, col: int, angle: float, max_range: float,
                     ) -> float:
    """March from the centre of (row, col) along ``angle`` every res / 200 to the first occupied (or off-grid)
    cell; the distance at which the ray enters it, to within res / 200."""
    ny, nx = occ.shape
    step = res / 200
    k = 1
    while k * step <= max_range + 1e-9:
        d = k * step
        u = col + 0.5 + d * math.cos(angle) / res
        v = row + 0.5 + d * math.sin(angle) / res
        c, r = math.floor(u), math.floor(v)
        if not (0 <= c < nx and 0 <= r < ny) or occ[r, c]:
            return d
        k += 1
    return math.inf


def test_polar_table_matches_brute_force(obstacles4):
    occ = obstacles4.map.occupancy.numpy()
    ny, nx = occ.shape
    rng = np.random.default_rng(2)
    table = obstacles4.ray_table
    finite = 0
    for _ in range(200):
        row, col = int(rng.integers(0, ny)), int(rng.integers(0, nx))
        b = int(rng.integers(0, obstacles4.num_bins))
        angle = b * 2 * math.pi / obstacles4.num_bins
        expected = _brute_force_ray(occ, 0.2, row, col, angle, RANGE)
        got = table[row * nx + col, b].item()
        if math.isinf(expected):
            assert math.isinf(got), (row, col, b, got)
        else:
            finite += 1
            assert expected - 0.2 / 200 - 1e-5 <= got <= expected + 1e-5, (row, col, b, got, expected)
    assert finite > 100


def test_polar_table_hand_values(column):
    # From cell (row 10, col 4), centre (2.25, 5.25): the column (col 12) straight along +x at 3.75 m; along
    # -x the grid edge (col -1) at 2.25 m (leaving the grid counts as a hit); inside an occupied cell: 0.
    nx = 20
    assert column.ray_table[10 * nx + 4, 0].item() == pytest.approx(3.75)
    assert column.ray_table[10 * nx + 4, column.num_bins // 2].item() == pytest.approx(2.25)
    assert column.ray_table[10 * nx + 12, 0].item() == 0.0


def test_in_view_applies_range_field_of_view_and_line_of_sight():
    occupancy = torch.zeros(20, 20, dtype=torch.bool)
    occupancy[8:12, 12] = True  # a wall at x in [6, 6.5) m, y in [4, 6) m
    geometry = _geometry(occupancy)
    pose = torch.tensor([2.0, 5.0, 0.0])
    points = torch.tensor([[4.0, 5.0], [2.0, 7.0], [2.0 + RANGE + 0.5, 5.0], [8.0, 5.0], [8.0, 9.0]])
    seen, polar = geometry.in_view(pose, points)
    # ahead: seen; straight left: outside the field of view; too far; behind the wall; 34 degrees to the left
    # at 7.2 m, the segment passing above the wall (y = 7.7 m at x = 6 m)
    assert seen.tolist() == [True, False, False, False, True]
    assert polar[0].tolist() == pytest.approx([2.0, 0.0]) and polar[1].tolist() == pytest.approx([2.0, math.pi / 2])


# ------------------------------------------------------ per-world maps
def _world_maps(resolution: float = 0.5) -> torch.Tensor:
    """Three 10 m x 10 m maps: a column, a few cells and a generated layout."""
    occ = torch.zeros(3, 20, 20, dtype=torch.bool)
    occ[0, 3:17, 12] = True
    occ[1, [4, 10, 10, 15], [4, 10, 11, 2]] = True
    layouts = RandomObstacles(RandomMapConfig(size=[10.0, 10.0], resolution=resolution, length=[1.0, 4.0],
                                              min_start_area=0.05), MARGIN)
    occ[2] = layouts.generate(torch.tensor([7]))[0][0]
    return occ


def test_world_maps_answer_as_each_worlds_own_map():
    occ = _world_maps()
    B = occ.shape[0]
    worlds = WorldMapGeometry(B, (10.0, 10.0), 0.5, MARGIN, 5.0, FOV, SPACING, 4, "cpu", torch.float32)
    worlds.set_maps(torch.arange(B), occ, start_cells(occ, 0.5, MARGIN))
    gen = torch.Generator().manual_seed(0)
    points = torch.rand(B, 400, 2, generator=gen) * 11 - 0.5
    poses = torch.cat((torch.rand(B, 300, 2, generator=gen) * 10, (torch.rand(B, 300, 1, generator=gen) * 2 - 1)
                       * math.pi), -1)
    # Each world answers one pose at a time, as a [B, ...] batch.
    collision = worlds.in_collision(points)
    closest = torch.stack([worlds.closest_obstacle(poses[:, k]) for k in range(poses.shape[1])], 1)
    seen, polar = worlds.in_view(poses, points[:, :300, None, :])
    for b in range(B):
        fixed = MapGeometry(GridMap("world", 0.5, occ[b]), MARGIN, 5.0, FOV, SPACING, 4, "cpu", torch.float32)
        assert torch.equal(collision[b], fixed.in_collision(points[b]))
        assert torch.equal(closest[b], fixed.closest_obstacle(poses[b]))
        fixed_seen, fixed_polar = fixed.in_view(poses[b], points[b, :300, None, :])
        assert torch.equal(seen[b], fixed_seen) and torch.equal(polar[b], fixed_polar)
    assert 0.1 < collision.float().mean() < 0.9 and (closest[..., 0] < 5.0).float().mean() > 0.3
    assert 0.05 < (~seen).float().mean() < 0.95


def test_world_map_starts_are_free_and_sampled_uniformly():
    occ = _world_maps()
    starts = start_cells(occ, 0.5, MARGIN)
    worlds = WorldMapGeometry(3, (10.0, 10.0), 0.5, MARGIN, 5.0, FOV, SPACING, 4, "cpu", torch.float32)
    worlds.set_maps(torch.arange(3), occ, starts)
    xy = worlds.sample_free(torch.rand(3, 4000, 3, generator=torch.Generator().manual_seed(1)))
    assert worlds.free_start(xy).all() and not worlds.in_collision(xy).any()
    for b in range(3):  # every start cell drawn, about equally often
        cells = (xy[b] / 0.5).long()
        counts = torch.zeros(20, 20).index_put_((cells[:, 1], cells[:, 0]), torch.ones(4000), accumulate=True)
        assert torch.equal(counts > 0, starts[b])
        assert counts[starts[b]].max() < 4 * 4000 / starts[b].sum()
