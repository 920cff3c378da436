"""``aia-rollout``: score scripted policies (random, belief pursuit) on a batch of tracking worlds.

Runs one episode in each of ``num_worlds`` worlds per policy, prints the score (SPEC 9), the shaped
return and the belief error (mean distance from the belief means to the true targets), and writes
``rollout.json`` in the Hydra run directory. ``aia-rollout --help`` lists the config. The env and the policies
(torch) are imported inside the functions that run them, so that ``--help`` and a refused config answer first.
"""

from __future__ import annotations

import time
from pathlib import Path

from hydra.core.hydra_config import HydraConfig
from omegaconf import DictConfig, OmegaConf
from tqdm import tqdm

from aia.apps.hydra_app import hydra_app
from aia.apps.output_files import write_json
from aia.config.schemas import ROLLOUT_POLICIES
from aia.config.validation import validate_rollout_config
from aia.envs.config import to_tracking_config


def make_policy(name: str, env, seed: int, standoff: float):
    """A scripted policy by name."""
    from aia.policies import BeliefPursuitPolicy, RandomPolicy

    if name == "random":
        return RandomPolicy(env.action_spec.n, seed=seed, device=env.device)
    if name == "pursuit":
        return BeliefPursuitPolicy(env.base_env, standoff=standoff)
    raise ValueError(f"unknown policy {name!r}: expected one of {list(ROLLOUT_POLICIES)}")


def score_policy(cfg: DictConfig, name: str) -> dict:
    """One batched episode of policy ``name``; summary statistics of its scores and returns."""
    from aia.envs import make_env
    from aia.evaluation import belief_errors, episode_scores, run_episodes

    env = make_env(to_tracking_config(cfg.env), batch_size=cfg.num_worlds, device=cfg.device, seed=cfg.seed,
                   compile=cfg.compile)
    policy = make_policy(name, env, cfg.seed, cfg.pursuit_standoff)
    steps = env.base_env.config.max_steps
    start = time.perf_counter()
    with tqdm(total=steps * cfg.num_worlds, desc=f"{name:>8}", unit="frame", unit_scale=True, leave=False) as bar:

        def act(td):
            bar.update(cfg.num_worlds)
            return policy(td)

        rollout = run_episodes(env, act)
    seconds = time.perf_counter() - start
    scores = episode_scores(rollout)
    returns = rollout.get(("next", "reward")).sum((1, 2))
    return {
        "policy": name,
        "episodes": cfg.num_worlds,
        "score_mean": scores.mean().item(),
        "score_std": scores.std(correction=0).item(),
        "return_mean": returns.mean().item(),
        "belief_error": belief_errors(rollout).mean().item(),
        "observed_fraction": rollout.get(("next", "observed")).float().mean().item(),
        "collision_fraction": rollout.get(("next", "collision")).float().mean().item(),
        "frames_per_s": steps * cfg.num_worlds / seconds,
    }


@hydra_app("aia-rollout", config_name="rollout")  # invalid input: one line on stderr, exit 2
def main(cfg: DictConfig) -> None:
    """Entry point of ``aia-rollout`` (invalid input: one line on stderr, exit status 2)."""
    validate_rollout_config(cfg)
    out_dir = Path(HydraConfig.get().runtime.output_dir)
    choice = HydraConfig.get().runtime.choices.get("env")
    print(f"setting {choice}: map {cfg.env.map}, {cfg.env.num_targets} target(s), {cfg.env.max_steps} steps, "
          f"{cfg.num_worlds} worlds, seed {cfg.seed}")
    results = [score_policy(cfg, name) for name in cfg.policies]
    print(f"{'policy':<10}{'score mean':>12}{'std':>9}{'return':>10}{'error m':>9}{'observed':>10}{'frames/s':>11}")
    for r in results:
        print(f"{r['policy']:<10}{r['score_mean']:>12.1f}{r['score_std']:>9.1f}{r['return_mean']:>10.1f}"
              f"{r['belief_error']:>9.2f}{r['observed_fraction']:>10.2f}{r['frames_per_s']:>11,.0f}")
    log = out_dir / "rollout.json"
    write_json(log, {"config": OmegaConf.to_container(cfg, resolve=True), "setting": choice, "results": results})
    print(f"log written to {log}")


if __name__ == "__main__":
    main()
