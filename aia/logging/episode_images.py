"""A recorded episode of a run log as images: every step (a GIF's frames) or a strip of evenly spaced steps (the
paper's Fig. 3), what ``aia-log render`` writes."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from aia.logging.reader import RunLog

if TYPE_CHECKING:
    from PIL.Image import Image


def action_view(points: np.ndarray, margin: float, limit: tuple[float, float]
                ) -> tuple[float, float, float, float] | None:
    """The square around ``points [K, 2]`` padded by ``margin`` metres, or None when it would not be smaller
    than the map (``limit``: its width and height)."""
    points = points[np.isfinite(points).all(-1)]
    if points.size == 0:
        return None
    low, high = points.min(0) - margin, points.max(0) + margin
    side = float((high - low).max())
    if side >= max(limit):
        return None
    centre = (low + high) / 2
    return (centre[0] - side / 2, centre[1] - side / 2, centre[0] + side / 2, centre[1] + side / 2)


def episode_images(run: RunLog, episode: int | str, size: int, frames: int | None = None, zoom: bool = True
                   ) -> list[Image]:
    """Recorded ``episode`` of ``run`` (an index, ``"first"`` or ``"last"``) as ``size`` x ``size`` images:
    every step, or ``frames`` evenly spaced steps, each with the earlier robot and target positions as trails,
    zoomed on the episode's action (the square around every robot, target and belief position, padded by the
    sensor range) when ``zoom`` and that square is smaller than the map."""
    from PIL import Image

    from aia.envs.render import render_frame

    info, steps = run.episode(episode)
    if not steps:
        raise ValueError(f"{run.path}: recorded episode {info.episode} has no frames")
    shown = range(len(steps))
    if frames is not None:
        shown = np.unique(np.linspace(0, len(steps) - 1, frames).round().astype(int)).tolist()
    robot_path = np.stack([step.robot_pose[:2] for step in steps])
    target_paths = np.stack([step.targets for step in steps])
    view = None
    if zoom:
        view = action_view(np.concatenate([robot_path, target_paths.reshape(-1, 2),
                                           np.concatenate([step.belief_mean for step in steps])]),
                           margin=info.sensor_range, limit=(info.grid_map.width, info.grid_map.height))

    def draw(t: int) -> np.ndarray:
        step = steps[t]
        return render_frame(info.grid_map, step.robot_pose, step.targets, step.belief_mean, step.belief_cov,
                            info.sensor_range, info.fov_deg, size=size, observed=step.observed,
                            robot_path=robot_path[:t], target_paths=target_paths[:t], view=view,
                            particles=step.particles)

    return [Image.fromarray(draw(t)) for t in shown]


def image_strip(images: list[Image]) -> Image:
    """``images`` (squares of one size) side by side, each framed in the renderer's border colour."""
    from PIL import Image, ImageDraw

    from aia.envs.render import BORDER_COLOUR

    size = images[0].size[0]
    strip = Image.new("RGB", (size * len(images), size))
    outline = ImageDraw.Draw(strip)
    for i, image in enumerate(images):
        strip.paste(image, (i * size, 0))
        outline.rectangle([i * size, 0, (i + 1) * size - 1, size - 1], outline=BORDER_COLOUR)
    return strip
