"""Drive aia's ttenv presets with a fixed policy and write the same per-step statistics as run_ttenv.py.

Run with our venv::

    .venv/bin/python scripts/ttenv_compare/run_aia.py --setting ttenv_v1 --policy stay --episodes 300 \
        --out /tmp/ttenv_compare/aia_v1_stay_empty.json

All episodes run as one batch of worlds (``make_env(setting, batch_size=episodes, seed=...,
transforms=False)``, T = ``max_steps`` = 100). The records are those of run_ttenv.py: aia's state after a
step is the updated belief b_t|t, so ``logdet`` and ``logdet_feat`` are the same number here; aia does not
observe at the reset, so ``observed`` at t = 0 is 0 and the belief at t = 0 is the sampled one.
"""

from __future__ import annotations

import argparse
import os
import sys
import time

import numpy as np
import torch

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from common import POLICIES, actions, new_record, save  # noqa: E402

from aia.envs import make_env  # noqa: E402


def run(setting: str, policy: str, map_name: str, episodes: int, steps: int, seed: int,
        extra: tuple[str, ...] = ()) -> dict[str, np.ndarray]:
    overrides = [f"max_steps={steps}", *([] if map_name == "empty" else [f"map={map_name}"]), *extra]
    env = make_env(setting, batch_size=episodes, seed=seed, overrides=overrides, transforms=False)
    velocity_state = env.targets.dim == 4  # the double integrator keeps [x, y, vx, vy]
    acts = torch.as_tensor(actions(policy, episodes, steps, seed + 1))
    rec = new_record(episodes, steps)
    td = env.reset()
    rec["init_rb"][:] = _norm(td["belief_mean"][:, 0, :2] - td["robot_pose"][:, :2])
    rec["init_bt"][:] = _norm(td["target_state"][:, 0, :2] - td["belief_mean"][:, 0, :2])
    collisions = torch.zeros(episodes)
    previous = td["target_state"][:, 0, :2].clone()
    start = td["robot_pose"][:, :2].clone()
    for t in range(steps + 1):
        if t > 0:
            td["action"] = acts[:, t - 1]
            td = env.step(td)["next"]
            collisions += td["collision"].float()
        target = td["target_state"][:, 0]
        logdet = td["logdet_cov"][:, 0].double().numpy()
        rec["logdet"][:, t] = rec["logdet_feat"][:, t] = logdet
        rec["observed"][:, t] = td["observed"][:, 0].double().numpy()
        rec["dist_rt"][:, t] = _norm(target[:, :2] - td["robot_pose"][:, :2])
        rec["belief_err"][:, t] = _norm(td["belief_mean"][:, 0, :2] - target[:, :2])
        if velocity_state:
            rec["target_speed"][:, t] = _norm(target[:, 2:4])
        elif t > 0:
            rec["target_speed"][:, t] = _norm(target[:, :2] - previous) / env.config.dt
        rec["collisions"][:, t] = collisions.double().numpy()
        rec["robot_travel"][:, t] = _norm(td["robot_pose"][:, :2] - start)
        rec["target_from_start"][:, t] = _norm(target[:, :2] - start)
        previous = target[:, :2].clone()
    return rec


def _norm(x: torch.Tensor) -> np.ndarray:
    return torch.linalg.vector_norm(x.double(), dim=-1).numpy()


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--setting", default="ttenv_v1", help="ttenv_v1, ttenv_v2 or ttenv_v3")
    p.add_argument("--policy", default="stay", choices=POLICIES)
    p.add_argument("--map", default="empty", help="aia's map name (ttenv's obstacles02 is our obstacles4)")
    p.add_argument("--episodes", type=int, default=300)
    p.add_argument("--steps", type=int, default=100)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--override", action="append", default=[], help="an env override, e.g. belief.control=random")
    p.add_argument("--out", required=True)
    args = p.parse_args()
    torch.set_num_threads(1)
    start = time.time()
    with torch.no_grad():
        rec = run(args.setting, args.policy, args.map, args.episodes, args.steps, args.seed, tuple(args.override))
    meta = dict(side="aia", version=int(args.setting[-1]), setting=args.setting, policy=args.policy, map=args.map,
                episodes=args.episodes, steps=args.steps, seed=args.seed, overrides=args.override, errors={},
                seconds=round(time.time() - start, 1))
    save(args.out, meta, rec)
    print(f"wrote {args.out}: {meta}")


if __name__ == "__main__":
    main()
