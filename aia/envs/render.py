"""Draw one tracking world as an RGB image with Pillow (no matplotlib).

:func:`render_frame` paints, back to front: the occupancy grid (occupied cells dark grey on white, the map
drawn with ``y`` pointing up), the sensor's field of view (a translucent blue sector), optional trails of
earlier robot and target positions (small blue and red dots, as in the paper's Fig. 3), the 2-sigma position
ellipse of every belief, the belief means (green dots), the true targets (red dots, ringed in orange when
observed), the robot (a blue triangle pointing along its heading) and the map border. The map keeps its
aspect ratio: a non-square map is centred and the rest of the square canvas is padded in light grey.

The colours are module constants so that callers (and tests) can find the drawn items by colour.
"""

from __future__ import annotations

import math

import numpy as np
import torch
from PIL import Image, ImageDraw

from aia.envs.maps import GridMap

FREE_COLOUR = (255, 255, 255)
OCCUPIED_COLOUR = (64, 64, 64)
PAD_COLOUR = (220, 220, 220)
BORDER_COLOUR = (0, 0, 0)
ROBOT_COLOUR = (30, 60, 220)
FOV_COLOUR = (80, 140, 255)
FOV_ALPHA = 70
TARGET_COLOUR = (220, 30, 30)
OBSERVED_COLOUR = (255, 150, 0)
BELIEF_COLOUR = (0, 160, 0)
PARTICLE_COLOUR = (140, 210, 140)

# Vertices of each 2-sigma ellipse polygon.
_ELLIPSE_POINTS = 72
# Pixel coordinates are clipped to this many canvas sizes around the canvas (a huge covariance would
# otherwise overflow Pillow's integer coordinates); only what lies far outside the image moves.
_CLIP_CANVASES = 8


def render_frame(
    grid_map: GridMap,
    robot_pose: torch.Tensor | np.ndarray,
    target_state: torch.Tensor | np.ndarray,
    belief_mean: torch.Tensor | np.ndarray,
    belief_cov: torch.Tensor | np.ndarray,
    sensor_range: float,
    fov_deg: float,
    size: int = 512,
    observed: torch.Tensor | np.ndarray | None = None,
    robot_path: np.ndarray | None = None,
    target_paths: np.ndarray | None = None,
    view: tuple[float, float, float, float] | None = None,
    target_heading: torch.Tensor | np.ndarray | None = None,
    particles: torch.Tensor | np.ndarray | None = None,
) -> np.ndarray:
    """An RGB frame ``uint8 [size, size, 3]`` of one world.

    Args:
        grid_map: the world's map (its occupancy ``[ny, nx]``, row = y, origin at the lower-left corner).
        robot_pose: ``[3]`` (x, y, theta) in metres and radians.
        target_state: ``[N, D]`` true target states, the position first; only the positions are drawn.
        belief_mean: ``[N, d]`` belief means, the position first; only the positions are drawn.
        belief_cov: ``[N, d, d]`` belief covariances; the 2x2 position block gives the 2-sigma ellipse.
        sensor_range: radius of the field-of-view sector in metres.
        fov_deg: opening angle of the field-of-view sector in degrees.
        size: side of the square image in pixels.
        observed: optional ``[N]`` booleans; observed targets get an orange ring.
        robot_path: optional ``[K, 2]`` earlier robot positions, drawn as small blue dots (the paper's Fig. 3).
        target_paths: optional ``[K, N, 2]`` earlier true target positions, drawn as small red dots.
        view: optional ``(x0, y0, x1, y1)`` in metres: draw only this rectangle (centred, aspect kept),
            e.g. to zoom on the action in a large map; default: the whole map.
        target_heading: optional ``[N]`` headings of SE(2) targets, each drawn as a short line from the target.
        particles: optional ``[N, K, >= 2]`` particle-filter particles, drawn as small dots under the ellipses.
    """
    size = int(size)
    if size < 16:
        raise ValueError(f"size={size} must be at least 16 pixels")
    pose = _as_numpy(robot_pose, "robot_pose").reshape(-1)
    targets = _as_numpy(target_state, "target_state")
    means = _as_numpy(belief_mean, "belief_mean")
    covs = _as_numpy(belief_cov, "belief_cov")
    if pose.shape != (3,):
        raise ValueError(f"robot_pose must hold (x, y, theta) of one world, got shape {list(pose.shape)}")
    if targets.ndim != 2 or targets.shape[1] < 2:
        raise ValueError(f"target_state must be [N, D >= 2] for one world, got shape {list(targets.shape)}")
    num_targets = targets.shape[0]
    if means.shape[:1] != (num_targets,) or means.ndim != 2 or means.shape[1] < 2:
        raise ValueError(f"belief_mean must be [N={num_targets}, d >= 2], got shape {list(means.shape)}")
    if covs.ndim != 3 or covs.shape[0] != num_targets or covs.shape[1] < 2 or covs.shape[1] != covs.shape[2]:
        raise ValueError(f"belief_cov must be [N={num_targets}, d, d], got shape {list(covs.shape)}")
    seen = None
    if observed is not None:
        seen = _as_numpy(observed, "observed").astype(bool).reshape(-1)
        if seen.shape != (num_targets,):
            raise ValueError(f"observed must be [N={num_targets}], got shape {list(seen.shape)}")

    width, height = float(grid_map.width), float(grid_map.height)
    if view is None:
        scale = size / max(width, height)  # pixels per metre
        map_w, map_h = max(1, round(width * scale)), max(1, round(height * scale))
        offset = np.array([(size - map_w) // 2, (size - map_h) // 2], dtype=np.float64)  # the map's corner
    else:
        x0, y0, x1, y1 = (float(v) for v in view)
        if not (x1 > x0 and y1 > y0):
            raise ValueError(f"view={tuple(view)} must be (x0, y0, x1, y1) with x1 > x0 and y1 > y0")
        scale = size / max(x1 - x0, y1 - y0)
        map_w, map_h = max(1, round(width * scale)), max(1, round(height * scale))
        centring = np.array([size - (x1 - x0) * scale, size - (y1 - y0) * scale]) / 2
        offset = np.round(centring - np.array([x0, height - y1]) * scale)

    def to_pixels(xy: np.ndarray) -> np.ndarray:
        """Metres ``[..., 2]`` to pixel coordinates ``[..., 2]`` (column, row; y up in the world)."""
        px = np.stack((xy[..., 0] * scale, (height - xy[..., 1]) * scale), -1) + offset
        return np.clip(px, -_CLIP_CANVASES * size, (_CLIP_CANVASES + 1) * size)

    image = Image.new("RGB", (size, size), PAD_COLOUR)
    image.paste(_grid_image(grid_map, map_w, map_h), (int(offset[0]), int(offset[1])))

    # Field of view: a translucent sector composited over the map.
    centre = to_pixels(pose[:2])
    overlay = Image.new("RGBA", (size, size), (0, 0, 0, 0))
    radius = float(sensor_range) * scale
    heading_deg = -math.degrees(float(pose[2]))  # Pillow's angles turn clockwise (the image y points down)
    half = float(fov_deg) / 2
    ImageDraw.Draw(overlay).pieslice(
        [centre[0] - radius, centre[1] - radius, centre[0] + radius, centre[1] + radius],
        start=heading_deg - half, end=heading_deg + half, fill=(*FOV_COLOUR, FOV_ALPHA),
    )
    image = Image.alpha_composite(image.convert("RGBA"), overlay).convert("RGB")
    draw = ImageDraw.Draw(image)

    line = max(1, round(size / 256))
    dot = max(2.0, size / 128)
    trail = dot / 2
    for path, colour in ((robot_path, ROBOT_COLOUR), (target_paths, TARGET_COLOUR)):
        if path is not None:
            for x, y in to_pixels(np.asarray(path, dtype=np.float64).reshape(-1, 2)).tolist():
                draw.ellipse([x - trail, y - trail, x + trail, y + trail], fill=colour)
    if particles is not None:
        cloud = _as_numpy(particles, "particles")
        if cloud.ndim != 3 or cloud.shape[0] != num_targets or cloud.shape[2] < 2:
            raise ValueError(f"particles must be [N={num_targets}, K, d], got shape {list(cloud.shape)}")
        speck = max(1.0, dot / 4)
        for x, y in to_pixels(cloud[..., :2].reshape(-1, 2)).tolist():
            draw.ellipse([x - speck, y - speck, x + speck, y + speck], fill=PARTICLE_COLOUR)
    for polygon in _ellipse_polygons(means[:, :2], covs[:, :2, :2], to_pixels):
        draw.polygon([tuple(p) for p in polygon.tolist()], outline=BELIEF_COLOUR, width=line)
    for x, y in to_pixels(means[:, :2]).tolist():
        draw.ellipse([x - dot, y - dot, x + dot, y + dot], fill=BELIEF_COLOUR)
    target_px = to_pixels(targets[:, :2])
    for i, (x, y) in enumerate(target_px.tolist()):
        if seen is not None and seen[i]:
            ring = dot + 2 * line + 1
            draw.ellipse([x - ring, y - ring, x + ring, y + ring], outline=OBSERVED_COLOUR, width=line + 1)
        draw.ellipse([x - dot, y - dot, x + dot, y + dot], fill=TARGET_COLOUR)
    if target_heading is not None:
        headings = _as_numpy(target_heading, "target_heading").reshape(-1)
        if headings.shape != (num_targets,):
            raise ValueError(f"target_heading must be [N={num_targets}], got shape {list(headings.shape)}")
        tips = target_px + 3 * dot * np.stack((np.cos(headings), -np.sin(headings)), -1)  # image y points down
        for (x, y), (u, v) in zip(target_px.tolist(), tips.tolist(), strict=True):
            draw.line([x, y, u, v], fill=TARGET_COLOUR, width=line + 1)

    triangle = _robot_triangle(centre, float(pose[2]), size)
    draw.polygon([tuple(p) for p in triangle.tolist()], fill=ROBOT_COLOUR)
    x0, y0 = offset
    draw.rectangle([x0, y0, x0 + map_w - 1, y0 + map_h - 1], outline=BORDER_COLOUR, width=line)
    return np.asarray(image, dtype=np.uint8).copy()


def _as_numpy(value: torch.Tensor | np.ndarray, name: str) -> np.ndarray:
    """A float64 (or bool) numpy copy of a tensor or array."""
    if isinstance(value, torch.Tensor):
        value = value.detach().cpu()
        value = value.numpy() if value.dtype == torch.bool else value.to(torch.float64).numpy()
    array = np.asarray(value)
    if array.dtype != bool and not np.issubdtype(array.dtype, np.number):
        raise ValueError(f"{name} must be numeric, got dtype {array.dtype}")
    return array if array.dtype == bool else array.astype(np.float64)


def _grid_image(grid_map: GridMap, map_w: int, map_h: int) -> Image.Image:
    """The occupancy grid as an RGB image of ``map_w x map_h`` pixels, row 0 at the top (largest y)."""
    occupancy = grid_map.occupancy
    occupancy = occupancy.cpu().numpy() if isinstance(occupancy, torch.Tensor) else np.asarray(occupancy)
    occupied = np.flipud(occupancy.astype(bool))[..., None]
    cells = np.where(occupied, OCCUPIED_COLOUR, FREE_COLOUR).astype(np.uint8)
    return Image.fromarray(cells, "RGB").resize((map_w, map_h), Image.Resampling.NEAREST)


def _ellipse_polygons(means: np.ndarray, covs: np.ndarray, to_pixels) -> list[np.ndarray]:
    """Pixel polygons ``[K, 2]`` of the 2-sigma ellipses of ``N`` positions (non-finite ones skipped)."""
    finite = np.isfinite(means).all(-1) & np.isfinite(covs).all((-1, -2))
    if not finite.any():
        return []
    means, covs = means[finite], covs[finite]
    covs = (covs + np.swapaxes(covs, -1, -2)) / 2
    values, vectors = np.linalg.eigh(covs)  # [N, 2], [N, 2, 2] (eigenvectors in the columns)
    radii = 2.0 * np.sqrt(np.clip(values, 0.0, None))
    angles = np.linspace(0.0, 2 * math.pi, _ELLIPSE_POINTS, endpoint=False)
    circle = np.stack((np.cos(angles), np.sin(angles)), -1)  # [K, 2]
    points = means[:, None, :] + np.einsum("nij,nj,kj->nki", vectors, radii, circle)
    return list(to_pixels(points))


def _robot_triangle(centre: np.ndarray, heading: float, size: int) -> np.ndarray:
    """Pixel vertices ``[3, 2]`` of an isosceles triangle around ``centre`` pointing along ``heading``."""
    length = max(6.0, size / 40)
    forward = np.array([math.cos(heading), -math.sin(heading)])  # image y points down
    normal = np.array([-forward[1], forward[0]])
    along = np.array([1.0, -0.6, -0.6])[:, None] * length
    across = np.array([0.0, 0.6, -0.6])[:, None] * length
    return centre + along * forward + across * normal
