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

_MAP_KEYS = {"size", "resolution", "robot_start", "border_cells", "boxes", "rotated_boxes", "grid", "description"}


@dataclass(frozen=True)
class GridMap:
    """A rectangular world ``[0, width] x [0, height]`` with an occupancy grid (``[ny, nx]``, row = y)."""

    name: str
    resolution: float
    occupancy: Tensor
    # None: the robot starts uniformly in the collision-free space; else a fixed (x, y).
    robot_start: tuple[float, float] | None = None

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
    """Load a shipped map by name (``"obstacles4"``) or any map YAML by path."""
    path = Path(name_or_path)
    if path.suffix not in (".yaml", ".yml"):
        path = map_directory() / f"{name_or_path}.yaml"
        if not path.is_file():
            raise ValueError(
                f"unknown map {name_or_path!r}: expected one of {available_maps()} or a path to a map .yaml file"
            )
    elif not path.is_file():
        raise ValueError(f"map file {str(path)!r} does not exist")
    spec = yaml.safe_load(path.read_text())
    return build_map(spec, name=path.stem, base_dir=path.parent)


def build_map(spec: dict, name: str = "custom", base_dir: Path | None = None) -> GridMap:
    """Build a :class:`GridMap` from a map specification (the parsed YAML; see the module docstring)."""
    if not isinstance(spec, dict):
        raise ValueError(f"map {name!r}: expected a mapping of fields, got {type(spec).__name__}")
    unknown = set(spec) - _MAP_KEYS
    if unknown:
        raise ValueError(f"map {name!r}: unknown fields {sorted(unknown)}; allowed: {sorted(_MAP_KEYS)}")
    try:
        width, height = (float(v) for v in spec["size"])
        resolution = float(spec["resolution"])
    except (KeyError, TypeError, ValueError) as err:
        raise ValueError(f"map {name!r}: needs 'size: [width, height]' and 'resolution' in metres ({err})") from None
    if resolution <= 0 or width <= 0 or height <= 0:
        raise ValueError(f"map {name!r}: size {[width, height]} and resolution {resolution} must be positive")
    nx, ny = round(width / resolution), round(height / resolution)
    if not (math.isclose(nx * resolution, width, abs_tol=1e-6) and math.isclose(ny * resolution, height, abs_tol=1e-6)):
        raise ValueError(f"map {name!r}: size {[width, height]} is not a whole number of {resolution} m cells")

    if spec.get("grid") is not None:
        occupancy = _load_grid(Path(base_dir or ".") / spec["grid"], (ny, nx), name)
    else:
        occupancy = _rasterise(spec, nx, ny, resolution)

    start = spec.get("robot_start")
    if start is not None:
        start = (float(start[0]), float(start[1]))
        if not (0 <= start[0] <= width and 0 <= start[1] <= height):
            raise ValueError(f"map {name!r}: robot_start {list(start)} lies outside [0, {width}] x [0, {height}]")
    return GridMap(name=name, resolution=resolution, occupancy=occupancy, robot_start=start)


def _load_grid(path: Path, expected: tuple[int, int], name: str) -> Tensor:
    if not path.is_file():
        raise ValueError(f"map {name!r}: grid file {str(path)!r} does not exist")
    try:
        grid = np.load(path, allow_pickle=False)
    except (ValueError, OSError) as err:
        raise ValueError(f"map {name!r}: cannot read grid file {str(path)!r} as a .npy array ({err})") from None
    if grid.shape != expected:
        raise ValueError(
            f"map {name!r}: grid file {str(path)!r} has shape {list(grid.shape)}, but size / resolution "
            f"needs [rows (y), cols (x)] = {list(expected)}"
        )
    return torch.from_numpy(np.asarray(grid) != 0)


def _rasterise(spec: dict, nx: int, ny: int, resolution: float) -> Tensor:
    """Occupancy from geometry: a cell is occupied when its centre lies in a box or in the border."""
    xs = (torch.arange(nx, dtype=torch.float64) + 0.5) * resolution
    ys = (torch.arange(ny, dtype=torch.float64) + 0.5) * resolution
    cy, cx = torch.meshgrid(ys, xs, indexing="ij")
    occupancy = torch.zeros(ny, nx, dtype=torch.bool)
    border = int(spec.get("border_cells") or 0)
    if border > 0:
        occupancy[:border] = occupancy[-border:] = True
        occupancy[:, :border] = occupancy[:, -border:] = True
    for xmin, ymin, xmax, ymax in spec.get("boxes") or []:
        occupancy |= (cx >= xmin) & (cx <= xmax) & (cy >= ymin) & (cy <= ymax)
    for box in spec.get("rotated_boxes") or []:
        (x0, y0), (length, width) = box["center"], box["size"]
        angle = math.radians(box["angle_deg"])
        # Coordinates of each cell centre in the box frame.
        u = (cx - x0) * math.cos(angle) + (cy - y0) * math.sin(angle)
        v = -(cx - x0) * math.sin(angle) + (cy - y0) * math.cos(angle)
        occupancy |= (u.abs() <= length / 2) & (v.abs() <= width / 2)
    return occupancy
