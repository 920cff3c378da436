# ruff: noqa: UP031  (%-templates: JSON braces would need doubling in str.format)
"""Foxglove scene messages of a tracking episode, and their inverse for ``aia-log render``.

Three topics describe a recorded episode, all in the fixed frame ``world`` (metres, the map's lower-left
corner at the origin):

* ``/world`` (``foxglove.SceneUpdate``, once per recorded episode): entity ``map`` with one cube per
  maximal rectangle of occupied cells and the map border as a line loop; its metadata holds the map name,
  resolution and size, the sensor range and field of view, the episode index and the frame counter.
* ``/tf`` (``foxglove.FrameTransform``, every step): ``world -> robot``, the robot's pose.
* ``/scene`` (``foxglove.SceneUpdate``, every step): entity ``robot`` (frame ``robot``: heading arrow and
  field-of-view outline), entity ``targets`` (true positions: spheres, orange when observed, else red)
  and entity ``beliefs`` (each belief's ``sigma``-sigma position ellipse as a flat ellipsoid around the
  mean, green). The robot entity's metadata holds the episode index, the frame counter, the step, the
  simulation time and the observed flags.
* ``/belief_particles`` (``foxglove.PointCloud``, every step, with a particle filter only): every target's
  particles in frame ``world``, packed float32 fields ``x``, ``y``, ``z`` (0), ``weight`` and ``target`` (its
  index), so that Foxglove colours the cloud by weight or by target.

The per-step messages are formatted from templates rather than ``json.dumps`` (3-4x faster), which is how
recording keeps up with thousands of steps per second. :func:`parse_world` and :func:`parse_frame` invert
the encoding exactly (up to the printed precision), so the CLI draws what Foxglove shows.
"""

from __future__ import annotations

import base64
import json
import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:  # imported where a world is parsed: reading scalars needs no torch
    from aia.envs.maps import GridMap

WORLD_TOPIC = "/world"
TF_TOPIC = "/tf"
SCENE_TOPIC = "/scene"
PARTICLES_TOPIC = "/belief_particles"
WORLD_FRAME = "world"
ROBOT_FRAME = "robot"

MAP_COLOUR = (0.25, 0.25, 0.25, 1.0)
ROBOT_COLOUR = (0.12, 0.24, 0.86, 1.0)
FOV_COLOUR = (0.31, 0.55, 1.0, 0.8)
TARGET_COLOUR = (0.86, 0.12, 0.12, 1.0)
OBSERVED_COLOUR = (1.0, 0.59, 0.0, 1.0)
BELIEF_COLOUR = (0.1, 0.7, 0.2, 0.45)
OBSTACLE_HEIGHT = 1.0   # metres: cubes of the map stand on the ground plane
TARGET_DIAMETER = 0.5   # metres
FLAT = 0.02             # thickness of the belief ellipsoids, metres
FOV_ARC_POINTS = 24


@dataclass
class WorldInfo:
    """What ``/world`` holds: the map and the sensor of a recorded episode."""

    grid_map: GridMap
    sensor_range: float
    fov_deg: float
    num_targets: int
    episode: int
    frame: int


@dataclass
class SceneFrame:
    """One recorded step of one world, decoded from ``/scene`` and ``/tf``."""

    episode: int
    frame: int
    step: int
    time: float
    robot_pose: np.ndarray    # [3] x, y, theta
    targets: np.ndarray       # [N, 2] true positions
    belief_mean: np.ndarray   # [N, 2]
    belief_cov: np.ndarray    # [N, 2, 2] position block
    observed: np.ndarray      # [N] bool
    particles: np.ndarray | None = None  # [N, K, 2] particle positions (a particle filter's), else None


def _time(ns: int) -> str:
    return '{"sec":%d,"nsec":%d}' % divmod(ns, 1_000_000_000)


def _colour(rgba: tuple[float, float, float, float]) -> str:
    return '{"r":%g,"g":%g,"b":%g,"a":%g}' % rgba


def _pose(x: float, y: float, z: float, yaw: float = 0.0) -> str:
    return ('{"position":{"x":%.6g,"y":%.6g,"z":%.6g},"orientation":{"x":0,"y":0,"z":%.9g,"w":%.9g}}'
            % (x, y, z, math.sin(yaw / 2), math.cos(yaw / 2)))


def _metadata(items: dict[str, object]) -> str:
    return "[" + ",".join('{"key":"%s","value":"%s"}' % kv for kv in items.items()) + "]"


def _entity(stamp: str, frame_id: str, name: str, metadata: str = "[]", arrows: str = "", cubes: str = "",
            spheres: str = "", lines: str = "") -> str:
    return ('{"timestamp":%s,"frame_id":"%s","id":"%s","lifetime":{"sec":0,"nsec":0},"frame_locked":false,'
            '"metadata":%s,"arrows":[%s],"cubes":[%s],"spheres":[%s],"cylinders":[],"lines":[%s],'
            '"triangles":[],"texts":[],"models":[]}'
            % (stamp, frame_id, name, metadata, arrows, cubes, spheres, lines))


def _line(points: list[tuple[float, float]], colour: tuple, thickness: float, loop: bool = False) -> str:
    coords = ",".join('{"x":%.6g,"y":%.6g,"z":0}' % p for p in points)
    return ('{"type":%d,"pose":%s,"thickness":%g,"scale_invariant":false,"points":[%s],"color":%s,'
            '"colors":[],"indices":[]}' % (1 if loop else 0, _pose(0, 0, 0), thickness, coords, _colour(colour)))


def occupied_rectangles(occupancy: np.ndarray) -> list[tuple[int, int, int, int]]:
    """Cover the ``True`` cells of ``occupancy [ny, nx]`` with disjoint rectangles ``(ix0, iy0, ix1, iy1)``
    (cell indices, ``ix1``/``iy1`` exclusive): row runs, each merged with the identical run of the row below."""
    open_runs: dict[tuple[int, int], int] = {}  # (ix0, ix1) -> first row of the rectangle still growing
    rectangles = []
    for iy, row in enumerate(np.vstack([occupancy.astype(bool), np.zeros((1, occupancy.shape[1]), bool)])):
        edges = np.flatnonzero(np.diff(np.concatenate(([0], row.astype(np.int8), [0]))))
        runs = set(zip(edges[::2].tolist(), edges[1::2].tolist(), strict=True))
        for run in [r for r in open_runs if r not in runs]:
            rectangles.append((run[0], open_runs.pop(run), run[1], iy))
        for run in runs - open_runs.keys():
            open_runs[run] = iy
    return sorted(rectangles, key=lambda r: (r[1], r[0]))


def world_message(info: WorldInfo, stamp_ns: int) -> bytes:
    """``/world``: the map as cubes plus a border loop, and the sensor and episode as metadata."""
    grid, res = info.grid_map, info.grid_map.resolution
    cubes = ",".join(
        '{"pose":%s,"size":{"x":%.6g,"y":%.6g,"z":%g},"color":%s}'
        % (_pose((x0 + x1) * res / 2, (y0 + y1) * res / 2, OBSTACLE_HEIGHT / 2), (x1 - x0) * res, (y1 - y0) * res,
           OBSTACLE_HEIGHT, _colour(MAP_COLOUR))
        for x0, y0, x1, y1 in occupied_rectangles(grid.occupancy.cpu().numpy())
    )
    border = _line([(0, 0), (grid.width, 0), (grid.width, grid.height), (0, grid.height)], MAP_COLOUR, 0.05, True)
    metadata = _metadata({
        "map": grid.name, "resolution": repr(res), "cells_x": grid.shape[1], "cells_y": grid.shape[0],
        "sensor_range": repr(info.sensor_range), "fov_deg": repr(info.fov_deg), "num_targets": info.num_targets,
        "episode": info.episode, "frame": info.frame,
    })
    entity = _entity(_time(stamp_ns), WORLD_FRAME, "map", metadata, cubes=cubes, lines=border)
    return ('{"deletions":[],"entities":[%s]}' % entity).encode()


def robot_shapes(sensor_range: float, fov_deg: float) -> tuple[str, str]:
    """The robot's constant drawing in its own frame: a heading arrow and the field-of-view outline."""
    arrow = ('{"pose":%s,"shaft_length":0.8,"shaft_diameter":0.2,"head_length":0.5,"head_diameter":0.5,'
             '"color":%s}' % (_pose(0, 0, 0.1), _colour(ROBOT_COLOUR)))
    half = math.radians(fov_deg) / 2
    arc = [(sensor_range * math.cos(a), sensor_range * math.sin(a))
           for a in np.linspace(-half, half, FOV_ARC_POINTS).tolist()]
    return arrow, _line([(0.0, 0.0), *arc], FOV_COLOUR, 0.05, loop=fov_deg < 360)


def ellipse(cov: Sequence[Sequence[float]], sigma: float) -> tuple[float, float, float]:
    """(diameter along the major axis, along the minor axis, angle of the major axis) of the ``sigma``-sigma
    ellipse of a covariance whose top-left 2x2 block is the position's (closed-form eigen-decomposition in
    plain Python: for a handful of targets it is 20x cheaper than numpy's)."""
    a, b, d = cov[0][0], cov[0][1], cov[1][1]
    centre, radius = (a + d) / 2, math.hypot((a - d) / 2, b)
    minor = max(centre - radius, 0.0)
    return 2 * sigma * math.sqrt(centre + radius), 2 * sigma * math.sqrt(minor), 0.5 * math.atan2(2 * b, a - d)


class FrameEncoder:
    """Formats the ``/tf`` and ``/scene`` messages of one step (the hot path of episode recording)."""

    def __init__(self, sensor_range: float, fov_deg: float, sigma: float = 2.0) -> None:
        self.arrow, self.fov = robot_shapes(sensor_range, fov_deg)
        self.sigma = sigma
        self._observed = _colour(OBSERVED_COLOUR)
        self._unobserved = _colour(TARGET_COLOUR)
        self._belief = _colour(BELIEF_COLOUR)

    def encode(self, stamp_ns: int, episode: int, frame: int, step: int, time: float, robot_pose: Sequence[float],
               targets: Sequence[Sequence[float]], belief_mean: Sequence[Sequence[float]],
               belief_cov: Sequence[Sequence[Sequence[float]]], observed: Sequence[bool]) -> tuple[bytes, bytes]:
        """``(tf, scene)`` payloads of one step from plain lists: the pose (x, y, theta), per target its true
        state and belief mean (positions first) and belief covariance, and whether it is observed.
        Non-finite numbers (which JSON cannot hold) are drawn as 0."""
        if not math.isfinite(sum(robot_pose) + sum(map(sum, targets)) + sum(map(sum, belief_mean))
                             + sum(sum(map(sum, c)) for c in belief_cov)):
            robot_pose, targets, belief_mean, belief_cov = _finite((robot_pose, targets, belief_mean, belief_cov))
        x, y, theta = robot_pose
        stamp = _time(stamp_ns)
        tf = ('{"timestamp":%s,"parent_frame_id":"world","child_frame_id":"robot",'
              '"translation":{"x":%.9g,"y":%.9g,"z":0},"rotation":{"x":0,"y":0,"z":%.12g,"w":%.12g}}'
              % (stamp, x, y, math.sin(theta / 2), math.cos(theta / 2)))
        flags = ",".join("1" if o else "0" for o in observed)
        metadata = ('[{"key":"episode","value":"%d"},{"key":"frame","value":"%d"},{"key":"step","value":"%d"},'
                    '{"key":"time","value":"%r"},{"key":"observed","value":"%s"},{"key":"sigma","value":"%r"}]'
                    % (episode, frame, step, time, flags, self.sigma))
        spheres = ",".join(
            '{"pose":%s,"size":{"x":%g,"y":%g,"z":%g},"color":%s}'
            % (_pose(px, py, 0.1), TARGET_DIAMETER, TARGET_DIAMETER, TARGET_DIAMETER,
               self._observed if seen else self._unobserved)
            for (px, py, *_), seen in zip(targets, observed, strict=True)
        )
        beliefs = ",".join(
            '{"pose":%s,"size":{"x":%.9g,"y":%.9g,"z":%g},"color":%s}'
            % (_pose(mx, my, 0.0, angle), major, minor, FLAT, self._belief)
            for (mx, my, *_), (major, minor, angle) in zip(
                belief_mean, (ellipse(c, self.sigma) for c in belief_cov), strict=True)
        )
        scene = ('{"deletions":[],"entities":[%s,%s,%s]}' % (
            _entity(stamp, ROBOT_FRAME, "robot", metadata, arrows=self.arrow, lines=self.fov),
            _entity(stamp, WORLD_FRAME, "targets", spheres=spheres),
            _entity(stamp, WORLD_FRAME, "beliefs", spheres=beliefs),
        ))
        return tf.encode(), scene.encode()


# foxglove.PointCloud's packed fields of a particle: (name, byte offset); every field a float32 (NumericType 7)
_PARTICLE_FIELDS = (("x", 0), ("y", 4), ("z", 8), ("weight", 12), ("target", 16))
_FLOAT32 = 7


def particle_cloud_message(stamp_ns: int, particles: np.ndarray, weights: np.ndarray) -> bytes:
    """``/belief_particles``: the particles ``[N, K, >= 2]`` (positions first) with their weights ``[N, K]`` as a
    ``foxglove.PointCloud`` in frame ``world``."""
    num_targets, count = weights.shape
    points = np.zeros((num_targets, count, len(_PARTICLE_FIELDS)), dtype="<f4")
    points[..., :2] = particles[..., :2]
    points[..., 3] = weights
    points[..., 4] = np.arange(num_targets)[:, None]
    fields = ",".join('{"name":"%s","offset":%d,"type":%d}' % (name, offset, _FLOAT32)
                      for name, offset in _PARTICLE_FIELDS)
    return ('{"timestamp":%s,"frame_id":"%s","pose":%s,"point_stride":%d,"fields":[%s],"data":"%s"}' % (
        _time(stamp_ns), WORLD_FRAME, _pose(0.0, 0.0, 0.0), points.itemsize * len(_PARTICLE_FIELDS), fields,
        base64.b64encode(points.tobytes()).decode())).encode()


def parse_particle_cloud(data: bytes) -> tuple[np.ndarray, np.ndarray]:
    """Invert :func:`particle_cloud_message`: ``(positions [N, K, 2], weights [N, K])``."""
    cloud = json.loads(data)
    points = np.frombuffer(base64.b64decode(cloud["data"]), dtype="<f4").reshape(-1, len(_PARTICLE_FIELDS))
    num_targets = int(points[:, 4].max()) + 1 if len(points) else 0
    points = points.reshape(num_targets, -1, len(_PARTICLE_FIELDS)).astype(np.float64)
    return points[..., :2], points[..., 3]


def _finite(values):
    """``values`` (nested lists of numbers) with every non-finite number replaced by 0."""
    if isinstance(values, (list, tuple)):
        return [_finite(v) for v in values]
    return values if math.isfinite(values) else 0.0


def _meta(entity: dict) -> dict[str, str]:
    return {item["key"]: item["value"] for item in entity["metadata"]}


def _yaw(orientation: dict) -> float:
    return 2.0 * math.atan2(orientation["z"], orientation["w"])


def world_episode(data: bytes) -> int:
    """The episode index of a ``/world`` message, without rasterising its map (:func:`parse_world`)."""
    return int(_meta(json.loads(data)["entities"][0])["episode"])


def parse_world(data: bytes) -> WorldInfo:
    """Invert :func:`world_message`: the map is rasterised back from its cubes."""
    import torch

    from aia.envs.maps import GridMap

    entity = json.loads(data)["entities"][0]
    meta = _meta(entity)
    res, nx, ny = float(meta["resolution"]), int(meta["cells_x"]), int(meta["cells_y"])
    occupancy = np.zeros((ny, nx), dtype=bool)
    for cube in entity["cubes"]:
        centre, size = cube["pose"]["position"], cube["size"]
        x0, y0 = round((centre["x"] - size["x"] / 2) / res), round((centre["y"] - size["y"] / 2) / res)
        occupancy[y0:y0 + round(size["y"] / res), x0:x0 + round(size["x"] / res)] = True
    grid_map = GridMap(name=meta["map"], resolution=res, occupancy=torch.from_numpy(occupancy))
    return WorldInfo(grid_map, float(meta["sensor_range"]), float(meta["fov_deg"]), int(meta["num_targets"]),
                     int(meta["episode"]), int(meta["frame"]))


def parse_frame(tf: bytes, scene: bytes) -> SceneFrame:
    """Invert :meth:`FrameEncoder.encode`: the belief covariance is rebuilt from its ellipse."""
    transform = json.loads(tf)
    entities = {e["id"]: e for e in json.loads(scene)["entities"]}
    meta = _meta(entities["robot"])
    sigma = float(meta["sigma"])
    pose = np.array([transform["translation"]["x"], transform["translation"]["y"], _yaw(transform["rotation"])])
    targets = np.array([[s["pose"]["position"]["x"], s["pose"]["position"]["y"]]
                        for s in entities["targets"]["spheres"]]).reshape(-1, 2)
    beliefs = entities["beliefs"]["spheres"]
    means = np.array([[s["pose"]["position"]["x"], s["pose"]["position"]["y"]] for s in beliefs]).reshape(-1, 2)
    covs = np.zeros((len(beliefs), 2, 2))
    for i, sphere in enumerate(beliefs):
        angle = _yaw(sphere["pose"]["orientation"])
        rotation = np.array([[math.cos(angle), -math.sin(angle)], [math.sin(angle), math.cos(angle)]])
        variances = (np.array([sphere["size"]["x"], sphere["size"]["y"]]) / (2 * sigma)) ** 2
        covs[i] = rotation @ np.diag(variances) @ rotation.T
    flags = meta["observed"]
    observed = np.array([f == "1" for f in flags.split(",")] if flags else [], dtype=bool)
    return SceneFrame(int(meta["episode"]), int(meta["frame"]), int(meta["step"]), float(meta["time"]), pose,
                      targets, means, covs, observed)
