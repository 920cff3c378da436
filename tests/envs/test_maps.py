"""Tests of aia/envs/maps.py: the shipped maps, rasterisation and the validation errors."""

from __future__ import annotations

import numpy as np
import pytest
import torch
import yaml

from aia.config.errors import ConfigError
from aia.envs.config import TrackingConfig
from aia.envs.maps import GridMap, available_maps, build_map, load_map


def _occupied(m: GridMap, x: float, y: float) -> bool:
    return bool(m.occupancy[int(y / m.resolution), int(x / m.resolution)])


def _write_yaml(path, spec) -> str:
    path.write_text(yaml.safe_dump(spec))
    return str(path)


# ------------------------------------------------------------- shipped maps
def test_available_maps():
    names = available_maps()
    assert {"empty", "empty_small", "obstacles4"} <= set(names)
    assert names == sorted(names)


@pytest.mark.parametrize(
    "name,shape,res,obstacles,start",
    [
        ("empty", (202, 202), 0.5, False, (50.5, 50.5)),
        ("empty_small", (135, 135), 0.2, False, (13.5, 13.5)),
        ("obstacles4", (181, 181), 0.2, True, None),
    ],
)
def test_shipped_map_shapes(name, shape, res, obstacles, start):
    m = load_map(name)
    assert m.name == name
    assert m.shape == shape
    assert m.occupancy.dtype == torch.bool
    assert m.resolution == pytest.approx(res)
    assert m.has_obstacles is obstacles
    assert m.robot_start == start
    assert m.width == pytest.approx(shape[1] * res) and m.height == pytest.approx(shape[0] * res)


def test_empty_maps_have_no_occupied_cells():
    assert int(load_map("empty").occupancy.sum()) == 0
    assert int(load_map("empty_small").occupancy.sum()) == 0


@pytest.mark.parametrize("point", [(5.0, 12.0), (24.5, 15.0), (11.0, 27.0), (27.04, 27.49), (0.1, 10.0),
                                   (36.1, 20.0), (20.0, 0.5), (20.0, 35.7)])
def test_obstacles4_occupied_points(point):
    assert _occupied(load_map("obstacles4"), *point)


@pytest.mark.parametrize("point", [(18.0, 18.0), (20.0, 5.0), (1.0, 1.0), (5.0, 20.0), (30.0, 12.0),
                                   (2.4, 12.0), (9.6, 12.0)])
def test_obstacles4_free_points(point):
    assert not _occupied(load_map("obstacles4"), *point)


def test_obstacles4_border_is_three_cells():
    occ = load_map("obstacles4").occupancy
    assert occ[:3].all() and occ[-3:].all() and occ[:, :3].all() and occ[:, -3:].all()
    # The fourth ring is free away from the obstacles.
    assert not occ[3, 80:100].any() and not occ[80:100, 3].any()


def test_obstacles4_axis_aligned_boxes_cell_counts():
    occ = load_map("obstacles4").occupancy
    # Box A: x 2.6-9.4, y 7.4-17.0 -> cols 13..46 (34 cells), rows 37..84 (48 cells).
    assert occ[37:85, 13:47].all()
    assert not occ[37:85, 12].any() and not occ[37:85, 47].any()
    assert not occ[36, 13:47].any() and not occ[85, 13:47].any()
    # Box B: x 23.2-26.0, y 8.4-19.6 -> cols 116..129, rows 42..97.
    assert occ[42:98, 116:130].all()
    assert not occ[42:98, 130].any() and not occ[41, 116:130].any() and not occ[98, 116:130].any()


def test_obstacles4_rotated_box_cells():
    occ = load_map("obstacles4").occupancy
    assert int(occ[118:157, 117:154].sum()) == 715
    # The rows just outside the window are free.
    assert not occ[117, 117:154].any() and not occ[157, 117:154].any()
    # Total obstacle cells besides the border: the three boxes and the rotated one.
    # (The rotated box rasterises to 716 cells: one more, at row 130 / col 116, lies just outside the
    # window of the authors' 715-cell raster.)
    interior = occ[3:-3, 3:-3]
    boxes = 34 * 48 + 14 * 56 + 22 * 34
    assert int(occ[37:85, 13:47].sum() + occ[42:98, 116:130].sum() + occ[120:154, 46:68].sum()) == boxes
    assert int(interior.sum()) - boxes in (715, 716)


def test_load_map_is_cached():
    assert load_map("obstacles4") is load_map("obstacles4")


# ------------------------------------------------------------------ errors
def test_unknown_map_name():
    with pytest.raises(ValueError) as info:
        load_map("no_such_map")
    msg = str(info.value)
    assert "no_such_map" in msg
    for name in ("empty", "empty_small", "obstacles4"):
        assert name in msg


def test_missing_yaml_path(tmp_path):
    with pytest.raises(ValueError, match="does not exist"):
        load_map(str(tmp_path / "missing.yaml"))


def test_grid_file_wrong_shape(tmp_path):
    np.save(tmp_path / "x.npy", np.zeros((10, 12), dtype=np.uint8))
    path = _write_yaml(tmp_path / "bad_grid.yaml", {"size": [5.0, 4.0], "resolution": 0.5, "grid": "x.npy"})
    with pytest.raises(ValueError) as info:
        load_map(path)
    msg = str(info.value)
    assert "[10, 12]" in msg  # what the file holds
    assert "[8, 10]" in msg  # what 5 m x 4 m at 0.5 needs: 8 rows, 10 cols


def test_grid_file_loads(tmp_path):
    grid = np.zeros((8, 10), dtype=np.uint8)
    grid[2, 3] = 1
    grid[7, 9] = 5
    np.save(tmp_path / "g.npy", grid)
    path = _write_yaml(tmp_path / "good_grid.yaml",
                       {"size": [5.0, 4.0], "resolution": 0.5, "grid": "g.npy", "robot_start": [1.0, 1.0]})
    m = load_map(path)
    assert m.name == "good_grid"
    assert m.shape == (8, 10)
    assert m.robot_start == (1.0, 1.0)
    assert torch.equal(m.occupancy, torch.from_numpy(grid != 0))
    assert _occupied(m, 1.75, 1.25)  # row 2 (y 1.0-1.5), col 3 (x 1.5-2.0)


def test_missing_grid_file(tmp_path):
    path = _write_yaml(tmp_path / "m.yaml", {"size": [5.0, 4.0], "resolution": 0.5, "grid": "nope.npy"})
    with pytest.raises(ValueError, match="nope.npy"):
        load_map(path)


@pytest.mark.parametrize("size,res", [([10.3, 10.0], 0.5), ([10.0, 10.1], 0.2), ([3.0, 3.0], 0.7)])
def test_non_whole_size(tmp_path, size, res):
    path = _write_yaml(tmp_path / "frac.yaml", {"size": size, "resolution": res})
    with pytest.raises(ValueError, match="whole number"):
        load_map(path)


def test_unknown_field(tmp_path):
    spec = {"size": [4.0, 4.0], "resolution": 0.5, "boxs": [[1, 1, 2, 2]]}
    path = _write_yaml(tmp_path / "typo.yaml", spec)
    with pytest.raises(ValueError) as info:
        load_map(path)
    assert "boxs" in str(info.value)


@pytest.mark.parametrize("spec", [
    {"resolution": 0.5},
    {"size": [4.0, 4.0]},
    {"size": [4.0, -4.0], "resolution": 0.5},
    {"size": [4.0, 4.0], "resolution": 0.0},
    {"size": [4.0, 4.0], "resolution": 0.5, "robot_start": [5.0, 1.0]},
])
def test_invalid_specs(spec):
    with pytest.raises(ValueError):
        build_map(spec)


def test_non_mapping_yaml(tmp_path):
    p = tmp_path / "list.yaml"
    p.write_text("- 1\n- 2\n")
    with pytest.raises(ValueError, match="mapping"):
        load_map(str(p))


# ------------------------------------------------------------ rasterisation
def test_custom_box_map(tmp_path):
    path = _write_yaml(tmp_path / "box.yaml", {
        "size": [4.0, 3.0], "resolution": 0.5, "robot_start": [0.5, 0.5],
        "boxes": [[1.0, 1.0, 2.0, 2.0]],
    })
    m = load_map(path)
    assert m.shape == (6, 8)
    assert m.robot_start == (0.5, 0.5)
    # Cell centres 1.25 and 1.75 in x and in y lie in the box: 4 cells, rows 2-3, cols 2-3.
    assert int(m.occupancy.sum()) == 4
    assert m.occupancy[2:4, 2:4].all()


def test_custom_border_and_boxes():
    m = build_map({"size": [4.0, 4.0], "resolution": 0.5, "border_cells": 1,
                   "boxes": [[1.0, 1.0, 2.0, 2.0], [2.5, 2.5, 3.0, 3.0]]})
    assert m.shape == (8, 8)
    # Border ring 8*4 - 4 = 28 cells, box 1: 4 cells, box 2 (0.5 m square): 1 cell (centre 2.75, 2.75).
    assert int(m.occupancy.sum()) == 28 + 4 + 1
    assert m.occupancy[5, 5]
    assert m.name == "custom"


def test_custom_rotated_box():
    # A 2.2 m x 0.4 m box turned 90 degrees about (2.25, 2.25) on a 0.5 m grid is a vertical strip: the cell
    # centres inside have x = 2.25 and y in {1.25, 1.75, 2.25, 2.75, 3.25}: 5 cells in column 4, rows 2..6.
    m = build_map({"size": [4.5, 4.5], "resolution": 0.5,
                   "rotated_boxes": [{"center": [2.25, 2.25], "size": [2.2, 0.4], "angle_deg": 90.0}]})
    occ = m.occupancy
    assert int(occ.sum()) == 5
    assert occ[2:7, 4].all()
    # At 45 degrees, a 1.5 m x 0.2 m strip along the diagonal holds the diagonal cell centres within 0.75 m.
    m = build_map({"size": [4.0, 4.0], "resolution": 0.5,
                   "rotated_boxes": [{"center": [2.0, 2.0], "size": [1.5, 0.2], "angle_deg": 45.0}]})
    # Centres (1.75, 1.75) and (2.25, 2.25) are at u = -+0.354 and v = 0; (1.25, 1.25) at |u| = 1.06 > 0.75.
    assert int(m.occupancy.sum()) == 2
    assert m.occupancy[3, 3] and m.occupancy[4, 4]


# ------------------------------------------------------- one test per validation rule
_BASE = {"size": [10.0, 8.0], "resolution": 0.5}
RULES = [
    ("size", {"size": [10.0, 0.0]}, "size=[10.0, 0.0]", "both > 0"),
    ("resolution", {"resolution": -0.5}, "resolution=-0.5", "> 0"),
    ("whole cells", {"resolution": 0.3}, "size=[10.0, 8.0]", "whole number"),
    ("border", {"border_cells": 8}, "border_cells=8", "<= 7"),
    ("box outside", {"boxes": [[20.0, 20.0, 25.0, 25.0]]}, "boxes[0]=[20.0, 20.0, 25.0, 25.0]", "[0, 10.0] x [0, 8.0]"),
    ("box across the edge", {"boxes": [[8.0, 1.0, 11.0, 2.0]]}, "boxes[0]=[8.0, 1.0, 11.0, 2.0]", "inside the map"),
    ("box inverted", {"boxes": [[3.0, 1.0, 2.0, 2.0]]}, "boxes[0]=[3.0, 1.0, 2.0, 2.0]", "xmin < xmax"),
    ("rotated box outside", {"rotated_boxes": [{"center": [9.5, 4.0], "size": [3.0, 1.0], "angle_deg": 0.0}]},
     "rotated_boxes[0]=", "corners lie inside the map"),
    ("rotated box size", {"rotated_boxes": [{"center": [5.0, 4.0], "size": [0.0, 1.0], "angle_deg": 0.0}]},
     "rotated_boxes[0]=", "size [length, width] > 0"),
    ("start outside", {"robot_start": [11.0, 1.0]}, "robot_start=[11.0, 1.0]", "inside [0, 10.0] x [0, 8.0]"),
    ("start occupied", {"robot_start": [2.0, 2.0], "boxes": [[1.0, 1.0, 3.0, 3.0]]}, "robot_start=[2.0, 2.0]",
     "free cell"),
    ("no free cell", {"boxes": [[0.0, 0.0, 10.0, 8.0]]}, "robot_start=null", "free cell"),
]


@pytest.mark.parametrize("rule, change, named, allowed", RULES, ids=[r[0] for r in RULES])
def test_each_map_rule_names_the_file_the_field_and_the_allowed_range(tmp_path, rule, change, named, allowed):
    path = _write_yaml(tmp_path / "room.yaml", {**_BASE, **change})
    with pytest.raises(ConfigError) as info:
        load_map(path)
    message = str(info.value)
    assert message.startswith(f"{path}: ") and named in message and allowed in message and "\n" not in message


def test_a_start_within_the_collision_margin_of_the_bounds_is_refused(tmp_path):
    path = _write_yaml(tmp_path / "edge.yaml", {**_BASE, "robot_start": [0.2, 4.0]})
    load_map(path)  # inside the map: the map itself is valid
    with pytest.raises(ConfigError, match=r"edge.yaml: robot_start=\[0.2, 4.0\].*env.margin=0.5"):
        TrackingConfig(map=path)


def test_a_malformed_yaml_file_is_named(tmp_path):
    path = tmp_path / "broken.yaml"
    path.write_text("size: [10.0, 8.0\nresolution: 0.5\n")
    with pytest.raises(ConfigError, match=rf"env.map='{path}': expected a map file that parses as YAML \(line"):
        load_map(str(path))
