"""Drive the authors' ttenv (coco66/ttenv) with a fixed policy and write per-step statistics to JSON.

Run with ttenv's own venv, never ours (ttenv is not a dependency of aia)::

    git --git-dir=/work/.mirror/coco66+ttenv/repo/.git worktree add /tmp/ttenv HEAD
    python3 -m venv /tmp/ttenv_venv
    /tmp/ttenv_venv/bin/pip install gym==0.23.1 filterpy==2.0.0 numpy==1.26.4 scipy scikit-image PyYAML
    /tmp/ttenv_venv/bin/python scripts/ttenv_compare/run_ttenv.py --version 1 --policy stay --episodes 300 \
        --out /tmp/ttenv_compare/ttenv_v1_stay_empty.json

It builds ``TargetTrackingEnv{version}(num_targets=1, map_name=...)`` with its defaults (ttenv has no time
limit of its own: episodes stop after ``--steps``), and records, at the reset (t = 0) and after every step:
the log det of the updated belief covariance b_t|t (``logdet``, caught just before ttenv predicts) and of the
predicted one its features read (``logdet_feat``), whether the target was observed, the robot-target
distance, |belief mean - target| (of b_t|t), the target's speed and the robot's collision count so far; per
episode the initial robot-belief and belief-target distances (the sampled poses, before ttenv's update at
the reset) and the step at which ttenv raised (its UKF's Cholesky), if it did.

Two run-time shims, no edit of ttenv's files: ``yaml.load`` gets a default Loader (ttenv calls it without
one), and, unless ``--no-fast-map``, the map's ``in_bound`` and ``cell_to_se2`` are swapped for float
versions of the same arithmetic (bit-identical results; the ray scans of v1's targets call them ~12 000
times a step). ``--check-shim N`` runs N episodes with and without them and asserts identical records.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
import warnings

import numpy as np
import yaml

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from common import POLICIES, actions, new_record, save  # noqa: E402

_yaml_load = yaml.load


def _load(stream, Loader=yaml.SafeLoader, **kwargs):
    return _yaml_load(stream, Loader=Loader, **kwargs)


yaml.load = _load


def fast_map(grid) -> None:
    """Give ``grid`` (a ttenv GridMap) float versions of ``in_bound`` and ``cell_to_se2``: same results."""
    lo_x = float(grid.mapmin[0] + grid.margin2wall)
    hi_x = float(grid.mapmax[0] - grid.margin2wall)
    lo_y = float(grid.mapmin[1] + grid.margin2wall)
    hi_y = float(grid.mapmax[1] - grid.margin2wall)
    rx, ry = float(grid.mapres[0]), float(grid.mapres[1])
    mx, my = float(grid.mapmin[0]), float(grid.mapmin[1])

    def in_bound(pos):
        x, y = float(pos[0]), float(pos[1])
        return not (x < lo_x or x > hi_x or y < lo_y or y > hi_y)

    def cell_to_se2(cell):
        return np.array(((int(cell[0]) + 0.5) * rx + mx, (int(cell[1]) + 0.5) * ry + my))

    grid.in_bound, grid.cell_to_se2 = in_bound, cell_to_se2


def make(version: int, map_name: str, fast: bool):
    from ttenv import target_tracking

    env = getattr(target_tracking, f"TargetTrackingEnv{version}")(num_targets=1, map_name=map_name)
    if fast:
        fast_map(env.MAP)
    return env


def run(version: int, policy: str, map_name: str, episodes: int, steps: int, seed: int, fast: bool = True,
        log_every: int = 0) -> dict[str, np.ndarray]:
    np.random.seed(seed)  # ttenv draws from numpy's global stream
    env = make(version, map_name, fast)
    acts = actions(policy, episodes, steps, seed + 1)
    rec = new_record(episodes, steps)
    caught: dict = {}

    # Catch b_t|t (ttenv predicts right after its update), the observed flags and the sampled poses.
    def wrap_predict(b):
        original = b.predict

        def predict(*args, **kwargs):
            caught["post"] = (np.array(b.state, dtype=float), np.array(b.cov, dtype=float))
            return original(*args, **kwargs)
        b.predict = predict

    original_observe, original_pose = env.observe_and_update_belief, env.get_init_pose

    def observe():
        caught["observed"] = original_observe()
        return caught["observed"]

    def init_pose(**kwargs):
        caught["pose"] = original_pose(**kwargs)
        return caught["pose"]

    env.observe_and_update_belief, env.get_init_pose = observe, init_pose
    for b in env.belief_targets:  # built once in __init__ (reset() rebuilds them only when given const_q)
        wrap_predict(b)
    start = time.time()
    for ep in range(episodes):
        try:
            env.reset()
        except Exception as err:  # noqa: BLE001 (its UKF updates with the last episode's sigma points)
            rec["crash_step"][ep] = 0
            caught.setdefault("errors", {}).setdefault(f"{type(err).__name__} at reset", 0)
            caught["errors"][f"{type(err).__name__} at reset"] += 1
            continue
        pose = caught["pose"]
        robot, bel, tgt = (np.array(p, dtype=float)[:2] for p in
                           (pose["agent"], pose["belief_targets"][0], pose["targets"][0]))
        rec["init_rb"][ep], rec["init_bt"][ep] = np.linalg.norm(bel - robot), np.linalg.norm(tgt - bel)
        previous = np.array(env.targets[0].state[:2], dtype=float)
        caught["start"] = np.array(env.agent.state[:2], dtype=float)
        for t in range(steps + 1):
            if t > 0:
                try:
                    env.step(int(acts[ep, t - 1]))
                except Exception as err:  # noqa: BLE001 (ttenv's UKF: LinAlgError from its Cholesky)
                    rec["crash_step"][ep] = t
                    caught.setdefault("errors", {}).setdefault(type(err).__name__, 0)
                    caught["errors"][type(err).__name__] += 1
                    break
            _record(rec, env, caught, ep, t, version, previous)
            previous = np.array(env.targets[0].state[:2], dtype=float)
        if log_every and (ep + 1) % log_every == 0:
            print(f"  v{version} {policy} {map_name}: {ep + 1}/{episodes} episodes, {time.time() - start:.0f} s",
                  flush=True)
    rec["errors"] = caught.get("errors", {})
    return rec


def _record(rec, env, caught, ep, t, version, previous) -> None:
    robot, target = np.asarray(env.agent.state, dtype=float), np.asarray(env.targets[0].state, dtype=float)
    rec["observed"][ep, t] = float(caught["observed"][0])
    rec["dist_rt"][ep, t] = np.linalg.norm(target[:2] - robot[:2])
    if version == 1:
        rec["target_speed"][ep, t] = np.linalg.norm(target[2:4])
    elif t > 0:
        rec["target_speed"][ep, t] = np.linalg.norm(target[:2] - previous) / env.sampling_period
    rec["collisions"][ep, t] = env.num_collisions
    rec["robot_travel"][ep, t] = np.linalg.norm(robot[:2] - caught["start"])
    rec["target_from_start"][ep, t] = np.linalg.norm(target[:2] - caught["start"])
    rec["logdet_feat"][ep, t] = np.linalg.slogdet(env.belief_targets[0].cov)[1]
    if caught.get("post") is not None:
        mean, cov = caught["post"]
        rec["logdet"][ep, t] = np.linalg.slogdet(cov)[1]
        rec["belief_err"][ep, t] = np.linalg.norm(mean[:2] - target[:2])


def main() -> None:
    warnings.filterwarnings("ignore")
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--ttenv", default="/tmp/ttenv", help="folder holding the ttenv package (a worktree of it)")
    p.add_argument("--version", type=int, default=1, choices=(1, 2, 3))
    p.add_argument("--policy", default="stay", choices=POLICIES)
    p.add_argument("--map", default="empty")
    p.add_argument("--episodes", type=int, default=300)
    p.add_argument("--steps", type=int, default=100)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--out", required=False)
    p.add_argument("--no-fast-map", action="store_true")
    p.add_argument("--check-shim", type=int, default=0, metavar="N")
    args = p.parse_args()
    sys.path.insert(0, args.ttenv)
    if args.check_shim:
        a = run(args.version, args.policy, args.map, args.check_shim, args.steps, args.seed, fast=True)
        b = run(args.version, args.policy, args.map, args.check_shim, args.steps, args.seed, fast=False)
        for k in a:
            if k != "errors":
                np.testing.assert_array_equal(a[k], b[k], err_msg=k)
        print(f"shim check: {args.check_shim} episodes identical with and without the fast map")
        return
    start = time.time()
    rec = run(args.version, args.policy, args.map, args.episodes, args.steps, args.seed, not args.no_fast_map,
              log_every=max(1, args.episodes // 5))
    errors = rec.pop("errors")
    meta = dict(side="ttenv", version=args.version, policy=args.policy, map=args.map, episodes=args.episodes,
                steps=args.steps, seed=args.seed, errors=errors, seconds=round(time.time() - start, 1))
    save(args.out, meta, rec)
    print(f"wrote {args.out}: {meta}")


if __name__ == "__main__":
    main()
