"""LocalMap: ttenv v4/v5's map images against hand-computed ones on a small map, Bresenham's closed form against
ttenv's definition, per-world maps against each map alone, the visit frequencies' decay and partial resets, the
config's checks and the presets.

Against ttenv itself (its ``local_map``, ``local_visit_map_surroundings`` and ``update_visit_freq_map`` on its map
``obstacles02``, 40 poses of a trajectory, float64): every pixel of the 40 x 5 images and every cell of the global
visit maps equal (docs/environment.md, "Map observations").
"""

from __future__ import annotations

import math

import pytest
import torch
from torchrl.envs.utils import check_env_specs

from aia.config.errors import ConfigError
from aia.envs import GridMap, load_env_config, make_env
from aia.envs.sensing import MapGeometry, WorldMapGeometry
from aia.transforms.local_map import (
    OCCUPANCY_SQUARE,
    VISIT_SQUARES,
    LocalMap,
    Visits,
    bresenham,
    map_images,
    mark_visits,
    stamp_rays,
    visit_decay,
)

F64 = torch.float64
SQUARES = torch.tensor(OCCUPANCY_SQUARE + VISIT_SQUARES, dtype=F64)
# An 8 m x 8 m map of 1 m cells, occupied at (x, y) = (7, 6), (6, 3), (3, 4), (4, 2).
OCCUPIED = ((7, 6), (6, 3), (3, 4), (4, 2))


def _small_map() -> GridMap:
    occupancy = torch.zeros(8, 8, dtype=torch.bool)
    for x, y in OCCUPIED:
        occupancy[y, x] = True
    return GridMap("small", 1.0, occupancy)


def _geometry(grid_map: GridMap) -> MapGeometry:
    return MapGeometry(grid_map, margin=1.0, sensor_range=4.0, fov=2.0, ray_spacing=0.05, dtype=F64)


def test_occupancy_images_by_hand_at_headings_0_and_half_pi() -> None:
    """Pixel (h, w) lies h + 0.5 cells ahead and w - 1.5 cells to the right of the robot (im_size 4)."""
    geometry = _geometry(_small_map())
    pose = torch.tensor([[6.0, 5.0, 0.0], [4.0, 2.0, math.pi / 2]], dtype=F64)
    images = map_images(geometry, pose, SQUARES[:1], 4)
    assert images.shape == (2, 1, 4, 4)
    # heading 0 from (6, 5): pixel (h, w) is cell (x, y) = (6 + h, 6 - w); x >= 8 is outside the map
    heading_0 = [[-1, -1, -1, 1],
                 [1, -1, -1, -1],
                 [1, 1, 1, 1],
                 [1, 1, 1, 1]]
    # heading pi/2 from (4, 2): pixel (h, w) is cell (2 + w, 2 + h)
    heading_half_pi = [[-1, -1, 1, -1],
                       [-1, -1, -1, -1],
                       [-1, 1, -1, -1],
                       [-1, -1, -1, -1]]
    torch.testing.assert_close(images[:, 0], torch.tensor([heading_0, heading_half_pi], dtype=F64), rtol=0, atol=0)


def test_visit_images_by_hand() -> None:
    """From (2, 5), heading 0, the robot's square covers cells x 2..5, y 6..3; the one left of it y 10..7, right
    y 2..-1, in front x 6..9, behind x -2..1. Outside the map or occupied +1; closer than the margin (1 m) to the
    bounds -1; else the visit frequency - 1 (here ``v(x, y) = (8 y + x) / 100 - 1``)."""
    geometry = _geometry(_small_map())
    frequencies = (torch.arange(64, dtype=F64) / 100).reshape(1, 64)  # row = y
    visits = Visits(-torch.log(frequencies), torch.zeros(1, dtype=F64))

    def v(x: int, y: int) -> float:
        return (8 * y + x) / 100 - 1

    images = map_images(geometry, torch.tensor([[2.0, 5.0, 0.0]], dtype=F64), SQUARES, 4, visits)
    occupancy = [[-1] * 4, [-1, -1, 1, -1], [-1] * 4, [-1] * 4]  # (3, 4) occupied
    left = [[1, 1, 1, -1]] * 4  # y 10, 9, 8 outside; y 7.5 beyond the margin
    right = [[v(x, 2), v(x, 1), -1, 1] for x in (2, 3, 4, 5)]
    right[2][0] = 1  # (4, 2) occupied
    front = [[v(6, 6), v(6, 5), v(6, 4), 1], [1, -1, -1, -1], [1] * 4, [1] * 4]  # (6, 3), (7, 6) occupied
    back = [[1] * 4, [1] * 4, [-1] * 4, [v(1, 6), v(1, 5), v(1, 4), v(1, 3)]]
    expected = torch.tensor([occupancy, left, right, front, back], dtype=F64)
    torch.testing.assert_close(images[0], expected, rtol=0, atol=1e-12)


def _ttenv_line(sx: int, sy: int, ex: int, ey: int) -> list[tuple[int, int]]:
    """ttenv's bresenham2D by its definition: along the longer axis one cell a step; the error term floor(dx / 2)
    - k dy taken modulo dx, and a step across whenever it wraps (its remainder does not decrease)."""
    dx, dy = abs(ex - sx), abs(ey - sy)
    steep = dy > dx
    if steep:
        dx, dy = dy, dx
    across, offsets, previous = 0, [], None
    for k in range(dx + 1):
        remainder = (dx // 2 - k * dy) % dx if dx else 0
        if k and dy and remainder >= previous:
            across += 1
        previous = remainder
        offsets.append((k, across))
    sign_x, sign_y = (1 if ex >= sx else -1), (1 if ey >= sy else -1)
    return [(sx + sign_x * (a if steep else k), sy + sign_y * (k if steep else a)) for k, a in offsets]


def test_bresenham_closed_form_equals_ttenv_lines() -> None:
    ends = torch.tensor([(x, y) for x in range(-9, 10) for y in range(-9, 10)]) + torch.tensor([3, -2])
    start = torch.tensor([3, -2]).expand_as(ends)
    x, y, on_line = bresenham(start, ends, 11)
    for i, (ex, ey) in enumerate(ends.tolist()):
        line = zip(x[i][on_line[i]].tolist(), y[i][on_line[i]].tolist(), strict=True)
        assert list(line) == _ttenv_line(3, -2, ex, ey)


def test_each_world_image_equals_its_own_map_alone() -> None:
    """Per-world maps (WorldMapGeometry) and their visit frequencies: world b's images are those computed on
    its map alone (MapGeometry), after three steps of decay and marking."""
    generator = torch.Generator().manual_seed(0)
    maps = torch.rand(3, 8, 8, generator=generator) < 0.25
    world_geometry = WorldMapGeometry(3, (8.0, 8.0), 1.0, margin=1.0, sensor_range=4.0, fov=2.0, ray_spacing=0.05,
                                      dtype=F64)
    world_geometry.occupancy.copy_(maps)
    transform = LocalMap(world_geometry, "occupancy_visits", im_size=4)
    poses = torch.rand(3, 3, 3, generator=generator, dtype=F64) * torch.tensor([6.0, 6.0, 2 * math.pi]) + 1.0
    decays = torch.rand(3, 3, generator=generator, dtype=F64)
    every = torch.ones(3, dtype=torch.bool)
    visits = Visits.empty(3, 64, "cpu")
    for pose, decay in zip(poses, decays, strict=True):
        mark_visits(visits, world_geometry, pose, every, decay, transform.ray_angles, transform.ray_cells)
    images = map_images(world_geometry, poses[-1], SQUARES, 4, visits)
    for b in range(3):
        alone = _geometry(GridMap(f"world {b}", 1.0, maps[b]))
        own = Visits.empty(1, 64, "cpu")
        for pose, decay in zip(poses[:, b : b + 1], decays[:, b : b + 1], strict=True):
            mark_visits(own, alone, pose, every[:1], decay, transform.ray_angles, transform.ray_cells)
        torch.testing.assert_close(visits.frequencies()[b], own.frequencies()[0], rtol=0, atol=0)
        expected = map_images(alone, poses[-1, b : b + 1], SQUARES, 4, own)
        torch.testing.assert_close(images[b], expected[0], rtol=0, atol=0)


def test_visits_decay_then_the_seen_cells_are_one() -> None:
    """A step multiplies every cell by the decay and sets the cells in view to 1; a wall stops a ray: the robot
    at (1.5, 1.5) facing +x sees (2..5, 1) up to the obstacle-free row's end, not past the occupied (6, 3)."""
    geometry = _geometry(_small_map())
    transform = LocalMap(geometry, "occupancy_visits", im_size=4)
    visits = Visits(torch.full((1, 65), math.log(2.0), dtype=F64), torch.zeros(1, dtype=F64))  # all at 0.5
    mark_visits(visits, geometry, torch.tensor([[1.5, 1.5, 0.0]], dtype=F64), torch.tensor([True]),
                torch.tensor([0.4], dtype=F64), transform.ray_angles, transform.ray_cells)
    grid = visits.frequencies()[0, :-1].reshape(8, 8)
    assert ((grid == 1.0) | (grid - 0.2).abs().lt(1e-15)).all() and (grid == 1.0).sum() > 0
    assert (grid[1, 1:6] == 1.0).all() and grid[4, 3] == 0.2 and grid[3, 6] == 0.2  # occupied cells stay unseen
    assert visit_decay(torch.tensor([[[3.0, 4.0], [0.0, 0.0]]]), 0.5, 10.0).item() == pytest.approx(0.7**0.125)
    assert visit_decay(None, 0.5, 10.0) == 1.0


def test_env_partial_reset_clears_only_the_reset_worlds() -> None:
    """The env's local_map passes TorchRL's spec check; a reset of world 0 alone gives it a fresh visit map (its
    first view only) and leaves the others' as they were."""
    torch.manual_seed(0)
    env = make_env("empty1", batch_size=3, seed=0, overrides=["features.local_map=occupancy_visits",
                                                                "features.im_size=6"])
    spec = env.observation_spec["local_map"]
    assert spec.shape == (3, 5, 6, 6) and (spec.space.low == -1).all() and (spec.space.high == 1).all()
    check_env_specs(env, seed=0)
    transform = next(t for t in env.transform if isinstance(t, LocalMap))
    rollout = env.rollout(3, break_when_any_done=False)
    assert spec.is_in(rollout[-1]["next", "local_map"]) and rollout["next", "local_map"].shape == (3, 3, 5, 6, 6)
    before = transform.visits.clone()
    reset = torch.tensor([[True], [False], [False]])
    out = env.reset(rollout[:, -1]["next"].clone().set("_reset", reset))
    fresh = Visits.empty(1, transform.visits[0].numel(), "cpu")
    mark_visits(fresh, env.geometry, out["robot_pose"][:1], torch.tensor([True]), 1.0, transform.ray_angles,
                transform.ray_cells)
    torch.testing.assert_close(transform.visits[0].flatten(), fresh.frequencies()[0, :-1], rtol=0, atol=0)
    torch.testing.assert_close(transform.visits[1:], before[1:], rtol=0, atol=0)


def test_config_refuses_im_size_below_one_and_presets_set_the_layout() -> None:
    with pytest.raises(ConfigError) as error:
        load_env_config("empty1", ["features.im_size=0"])
    assert str(error.value) == "env.features.im_size=0: expected an integer >= 1"
    with pytest.raises(ConfigError, match="env.features.local_map='v5': expected one of"):
        load_env_config("empty1", ["features.local_map=v5"])
    assert load_env_config("empty1").features.local_map == "none"
    for preset, layout in (("ttenv_v4", "occupancy"), ("ttenv_v5", "occupancy_visits")):
        features = load_env_config(preset).features
        assert (features.local_map, features.im_size) == (layout, 28)


def test_the_cpu_kernel_stamps_the_gathered_rays_cells() -> None:
    """mark_visits on the CPU walks each ray to its first occupied or outside cell: the same stamps as every ray's
    cells gathered (stamp_rays), on per-world maps and on one map, from inside, at and outside the bounds."""
    generator = torch.Generator().manual_seed(4)
    maps = torch.rand(5, 12, 9, generator=generator) < 0.1
    worlds = WorldMapGeometry(5, (9.0, 12.0), 1.0, margin=1.0, sensor_range=6.0, fov=2.0, ray_spacing=0.05,
                              dtype=F64)
    worlds.occupancy.copy_(maps)
    fixed = _geometry(GridMap("one", 1.0, maps[0]))
    transform = LocalMap(worlds, "occupancy_visits", im_size=4)
    for geometry in (worlds, fixed):
        pose = torch.rand(5, 3, generator=generator, dtype=F64) * torch.tensor([9.0, 12.0, 2 * math.pi])
        pose[0, :2] = torch.tensor([-0.5, 12.5], dtype=F64)  # outside: nothing marked
        marked = torch.tensor([True, True, False, True, True])
        walked, gathered = Visits.empty(5, 108, "cpu"), Visits.empty(5, 108, "cpu")
        walked.clock.fill_(-0.5)
        gathered.clock.fill_(-0.5)
        mark_visits(walked, geometry, pose, marked, 1.0, transform.ray_angles, transform.ray_cells)
        start = torch.floor(pose[:, :2]).long()
        angle = pose[:, 2:3] + transform.ray_angles
        reach = geometry.sensor_range * torch.stack((torch.cos(angle), torch.sin(angle)), -1)
        end = torch.floor(pose[:, None, :2] + reach).long()
        stamp_rays(gathered, geometry, start, end, marked, transform.ray_cells)
        assert torch.equal(walked.stamps[:, :-1], gathered.stamps[:, :-1])
        assert torch.isfinite(walked.stamps[:, :-1]).sum(-1).gt(0).sum() >= 2 and not walked.stamps[2].isfinite().any()
