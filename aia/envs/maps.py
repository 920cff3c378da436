"""Occupancy-grid maps: loading, validation and rasterisation.

A map is a YAML file in ``conf/maps/`` (or any path a user passes): its size in metres, its grid
resolution, where the robot starts, and its obstacles, given either as geometry (border cells, axis-aligned
boxes, rotated boxes; rasterised here: a cell is occupied when its centre lies inside) or as an occupancy
array in a ``.npy`` file next to the YAML. Row ``i`` of the grid is the cells with ``y`` in
``[i * res, (i + 1) * res)``; the origin is the lower-left corner.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass
from importlib import resources
from pathlib import Path

import numpy as np
import torch
import yaml
from torch import Tensor

from aia.config.checks import check_number, require
from aia.config.errors import ConfigError
from aia.envs.config import RANDOM_MAP

_MAP_KEYS = {"size", "resolution", "robot_start", "border_cells", "boxes", "rotated_boxes", "grid", "description"}


@dataclass(frozen=True)
class GridMap:
    """A rectangular world ``[0, width] x [0, height]`` with an occupancy grid (``[ny, nx]``, row = y)."""

    name: str
    resolution: float
    occupancy: Tensor
    # None: the robot starts uniformly in the collision-free space; else a fixed (x, y).
    robot_start: tuple[float, float] | None = None
    # Where the map came from (its file's path), for messages.
    source: str | None = None

    @property
    def shape(self) -> tuple[int, int]:
        return tuple(self.occupancy.shape)  # type: ignore[return-value]

    @property
    def width(self) -> float:
        return self.occupancy.shape[1] * self.resolution

    @property
    def height(self) -> float:
        return self.occupancy.shape[0] * self.resolution

    @property
    def has_obstacles(self) -> bool:
        return bool(self.occupancy.any())


def map_directory() -> Path:
    """The folder of the maps that ship with aia (``conf/maps``)."""
    return Path(str(resources.files("aia.conf") / "maps"))


def available_maps() -> list[str]:
    """Names of the shipped maps."""
    return sorted(p.stem for p in map_directory().glob("*.yaml"))


@functools.lru_cache(maxsize=32)
def load_map(name_or_path: str) -> GridMap:
    """Load a shipped map by name (``"obstacles4"``) or any map YAML by path; a
    :class:`~aia.config.errors.ConfigError` names the file, the field and what is allowed."""
    path = Path(name_or_path)
    if path.suffix not in (".yaml", ".yml"):
        path = map_directory() / f"{name_or_path}.yaml"
        require(path.is_file(), "env.map", name_or_path,
                f"one of {available_maps()}, a path to a map .yaml file, or {RANDOM_MAP} (a new layout per "
                "world and episode)")
    require(path.is_file(), "env.map", name_or_path, "an existing map .yaml file (this one does not exist)")
    try:
        spec = yaml.safe_load(path.read_text())
    except yaml.YAMLError as err:
        mark = getattr(err, "problem_mark", None)
        where = f" (line {mark.line + 1}, column {mark.column + 1}: {err.problem})" if mark else ""
        raise ConfigError("env.map", str(path), f"a map file that parses as YAML{where}") from None
    return build_map(spec, name=path.stem, base_dir=path.parent, source=str(path))


def build_map(spec: dict, name: str = "custom", base_dir: Path | None = None, source: str | None = None) -> GridMap:
    """Build a :class:`GridMap` from a map specification (the parsed YAML; see the module docstring).
    Every field is checked (sizes positive, obstacles inside the map, the robot's start inside and free);
    a :class:`~aia.config.errors.ConfigError` names ``source`` (default: ``map '<name>'``) and the field."""
    source = source or f"map {name!r}"
    require(isinstance(spec, dict), "map", type(spec).__name__, "a mapping of fields (size, resolution, ...)", source)
    unknown = sorted(set(spec) - _MAP_KEYS)
    require(not unknown, "fields", unknown, f"fields among {sorted(_MAP_KEYS)}", source)
    size = spec.get("size")
    require(isinstance(size, list) and len(size) == 2 and all(_is_number(v) and v > 0 for v in size), "size", size,
            "[width, height] in metres, both > 0", source)
    width, height = float(size[0]), float(size[1])
    check_number("resolution", spec.get("resolution"), gt=0, source=source)
    resolution = float(spec["resolution"])
    nx, ny = round(width / resolution), round(height / resolution)
    whole = math.isclose(nx * resolution, width, abs_tol=1e-6) and math.isclose(ny * resolution, height, abs_tol=1e-6)
    require(whole, "size", size, f"a whole number of {resolution} m cells (resolution)", source)

    if spec.get("grid") is not None:
        occupancy = _load_grid(Path(base_dir or ".") / spec["grid"], (ny, nx), source)
    else:
        occupancy = _rasterise(_checked_geometry(spec, width, height, nx, ny, source), nx, ny, resolution)

    start = spec.get("robot_start")
    if start is None:
        require(not bool(occupancy.all()), "robot_start", None, "a map with a free cell to start in", source)
    else:
        inside = (isinstance(start, list) and len(start) == 2 and all(_is_number(v) for v in start)
                  and 0 <= start[0] <= width and 0 <= start[1] <= height)
        require(inside, "robot_start", start, f"[x, y] inside [0, {width}] x [0, {height}]", source)
        start = (float(start[0]), float(start[1]))
        col, row = min(int(start[0] / resolution), nx - 1), min(int(start[1] / resolution), ny - 1)
        require(not bool(occupancy[row, col]), "robot_start", list(start), "a free cell (this one is occupied)",
                source)
    return GridMap(name=name, resolution=resolution, occupancy=occupancy, robot_start=start, source=source)


def check_start_margin(grid_map: GridMap, margin: float) -> None:
    """The map's fixed start, if any, lies at least ``margin`` (the env's collision margin) from its bounds."""
    if grid_map.robot_start is None:
        return
    x, y = grid_map.robot_start
    ok = margin <= x <= grid_map.width - margin and margin <= y <= grid_map.height - margin
    require(ok, "robot_start", list(grid_map.robot_start),
            f"a start at least env.margin={margin} m from the map's bounds", grid_map.source)


def _is_number(value) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool)


def _checked_geometry(spec: dict, width: float, height: float, nx: int, ny: int, source: str) -> dict:
    """The obstacle fields of ``spec``, each checked: a border thinner than half the map, boxes inside it."""
    border = spec.get("border_cells") or 0
    check_number("border_cells", border, ge=0, le=(min(nx, ny) - 1) // 2, integer=True, source=source)
    inside = f"inside the map [0, {width}] x [0, {height}]"
    boxes = spec.get("boxes") or []
    require(isinstance(boxes, list), "boxes", boxes, "a list of [xmin, ymin, xmax, ymax]", source)
    for i, box in enumerate(boxes):
        ok = isinstance(box, list) and len(box) == 4 and all(_is_number(v) for v in box)
        ok = ok and 0 <= box[0] < box[2] <= width and 0 <= box[1] < box[3] <= height
        require(ok, f"boxes[{i}]", box, f"[xmin, ymin, xmax, ymax] with xmin < xmax, ymin < ymax, {inside}", source)
    rotated = spec.get("rotated_boxes") or []
    require(isinstance(rotated, list), "rotated_boxes", rotated, "a list of {center, size, angle_deg}", source)
    for i, box in enumerate(rotated):
        key = f"rotated_boxes[{i}]"
        fields = isinstance(box, dict) and set(box) == {"center", "size", "angle_deg"}
        require(fields, key, box, "{center: [x, y], size: [length, width], angle_deg: a}", source)
        center, extent = box["center"], box["size"]
        shape = all(isinstance(v, list) and len(v) == 2 and all(_is_number(u) for u in v) for v in (center, extent))
        require(shape and _is_number(box["angle_deg"]) and min(extent) > 0, key, box,
                "center [x, y], size [length, width] > 0 and a number angle_deg", source)
        corners = _corners(center, extent, math.radians(box["angle_deg"]))
        ok = all(0 <= x <= width and 0 <= y <= height for x, y in corners)
        require(ok, key, box, f"a box whose corners lie {inside}", source)
    return {"border_cells": border, "boxes": boxes, "rotated_boxes": rotated}


def _corners(center: list, extent: list, angle: float) -> list[tuple[float, float]]:
    (x0, y0), (length, width), c, s = center, extent, math.cos(angle), math.sin(angle)
    half = ((-length / 2, -width / 2), (-length / 2, width / 2), (length / 2, -width / 2), (length / 2, width / 2))
    return [(x0 + u * c - v * s, y0 + u * s + v * c) for u, v in half]


def _load_grid(path: Path, expected: tuple[int, int], source: str) -> Tensor:
    require(path.is_file(), "grid", str(path), "an existing .npy file (this one does not exist)", source)
    try:
        grid = np.load(path, allow_pickle=False)
    except (ValueError, OSError) as err:
        raise ConfigError("grid", str(path), f"a readable .npy array ({err})", source) from None
    require(grid.shape == expected, "grid", str(path),
            f"a grid that fits the map (the file has shape {list(grid.shape)}; size / resolution needs "
            f"[rows (y), cols (x)] = {list(expected)})", source)
    return torch.from_numpy(np.asarray(grid) != 0)


def _rasterise(spec: dict, nx: int, ny: int, resolution: float) -> Tensor:
    """Occupancy from checked geometry (:func:`_checked_geometry`): a cell is occupied when its centre lies
    in a box or in the border."""
    xs = (torch.arange(nx, dtype=torch.float64) + 0.5) * resolution
    ys = (torch.arange(ny, dtype=torch.float64) + 0.5) * resolution
    cy, cx = torch.meshgrid(ys, xs, indexing="ij")
    occupancy = torch.zeros(ny, nx, dtype=torch.bool)
    border = spec["border_cells"]
    if border > 0:
        occupancy[:border] = occupancy[-border:] = True
        occupancy[:, :border] = occupancy[:, -border:] = True
    for xmin, ymin, xmax, ymax in spec["boxes"]:
        occupancy |= (cx >= xmin) & (cx <= xmax) & (cy >= ymin) & (cy <= ymax)
    for box in spec["rotated_boxes"]:
        (x0, y0), (length, width) = box["center"], box["size"]
        angle = math.radians(box["angle_deg"])
        # Coordinates of each cell centre in the box frame.
        u = (cx - x0) * math.cos(angle) + (cy - y0) * math.sin(angle)
        v = -(cx - x0) * math.sin(angle) + (cy - y0) * math.cos(angle)
        occupancy |= (u.abs() <= length / 2) & (v.abs() <= width / 2)
    return occupancy
