"""``aia-eval``: score a policy saved by ``aia-train`` on fresh episodes (greedy or semi-greedy).

Rebuilds the env and the network from the config stored in the checkpoint, runs ``episodes`` episodes as
one batched rollout at ``epsilon`` and prints the score mean and std (SPEC 9); writes ``eval.json``.
"""

from __future__ import annotations

import json
from pathlib import Path

import hydra
import torch
from hydra.core.hydra_config import HydraConfig
from omegaconf import DictConfig, OmegaConf
from tensordict.nn import TensorDictSequential

from aia.envs import make_env
from aia.envs.factory import to_tracking_config
from aia.evaluation import episode_scores, run_episodes
from aia.modules import EpsilonGreedy
from aia.train import make_actor


def load_checkpoint(path: str | Path) -> dict:
    """A checkpoint written by ``aia-train``, or a ValueError naming the path and what is wrong."""
    path = Path(path)
    if not path.is_file():
        raise ValueError(f"checkpoint={str(path)!r} does not exist")
    try:
        checkpoint = torch.load(path, weights_only=False, map_location="cpu")
    except Exception as err:  # torch raises several types for a file that is not a checkpoint
        raise ValueError(f"checkpoint={str(path)!r} is not a readable torch checkpoint ({err})") from None
    if not isinstance(checkpoint, dict) or not {"config", "actor"} <= checkpoint.keys():
        raise ValueError(f"checkpoint={str(path)!r} was not written by aia-train (no 'config'/'actor' entries)")
    return checkpoint


def evaluate_checkpoint(path: str | Path, episodes: int, epsilon: float, seed: int, device: str) -> dict:
    """Scores of the checkpoint's policy on ``episodes`` fresh episodes."""
    if episodes < 1:
        raise ValueError(f"episodes={episodes} must be >= 1")
    if not 0.0 <= epsilon <= 1.0:
        raise ValueError(f"epsilon={epsilon} must lie in [0, 1]")
    checkpoint = load_checkpoint(path)
    cfg = OmegaConf.create(checkpoint["config"])
    cfg.device = device
    env = make_env(to_tracking_config(cfg.env), batch_size=episodes, device=device, seed=seed)
    actor = make_actor(cfg, env)
    actor.load_state_dict(checkpoint["actor"])
    policy = TensorDictSequential(actor, EpsilonGreedy(env.action_spec.n, epsilon, epsilon, 1, seed=seed,
                                                       device=device))
    scores = episode_scores(run_episodes(env, policy))
    return {
        "checkpoint": str(path),
        "algo": cfg.algo.name,
        "frames_trained": checkpoint["state"]["frames"],
        "episodes": episodes,
        "epsilon": epsilon,
        "score_mean": scores.mean().item(),
        "score_std": scores.std(correction=0).item(),
        "scores": scores.tolist(),
    }


@hydra.main(config_path="pkg://aia.conf", config_name="eval", version_base="1.3")
def main(cfg: DictConfig) -> None:
    """Entry point of ``aia-eval``."""
    result = evaluate_checkpoint(cfg.checkpoint, cfg.episodes, cfg.epsilon, cfg.seed, cfg.device)
    print(f"{result['algo']} after {result['frames_trained']} frames: score {result['score_mean']:.1f} "
          f"+- {result['score_std']:.1f} over {cfg.episodes} episodes (epsilon {cfg.epsilon})")
    out = Path(HydraConfig.get().runtime.output_dir) / "eval.json"
    out.write_text(json.dumps(result, indent=2))
    print(f"log written to {out}")


if __name__ == "__main__":
    main()
