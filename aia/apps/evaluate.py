"""``aia-eval``: score a policy on fresh episodes: one saved by ``aia-train`` or the ARVI planner.

``policy=checkpoint`` rebuilds the env and the network from the config stored in the checkpoint and acts
at ``epsilon``; ``policy=arvi`` plans with :class:`~aia.planners.ARVIPolicy` (``planner.*``) in the setting
``env``. Either way ``episodes`` episodes run as one batched rollout through the same evaluation path; the
app prints the score mean and std (SPEC 9) and writes ``eval.json`` and ``run.mcap`` (the scores, the
config, and world 0's episode as Foxglove scenes: ``aia-log render`` draws it as in the paper's Fig. 3).
"""

from __future__ import annotations

import json
import math
from dataclasses import asdict
from pathlib import Path

import torch
from hydra.core.hydra_config import HydraConfig
from omegaconf import DictConfig, OmegaConf
from tensordict.nn import TensorDictSequential
from torchrl.envs import StepCounter

from aia.apps.hydra_app import hydra_app
from aia.envs import make_env
from aia.envs.factory import to_tracking_config
from aia.evaluation import evaluation_summary, log_score_summary, run_episodes
from aia.logging import MCAPLogger, SceneRecorder
from aia.modules import EpsilonGreedy
from aia.planners import ARVIPolicy, to_arvi_config
from aia.training import make_actor
from aia.validation import validate_eval_config

POLICIES = ("checkpoint", "arvi")


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


def evaluate_checkpoint(path: str | Path, episodes: int, epsilon: float, seed: int, device: str,
                        logger: MCAPLogger | None = None) -> dict:
    """Scores of the checkpoint's policy on ``episodes`` fresh episodes (logged to ``logger`` if given)."""
    _check_episodes(episodes)
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
    frames = checkpoint["state"]["frames"]
    if logger is not None:
        logger.log_hparams(cfg)  # the trained policy's config (env, algo, ...)
    result = {"checkpoint": str(path), "algo": cfg.algo.name, "frames_trained": frames, "episodes": episodes,
              "epsilon": epsilon}
    return result | score_episodes(env, policy, logger, frames)


def evaluate_planner(env_cfg: DictConfig, planner_cfg: DictConfig, episodes: int, seed: int, device: str,
                     logger: MCAPLogger | None = None) -> dict:
    """Scores of the ARVI planner on ``episodes`` fresh episodes of the setting ``env_cfg`` (all worlds are
    planned together, so a wall-clock budget is shared by the batch; logged to ``logger`` if given)."""
    _check_episodes(episodes)
    planner = to_arvi_config(planner_cfg)
    env = make_env(to_tracking_config(env_cfg), batch_size=episodes, device=device, seed=seed)
    env.append_transform(StepCounter())  # ARVIPolicy re-plans on the episode's step count
    if logger is not None:
        logger.log_hparams(OmegaConf.create({"policy": "arvi", "env": env_cfg, "planner": planner_cfg,
                                             "episodes": episodes, "seed": seed}))
    result = score_episodes(env, ARVIPolicy(env, planner), logger)
    parameters = {k: v if not isinstance(v, float) or math.isfinite(v) else str(v) for k, v in asdict(planner).items()}
    return {"policy": "arvi", "planner": parameters, "episodes": episodes} | result


def score_episodes(env, policy, logger: MCAPLogger | None, frame: int = 0) -> dict:
    """One episode per world of ``env`` under ``policy``: the scores and their mean and std. With a
    ``logger``, world 0's episode is recorded as scenes and every score goes to ``eval/episode_score`` (step:
    the world's index), their mean and std to ``eval/score`` and ``eval/score_std`` (step: ``frame``)."""
    if logger is not None:
        recorder = SceneRecorder(logger)
        env.append_transform(recorder)
        recorder.record(episode=0, frame=frame)
    summary = evaluation_summary(run_episodes(env, policy))
    if logger is not None:
        for world, score in enumerate(summary["scores"]):
            logger.log_scalar("eval/episode_score", score, step=world)
        log_score_summary(logger, summary, frame)
    return summary


def _check_episodes(episodes: int) -> None:
    if episodes < 1:
        raise ValueError(f"episodes={episodes} must be >= 1")


@hydra_app("aia-eval", config_name="eval")  # invalid input: one line on stderr, exit 2
def main(cfg: DictConfig) -> None:
    """Entry point of ``aia-eval``."""
    validate_eval_config(cfg, HydraConfig.get().overrides.task)
    if cfg.threads:
        torch.set_num_threads(cfg.threads)
    if cfg.policy not in POLICIES:
        raise ValueError(f"policy={cfg.policy!r} is not one of {list(POLICIES)}")
    out_dir = Path(HydraConfig.get().runtime.output_dir)
    logger = MCAPLogger(f"eval-{cfg.policy}-seed{cfg.seed}", out_dir, run_metadata={"seed": cfg.seed,
                                                                                     "policy": cfg.policy})
    try:
        if cfg.policy == "checkpoint":
            result = evaluate_checkpoint(cfg.checkpoint, cfg.episodes, cfg.epsilon, cfg.seed, cfg.device, logger)
            what = f"{result['algo']} after {result['frames_trained']} frames"
            how = f"epsilon {cfg.epsilon}"
        else:
            result = evaluate_planner(cfg.env, cfg.planner, cfg.episodes, cfg.seed, cfg.device, logger)
            what, how = "arvi", f"horizon {cfg.planner.horizon}, budget {_budget(cfg.planner)}"
    finally:
        logger.close()
    print(f"{what}: score {result['score_mean']:.1f} +- {result['score_std']:.1f} over {cfg.episodes} episodes, "
          f"belief error {result['belief_error']:.1f} m ({how})")
    out = out_dir / "eval.json"
    out.write_text(json.dumps(result, indent=2))
    print(f"log written to {out} and {logger.path} (world 0's episode recorded: aia-log render {logger.path})")


def _budget(planner: DictConfig) -> str:
    budgets = {"time_budget": "{} s", "max_passes": "{} passes", "max_nodes": "{} nodes per world"}
    return ", ".join(form.format(planner[name]) for name, form in budgets.items() if planner[name] is not None)


if __name__ == "__main__":
    main()
