"""Foxglove scene encoding: the map's rectangles, the belief ellipses, and decode(encode(x)) == x."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
import torch

from aia.envs.maps import GridMap, load_map
from aia.logging.scenes import (
    FrameEncoder,
    WorldInfo,
    ellipse,
    occupied_rectangles,
    parse_frame,
    parse_world,
    world_message,
)

# The fields of Foxglove's published schemas (foxglove-sdk schemas/jsonschema), which its panels expect.
SCENE_ENTITY_FIELDS = ["timestamp", "frame_id", "id", "lifetime", "frame_locked", "metadata", "arrows", "cubes",
                       "spheres", "cylinders", "lines", "triangles", "texts", "models"]
FRAME_TRANSFORM_FIELDS = ["timestamp", "parent_frame_id", "child_frame_id", "translation", "rotation"]


@pytest.mark.parametrize("seed", range(5))
def test_rectangles_cover_exactly_the_occupied_cells_once(seed):
    occupancy = np.random.default_rng(seed).random((23, 17)) < 0.4
    cover = np.zeros(occupancy.shape, dtype=int)
    for x0, y0, x1, y1 in occupied_rectangles(occupancy):
        assert x0 < x1 and y0 < y1
        cover[y0:y1, x0:x1] += 1
    assert np.array_equal(cover, occupancy.astype(int))


def test_a_box_is_one_rectangle_and_the_border_four():
    occupancy = np.zeros((10, 12), dtype=bool)
    occupancy[2:5, 3:9] = True
    assert occupied_rectangles(occupancy) == [(3, 2, 9, 5)]
    grid = load_map("obstacles4").occupancy.numpy()
    rectangles = occupied_rectangles(grid)
    assert len(rectangles) < 100  # 4 border strips, 3 boxes and the rows of the turned box
    assert sum((x1 - x0) * (y1 - y0) for x0, y0, x1, y1 in rectangles) == grid.sum()


def test_ellipses_match_an_eigendecomposition():
    rng = np.random.default_rng(0)
    factors = rng.normal(size=(6, 2, 2))
    cov = factors @ factors.transpose(0, 2, 1) + 0.1 * np.eye(2)
    cov[0] = np.diag([4.0, 1.0])  # axis-aligned: major axis along x
    result = np.array([ellipse(c.tolist(), sigma=2.0) for c in cov])
    assert result[0] == pytest.approx([8.0, 4.0, 0.0])
    eigenvalues, eigenvectors = np.linalg.eigh(cov)
    assert result[:, 0] == pytest.approx(4 * np.sqrt(eigenvalues[:, 1]))
    assert result[:, 1] == pytest.approx(4 * np.sqrt(eigenvalues[:, 0]))
    major = np.stack((np.cos(result[:, 2]), np.sin(result[:, 2])), -1)
    assert np.abs((major * eigenvectors[:, :, 1]).sum(-1)) == pytest.approx(np.ones(6))


def test_world_message_round_trips_the_map_and_the_sensor():
    grid_map = load_map("obstacles4")
    info = WorldInfo(grid_map, sensor_range=10.0, fov_deg=120.0, num_targets=3, episode=4, frame=900)
    message = json.loads(world_message(info, 1_700_000_000_123_456_789))
    entity = message["entities"][0]
    assert list(entity) == SCENE_ENTITY_FIELDS
    assert entity["timestamp"] == {"sec": 1_700_000_000, "nsec": 123_456_789}
    assert entity["frame_id"] == "world" and entity["lines"][0]["type"] == 1  # border: a line loop
    back = parse_world(world_message(info, 0))
    assert torch.equal(back.grid_map.occupancy, grid_map.occupancy)
    assert back.grid_map.resolution == grid_map.resolution and back.grid_map.name == "obstacles4"
    assert (back.sensor_range, back.fov_deg, back.num_targets, back.episode, back.frame) == (10.0, 120.0, 3, 4, 900)


def test_frame_round_trip_and_foxglove_fields():
    encoder = FrameEncoder(sensor_range=10.0, fov_deg=120.0, sigma=2.0)
    cov = np.array([[[2.0, 0.5], [0.5, 1.0]], [[0.3, -0.1], [-0.1, 0.2]]])
    full_cov = np.zeros((2, 4, 4))
    full_cov[:, :2, :2] = cov
    full_cov[:, 2:, 2:] = np.eye(2)
    tf, scene = encoder.encode(
        5_000_000_123, episode=3, frame=700, step=12, time=6.0, robot_pose=[1.0, 2.0, -2.5],
        targets=[[3.0, 4.0, 0.5, 0.5], [5.5, 6.5, 0.0, 1.0]], belief_mean=[[3.1, 4.2, 0.0, 0.0], [5.0, 6.0, 0, 0]],
        belief_cov=full_cov.tolist(), observed=[True, False],
    )
    transform = json.loads(tf)
    assert list(transform) == FRAME_TRANSFORM_FIELDS
    assert (transform["parent_frame_id"], transform["child_frame_id"]) == ("world", "robot")
    assert transform["rotation"]["z"] == pytest.approx(math.sin(-1.25))
    entities = {e["id"]: e for e in json.loads(scene)["entities"]}
    assert set(entities) == {"robot", "targets", "beliefs"}
    assert all(list(e) == SCENE_ENTITY_FIELDS for e in entities.values())
    assert entities["robot"]["frame_id"] == "robot" and entities["targets"]["frame_id"] == "world"
    sphere = entities["targets"]["spheres"][0]
    assert sphere["pose"]["position"]["x"] == 3.0 and sphere["color"]["g"] > entities["targets"]["spheres"][1][
        "color"]["g"]  # the observed target is drawn orange, the other red
    frame = parse_frame(tf, scene)
    assert (frame.episode, frame.frame, frame.step, frame.time) == (3, 700, 12, 6.0)
    assert frame.robot_pose == pytest.approx([1.0, 2.0, -2.5])
    assert frame.targets == pytest.approx(np.array([[3.0, 4.0], [5.5, 6.5]]))
    assert frame.belief_mean == pytest.approx(np.array([[3.1, 4.2], [5.0, 6.0]]))
    assert frame.belief_cov == pytest.approx(cov, rel=1e-6, abs=1e-9)
    assert frame.observed.tolist() == [True, False]


def test_grid_map_from_parse_world_is_a_grid_map():
    info = WorldInfo(GridMap("tiny", 0.5, torch.zeros(4, 6, dtype=torch.bool)), 5.0, 360.0, 1, 0, 0)
    back = parse_world(world_message(info, 0))
    assert back.grid_map.shape == (4, 6) and not back.grid_map.has_obstacles
    assert back.fov_deg == 360.0


def test_non_finite_numbers_are_drawn_as_zero_and_stay_valid_json():
    encoder = FrameEncoder(sensor_range=10.0, fov_deg=120.0)
    tf, scene = encoder.encode(0, 0, 0, 0, 0.0, [float("nan"), 1.0, 0.0], [[float("inf"), 2.0]], [[1.0, 2.0]],
                               [[[1.0, 0.0], [0.0, 1.0]]], [False])
    frame = parse_frame(tf, scene)  # json.loads would fail on NaN or Infinity
    assert frame.robot_pose.tolist() == [0.0, 1.0, 0.0] and frame.targets.tolist() == [[0.0, 2.0]]
