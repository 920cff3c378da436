"""What both sides of the comparison share: the fixed policies and the per-step record (numpy only, so that
ttenv's venv and ours can both import it)."""

from __future__ import annotations

import json
import math

import numpy as np

LINEAR = [3.0, 2.0, 1.0, 0.0]
ANGULAR = [math.pi / 2, 0.0, -math.pi / 2]
NUM_ACTIONS = len(LINEAR) * len(ANGULAR)
# a = len(ANGULAR) * i_v + i_w, as both ttenv's action_map and aia's motion_primitives number them.
FIXED = {"stay": 3 * 3 + 1, "spin": 3 * 3 + 0, "straight": 3 * 0 + 1}
POLICIES = ("stay", "spin", "straight", "random")
# Per step t = 0 (after the reset) .. T, one row per episode.
STEP_KEYS = ("logdet", "logdet_feat", "observed", "dist_rt", "belief_err", "target_speed", "collisions",
             "robot_travel", "target_from_start")  # |robot - its start|, |target - the robot's start|
EPISODE_KEYS = ("init_rb", "init_bt", "crash_step")


def actions(policy: str, episodes: int, steps: int, seed: int) -> np.ndarray:
    """``[episodes, steps]`` action indices of a fixed policy (random: uniform over the 12 primitives)."""
    if policy == "random":
        return np.random.default_rng(seed).integers(0, NUM_ACTIONS, size=(episodes, steps))
    return np.full((episodes, steps), FIXED[policy])


def new_record(episodes: int, steps: int) -> dict[str, np.ndarray]:
    rec = {k: np.full((episodes, steps + 1), np.nan) for k in STEP_KEYS}
    rec.update({k: np.full(episodes, np.nan) for k in EPISODE_KEYS})
    return rec


def save(path: str, meta: dict, rec: dict[str, np.ndarray]) -> None:
    data = dict(meta, **{k: np.where(np.isfinite(v), v, None).tolist() for k, v in rec.items()})
    with open(path, "w") as f:
        json.dump(data, f)
