"""Tests of ``aia.envs.render.render_frame``: shape, colours at known places, ellipse geometry."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from aia.envs.maps import GridMap, load_map
from aia.envs.render import (
    BELIEF_COLOUR,
    FREE_COLOUR,
    OBSERVED_COLOUR,
    OCCUPIED_COLOUR,
    PAD_COLOUR,
    PARTICLE_COLOUR,
    ROBOT_COLOUR,
    TARGET_COLOUR,
    render_frame,
)

# obstacles4 is 36.2 m wide: 362 pixels make 10 pixels per metre.
OBSTACLE_SIZE = 362
# empty_small is 27 m wide: 270 pixels make 10 pixels per metre.
SMALL_SIZE = 270


def pixel(frame: np.ndarray, x: float, y: float, height: float, scale: float) -> tuple[int, ...]:
    """The colour of the pixel holding the world point (x, y) of a square map filling the frame."""
    return tuple(int(c) for c in frame[int((height - y) * scale), int(x * scale)])


def colour_mask(frame: np.ndarray, colour: tuple[int, int, int]) -> np.ndarray:
    return (frame == np.array(colour, dtype=np.uint8)).all(-1)


def one_target(pos=(20.0, 20.0), belief=(21.0, 20.0), cov_xy=((1.0, 0.0), (0.0, 1.0))):
    target = np.array([[*pos, 0.0, 0.0]])
    mean = np.array([[*belief, 0.0, 0.0]])
    cov = np.eye(4)[None].copy()
    cov[0, :2, :2] = cov_xy
    return target, mean, cov


@pytest.fixture(scope="module")
def obstacles_frame() -> np.ndarray:
    """obstacles4, robot at (30, 5) heading +x, target far up-left."""
    target, mean, cov = one_target(pos=(18.0, 22.0), belief=(19.0, 22.0))
    return render_frame(
        load_map("obstacles4"), np.array([30.0, 5.0, 0.0]), target, mean, cov,
        sensor_range=10.0, fov_deg=120.0, size=OBSTACLE_SIZE, observed=np.array([False]),
    )


def test_frame_shape_and_dtype_for_a_non_default_size():
    target, mean, cov = one_target()
    frame = render_frame(load_map("empty_small"), np.array([13.5, 13.5, 0.3]), target, mean, cov, 10.0, 120.0,
                         size=200)
    assert frame.shape == (200, 200, 3)
    assert frame.dtype == np.uint8


def test_occupied_free_robot_target_and_belief_colours(obstacles_frame):
    h, s = 36.2, OBSTACLE_SIZE / 36.2
    assert pixel(obstacles_frame, 5.0, 12.0, h, s) == OCCUPIED_COLOUR  # inside the box [2.6, 7.4, 9.4, 17.0]
    assert pixel(obstacles_frame, 0.2, 20.0, h, s) == OCCUPIED_COLOUR  # the 3-cell walled border
    assert pixel(obstacles_frame, 18.0, 33.0, h, s) == FREE_COLOUR  # free and far from the robot
    assert pixel(obstacles_frame, 30.0, 5.0, h, s) == ROBOT_COLOUR
    assert pixel(obstacles_frame, 18.0, 22.0, h, s) == TARGET_COLOUR
    assert pixel(obstacles_frame, 19.0, 22.0, h, s) == BELIEF_COLOUR
    assert not colour_mask(obstacles_frame, OBSERVED_COLOUR).any()


def test_field_of_view_is_a_translucent_sector_ahead_of_the_robot(obstacles_frame):
    h, s = 36.2, OBSTACLE_SIZE / 36.2
    ahead = pixel(obstacles_frame, 36.0 - 1.5, 5.0, h, s)  # 4.5 m ahead, inside range and the 120 deg FOV
    def at_bearing(deg: float) -> tuple[int, ...]:
        return pixel(obstacles_frame, 30.0 + 5.0 * math.cos(math.radians(deg)),
                     5.0 + 5.0 * math.sin(math.radians(deg)), h, s)

    side = at_bearing(50.0)  # 5 m away, 50 deg off the heading: inside the 120 deg FOV
    outside_fov = at_bearing(75.0)  # 75 deg off the heading: outside
    behind = pixel(obstacles_frame, 26.0, 5.0, h, s)
    for colour in (ahead, side):
        assert colour[2] == 255 and colour[0] < 230 and colour[1] < 245  # white tinted blue
    assert outside_fov == FREE_COLOUR
    assert behind == FREE_COLOUR


@pytest.mark.parametrize("heading", [0.0, math.pi / 2, math.pi, -2.0])
def test_robot_triangle_points_along_the_heading(heading):
    size, scale = SMALL_SIZE, SMALL_SIZE / 27.0
    target, mean, cov = one_target(pos=(3.0, 3.0), belief=(3.5, 3.0))
    x, y = 13.5, 13.5
    pose = torch.tensor([x, y, heading])
    frame = render_frame(load_map("empty_small"), pose, target, mean, cov, 5.0, 90.0, size)
    length_m = max(6.0, size / 40) / scale
    # The nose is 1.0 length ahead of the pose, the rear edge 0.6 length behind it.
    cos, sin = math.cos(heading), math.sin(heading)
    ahead = pixel(frame, x + 0.5 * length_m * cos, y + 0.5 * length_m * sin, 27.0, scale)
    behind = pixel(frame, x - 0.9 * length_m * cos, y - 0.9 * length_m * sin, 27.0, scale)
    assert pixel(frame, x, y, 27.0, scale) == ROBOT_COLOUR
    assert ahead == ROBOT_COLOUR
    assert behind != ROBOT_COLOUR


def test_ellipse_grows_with_the_covariance():
    grid = load_map("empty_small")
    pose = np.array([3.0, 3.0, math.pi])  # looking away from the belief
    counts = {}
    for var in (1.0, 4.0):
        target, mean, cov = one_target(pos=(13.5, 13.5), belief=(13.5, 13.5), cov_xy=((var, 0.0), (0.0, var)))
        frame = render_frame(grid, pose, target, mean, cov, 5.0, 90.0, size=SMALL_SIZE)
        counts[var] = int(colour_mask(frame, BELIEF_COLOUR).sum())
    # The outline's length doubles with the 2-sigma radius (2 m -> 4 m); the target hides the mean's dot.
    assert 1.7 < counts[4.0] / counts[1.0] < 2.3


def test_ellipse_axes_follow_the_eigen_decomposition():
    grid, scale = load_map("empty_small"), SMALL_SIZE / 27.0
    pose = np.array([3.0, 3.0, math.pi])
    # Axis-aligned: sigma_x = 3 m, sigma_y = 1 m -> a 12 m x 4 m 2-sigma box.
    target, mean, cov = one_target(pos=(3.0, 25.0), belief=(13.5, 13.5), cov_xy=((9.0, 0.0), (0.0, 1.0)))
    frame = render_frame(grid, pose, target, mean, cov, 5.0, 90.0, size=SMALL_SIZE)
    rows, cols = np.nonzero(colour_mask(frame, BELIEF_COLOUR))
    assert abs((cols.max() - cols.min()) / scale - 12.0) < 0.4
    assert abs((rows.max() - rows.min()) / scale - 4.0) < 0.4
    # Rotated: eigenvalues 9 along (1, 1) and 1 along (1, -1): the outline passes 6 m up-right of the mean.
    target, mean, cov = one_target(pos=(3.0, 25.0), belief=(13.5, 13.5), cov_xy=((5.0, 4.0), (4.0, 5.0)))
    frame = render_frame(grid, pose, target, mean, cov, 5.0, 90.0, size=SMALL_SIZE)
    d = 6.0 / math.sqrt(2)

    def near(x: float, y: float) -> bool:
        row, col = int((27.0 - y) * scale), int(x * scale)
        return bool(colour_mask(frame[row - 2:row + 3, col - 2:col + 3], BELIEF_COLOUR).any())

    assert near(13.5 + d, 13.5 + d) and near(13.5 - d, 13.5 - d)  # major axis: 2 * 3 m along (1, 1)
    assert near(13.5 + 2.0 / math.sqrt(2), 13.5 - 2.0 / math.sqrt(2))  # minor axis: 2 * 1 m along (1, -1)
    assert not near(13.5 + d, 13.5 - d)  # 6 m along the minor axis lies far outside


def test_observed_targets_are_ringed():
    target, mean, cov = one_target(pos=(10.0, 10.0), belief=(20.0, 20.0))
    args = (load_map("empty_small"), np.array([3.0, 3.0, 0.0]), target, mean, cov, 5.0, 90.0, SMALL_SIZE)
    seen = render_frame(*args, observed=torch.tensor([True]))
    unseen = render_frame(*args, observed=np.array([False]))
    assert colour_mask(seen, OBSERVED_COLOUR).sum() > 20
    assert not colour_mask(unseen, OBSERVED_COLOUR).any()


def test_torch_and_numpy_inputs_give_the_same_frame():
    target, mean, cov = one_target(cov_xy=((2.0, 0.5), (0.5, 1.0)))
    pose = np.array([13.5, 13.5, 0.4])
    grid = load_map("empty_small")
    from_numpy = render_frame(grid, pose, target, mean, cov, 6.0, 120.0, size=128)
    tensors = (torch.tensor(a, dtype=torch.float32) for a in (pose, target, mean, cov))
    from_torch = render_frame(grid, *tensors, 6.0, 120.0, size=128)
    np.testing.assert_array_equal(from_numpy, from_torch)


def test_non_square_map_keeps_its_aspect_ratio_and_is_padded():
    # 20 m wide, 10 m high.
    wide = GridMap(name="wide", resolution=0.2, occupancy=torch.zeros(50, 100, dtype=torch.bool))
    target, mean, cov = one_target(pos=(2.0, 2.0), belief=(2.5, 2.0))
    frame = render_frame(wide, np.array([18.0, 8.0, math.pi]), target, mean, cov, 3.0, 90.0, size=200)
    # 10 pixels per metre: the map spans rows 50..149.
    assert tuple(frame[20, 100]) == PAD_COLOUR
    assert tuple(frame[180, 100]) == PAD_COLOUR
    assert tuple(frame[100, 100]) == FREE_COLOUR
    assert tuple(frame[int(50 + (10.0 - 2.0) * 10), int(2.0 * 10)]) == TARGET_COLOUR


def test_bad_shapes_raise():
    target, mean, cov = one_target()
    grid = load_map("empty_small")
    with pytest.raises(ValueError, match="robot_pose"):
        render_frame(grid, np.zeros((2, 3)), target, mean, cov, 5.0, 90.0)
    with pytest.raises(ValueError, match="belief_cov"):
        render_frame(grid, np.zeros(3), target, mean, cov[:, :, :3], 5.0, 90.0)


def test_trails_draw_earlier_positions():
    grid = load_map("empty_small")
    pose = np.array([20.0, 20.0, 0.0])
    target = np.array([[22.0, 20.0, 0.0, 0.0]])
    mean, cov = target.copy(), np.eye(4)[None] * 0.01
    plain = render_frame(grid, pose, target, mean, cov, 5.0, 90.0, size=270)
    robot_path = np.array([[3.0, 3.0]])
    target_paths = np.array([[[3.0, 24.0]]])
    trailed = render_frame(grid, pose, target, mean, cov, 5.0, 90.0, size=270, robot_path=robot_path,
                           target_paths=target_paths)
    # 10 pixels per metre on this 27 m map: (3, 3) is pixel (30, 240), (3, 24) is (30, 30)
    assert tuple(trailed[240, 30]) == ROBOT_COLOUR and tuple(plain[240, 30]) == FREE_COLOUR
    assert tuple(trailed[30, 30]) == TARGET_COLOUR and tuple(plain[30, 30]) == FREE_COLOUR


def test_view_zooms_on_a_rectangle_of_the_map():
    grid = load_map("empty")  # 101 m
    pose = np.array([30.0, 40.0, 0.0])
    target = np.array([[34.0, 40.0, 0.0, 0.0]])
    mean, cov = target.copy(), np.eye(4)[None] * 0.01
    frame = render_frame(grid, pose, target, mean, cov, 5.0, 90.0, size=200, view=(24.0, 30.0, 44.0, 50.0))
    # 10 pixels per metre: the target at (34, 40) is the centre pixel (100, 100)
    assert tuple(frame[100, 100]) == TARGET_COLOUR
    with pytest.raises(ValueError, match=r"view=\(5.0, 0.0, 5.0, 1.0\)"):
        render_frame(grid, pose, target, mean, cov, 5.0, 90.0, size=200, view=(5.0, 0.0, 5.0, 1.0))


def test_particles_and_se2_headings_are_drawn():
    grid = load_map("empty_small")
    pose = np.array([3.0, 3.0, 0.0])
    target = np.array([[20.0, 20.0, math.pi / 2, 1.0, 0.0]])       # an SE(2) target facing north
    mean, cov = np.array([[20.0, 20.0, 0.0]]), np.eye(3)[None] * 0.01
    particles = np.array([[[10.0, 10.0, 0.0], [5.0, 20.0, 0.0]]])   # pixels (100, 170) and (50, 70)
    plain = render_frame(grid, pose, target, mean, cov, 5.0, 90.0, size=270)
    drawn = render_frame(grid, pose, target, mean, cov, 5.0, 90.0, size=270, target_heading=target[:, 2],
                         particles=particles)
    assert tuple(drawn[170, 100]) == PARTICLE_COLOUR and tuple(plain[170, 100]) == FREE_COLOUR
    assert tuple(drawn[70, 50]) == PARTICLE_COLOUR
    # the heading line runs north of the target's dot (pixel (200, 70)) for 3 dots: 0.5 m above it is (200, 65)
    assert tuple(drawn[65, 200]) == TARGET_COLOUR and tuple(plain[65, 200]) == FREE_COLOUR
    with pytest.raises(ValueError, match="particles must be"):
        render_frame(grid, pose, target, mean, cov, 5.0, 90.0, particles=particles[0])
