"""State-by-state check of v1's obstacle rule: ttenv's ``collision_control`` and ``obstacle_detour_maneuver``
against aia's ``DoubleIntegratorTargets._detour`` on the same target states and the same random draws::

    /tmp/ttenv_venv/bin/python scripts/ttenv_compare/detour_check.py ttenv /tmp/ttenv_compare/detour.json
    .venv/bin/python scripts/ttenv_compare/detour_check.py aia /tmp/ttenv_compare/detour.json

The first writes random target states on the empty map (half within 8 m of a wall), the draws
collision_control takes (N(0, 1), then U(0, 1)) and ttenv's results; the second recomputes them with aia
and prints the largest differences. (The nearest obstacle differs by design: ttenv's is the first
out-of-bounds cell centre along rays 0.05 rad apart, aia's the exact margin-shrunk wall.)
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np


def ttenv_side(path: str, count: int = 300) -> None:
    import run_ttenv  # noqa: F401  (its yaml shim)
    sys.path.insert(0, "/tmp/ttenv")
    env = run_ttenv.make(1, "empty", fast=True)
    target = env.targets[0]
    rng = np.random.default_rng(5)
    rows = []
    for k in range(count):
        near = k % 2 == 0
        xy = rng.uniform(1.5, 9.0, 2) if near else rng.uniform(1.5, 99.5, 2)
        if near:  # by a random wall
            xy = np.where(rng.random(2) < 0.5, xy, 101.0 - xy) if rng.random() < 0.5 else \
                np.array([xy[0] if rng.random() < 0.5 else 101.0 - xy[0], rng.uniform(1.5, 99.5)])
        speed, angle = rng.uniform(0.0, 3.5), rng.uniform(-np.pi, np.pi)
        state = np.array([xy[0], xy[1], speed * np.cos(angle), speed * np.sin(angle)])
        target.state = state.copy()
        np.random.seed(k)
        after = target.collision_control()
        np.random.seed(k)
        normal, uniform = np.random.normal(0.0, 1.0), np.random.random()
        push = target.obstacle_detour_maneuver(r_margin=3.5 * 0.5 * 2)
        odom = [state[0], state[1], np.arctan2(state[3], state[2])]
        obstacle = target.obs_check_func(odom)
        rows.append(dict(state=state.tolist(), normal=normal, uniform=uniform, after=after[2:].tolist(),
                         push=list(push), obstacle=list(obstacle)))
    Path(path).write_text(json.dumps(rows))
    print(f"wrote {count} states to {path}")


def aia_side(path: str) -> None:
    import torch
    from scipy.stats import norm

    from aia.envs import make_env

    rows = json.loads(Path(path).read_text())
    env = make_env("ttenv_v1", batch_size=1, transforms=False, overrides=["dtype=float64"])
    state = torch.tensor([r["state"] for r in rows], dtype=torch.float64)[:, None]
    normals = torch.tensor([[r["normal"], norm.ppf(r["uniform"])] for r in rows], dtype=torch.float64)[:, None]
    after, push = (x[:, 0].numpy() for x in env.targets._detour(state, normals))
    distance, direction = (x[:, 0].numpy() for x in env.geometry.nearest_obstacle(state[..., :2]))
    ref_after, ref_push = np.array([r["after"] for r in rows]), np.array([r["push"] for r in rows])
    ref_obstacle = np.array([r["obstacle"] for r in rows])
    heading = np.arctan2(state[:, 0, 3].numpy(), state[:, 0, 2].numpy())
    bearing = (direction - heading + np.pi) % (2 * np.pi) - np.pi
    d_bearing = (bearing - ref_obstacle[:, 1] + np.pi) % (2 * np.pi) - np.pi
    print(f"{len(rows)} states; nearest obstacle: distance aia - ttenv in "
          f"[{(distance - ref_obstacle[:, 0]).min():.3f}, {(distance - ref_obstacle[:, 0]).max():.3f}] m, "
          f"bearing |diff| max {np.abs(d_bearing).max():.3f} rad")
    same_side = (bearing >= 0) == (ref_obstacle[:, 1] >= 0)
    print(f"the obstacle is on the other side of the heading in {int((~same_side).sum())} states (left out below)")
    for name, ours, ref in (("velocity after a collision", after, ref_after), ("detour push", push, ref_push)):
        ours, ref = ours[same_side], ref[same_side]
        diff = np.linalg.norm(ours - ref, axis=-1)
        worst = int(diff.argmax())
        print(f"{name}: |aia - ttenv| median {np.median(diff):.2e}, max {diff.max():.2e} (state {worst}: "
              f"aia {np.round(ours[worst], 4).tolist()}, ttenv {np.round(ref[worst], 4).tolist()}, "
              f"|ttenv| mean {np.linalg.norm(ref, axis=-1).mean():.3f})")
    # The formulas alone: aia's rule fed ttenv's nearest obstacle (its ray-scan distance and bearing).
    given = (torch.tensor(ref_obstacle[:, :1]), torch.tensor(ref_obstacle[:, 1:] + heading[:, None]))
    env.targets.geometry.nearest_obstacle = lambda xy: given
    after, push = (x[:, 0].numpy() for x in env.targets._detour(state, normals))
    print("with ttenv's nearest obstacle: max |aia - ttenv| "
          f"{np.abs(after - ref_after).max():.1e} (after a collision), {np.abs(push - ref_push).max():.1e} (push)")


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("side", choices=("ttenv", "aia"), help="ttenv: write the states and ttenv's results; "
                        "aia: recompute them and print the differences")
    parser.add_argument("path", help="the JSON file of the states and ttenv's results")
    args = parser.parse_args()
    sys.path.insert(0, __file__.rsplit("/", 1)[0])
    {"ttenv": ttenv_side, "aia": aia_side}[args.side](args.path)
