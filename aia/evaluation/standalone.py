"""Policies scored outside the training loop, on fresh episodes: a checkpoint's network (``aia-eval
policy=checkpoint``), the ARVI planner and belief pursuit (``aia-eval``, a sweep's seeds in one rollout), and the
scripted baselines of ``aia-rollout``. torch, TorchRL and the policies load inside the functions: the apps import
this module before their config is valid."""

from __future__ import annotations

import math
import time
from collections.abc import Sequence
from dataclasses import asdict
from pathlib import Path
from typing import TYPE_CHECKING

from omegaconf import DictConfig, OmegaConf
from tqdm import tqdm

from aia.config.schemas import ROLLOUT_POLICIES
from aia.envs.config import to_tracking_config
from aia.evaluation.checkpoints import check_layout, load_checkpoint
from aia.planners import to_arvi_config

if TYPE_CHECKING:
    from aia.logging import MCAPLogger


def evaluate_checkpoint(path: str | Path, episodes: int, epsilon: float, seed: int, device: str,
                        logger: MCAPLogger | None = None, setting: DictConfig | None = None) -> dict:
    """Scores of the checkpoint's policy on ``episodes`` fresh episodes (logged to ``logger`` if given), in
    ``setting`` (an env config: :func:`~aia.evaluation.checkpoints.check_setting`) or, without one, in the
    checkpoint's own."""
    from tensordict.nn import TensorDictSequential

    from aia.envs import make_env
    from aia.modules import EpsilonGreedy
    from aia.training import make_actor

    check_episodes(episodes)
    if not 0.0 <= epsilon <= 1.0:
        raise ValueError(f"epsilon={epsilon} must lie in [0, 1]")
    checkpoint = load_checkpoint(path)
    cfg = OmegaConf.create(checkpoint["config"])
    cfg.device = device
    trained = cfg.env
    if setting is not None:
        cfg.env = setting  # the logged config names the setting its episodes ran in
    env = make_env(to_tracking_config(cfg.env), batch_size=episodes, device=device, seed=seed)
    if setting is not None:
        check_layout(path, setting, trained)
    actor = make_actor(cfg, env)
    actor.load_state_dict(checkpoint["actor"])
    policy = TensorDictSequential(actor, EpsilonGreedy(env.action_spec.n, epsilon, epsilon, 1, seed=seed,
                                                       device=device))
    frames = checkpoint["state"]["frames"]
    if logger is not None:
        # the trained policy's config (algo, ...; env: the setting its episodes ran in) and, as trained_env, the
        # setting it was trained in, every key filled (a key added after the checkpoint: its default):
        # evaluations group by where their policies learned (aia-log --group-by trained_env.map)
        logger.log_hparams(OmegaConf.merge(cfg, {"trained_env": OmegaConf.structured(to_tracking_config(trained))}))
    result = {"checkpoint": str(path), "algo": cfg.algo.name, "frames_trained": frames, "episodes": episodes,
              "epsilon": epsilon}
    return result | score_episodes(env, policy, [logger], frames)[0]


def evaluate_planner(env_cfg: DictConfig, planner_cfg: DictConfig, episodes: int, seed: int, device: str,
                     logger: MCAPLogger | None = None) -> dict:
    """Scores of the ARVI planner on ``episodes`` fresh episodes of the setting ``env_cfg`` (all worlds are
    planned together, so a wall-clock budget is shared by the batch; logged to ``logger`` if given)."""
    return evaluate_scripted_seeds("arvi", env_cfg, episodes, [seed], device, [logger], planner_cfg=planner_cfg)[0]


def evaluate_scripted_seeds(policy: str, env_cfg: DictConfig, episodes: int, seeds: Sequence[int], device: str,
                            loggers: Sequence[MCAPLogger | None] | None = None, planner_cfg: DictConfig | None = None,
                            standoff: float = 0.5) -> list[dict]:
    """Scores of a policy that needs no training, ``arvi`` (planned with ``planner_cfg``) or ``pursuit`` (the
    belief-pursuit heuristic at ``standoff``), on ``episodes`` fresh episodes of ``env_cfg`` for each of
    ``seeds`` (logged to ``loggers[k]``), all in one rollout: seed ``k``'s worlds replay the episodes of an env
    seeded with it (for ARVI planned as budget group ``k``). Each result equals the seed's own call's (ARVI:
    under a node or pass budget; a wall-clock budget is shared by all worlds)."""
    import torch
    from torchrl.envs import StepCounter

    from aia.envs import make_env
    from aia.planners import ARVIPolicy

    check_episodes(episodes)
    loggers = [None] * len(seeds) if loggers is None else list(loggers)
    env = make_env(to_tracking_config(env_cfg), batch_size=episodes * len(seeds), device=device, seed=seeds[0])
    env.base_env.replay_streams(torch.tensor(seeds).repeat_interleave(episodes),
                                torch.arange(episodes).repeat(len(seeds)),
                                torch.zeros(episodes * len(seeds), dtype=torch.long))
    if policy == "arvi":
        planner = to_arvi_config(planner_cfg)
        env.append_transform(StepCounter())  # ARVIPolicy re-plans on the episode's step count
        actor = ARVIPolicy(env, planner, groups=torch.arange(len(seeds)).repeat_interleave(episodes))
        parameters = {k: v if not isinstance(v, float) or math.isfinite(v) else str(v)
                      for k, v in asdict(planner).items()}
        config, extra = {"planner": planner_cfg}, {"planner": parameters}
    else:
        actor = scripted_policy("pursuit", env, seeds[0], standoff)
        config = extra = {"pursuit_standoff": standoff}
    for seed, logger in zip(seeds, loggers, strict=True):
        if logger is not None:
            logger.log_hparams(OmegaConf.create({"policy": policy, "env": env_cfg, **config, "episodes": episodes,
                                                 "seed": seed}))
    return [{"policy": policy, **extra, "episodes": episodes} | result
            for result in score_episodes(env, actor, loggers)]


def score_episodes(env, policy, loggers: Sequence[MCAPLogger | None], frame: int = 0) -> list[dict]:
    """One episode per world of ``env`` under ``policy``, the worlds split into ``len(loggers)`` equal
    consecutive blocks (one per run): each block's scores and their mean and std. With a logger, its
    block's first episode is recorded as scenes and its scores go to ``eval/episode_score`` (step: the
    world's index in the block), their mean and std to ``eval/score`` and ``eval/score_std`` (step: ``frame``)."""
    from aia.evaluation.rollouts import run_episodes
    from aia.evaluation.scores import evaluation_summary, log_score_summary
    from aia.logging import SceneRecorder

    size = env.batch_size[0] // len(loggers)
    for block, logger in enumerate(loggers):
        if logger is not None:
            recorder = SceneRecorder(logger, world=block * size)
            env.append_transform(recorder)
            recorder.record(episode=0, frame=frame)
    rollout = run_episodes(env, policy)
    summaries = []
    for block, logger in enumerate(loggers):
        summary = evaluation_summary(rollout[block * size:(block + 1) * size])
        if logger is not None:
            for world, score in enumerate(summary["scores"]):
                logger.log_scalar("eval/episode_score", score, step=world)
            log_score_summary(logger, summary, frame)
        summaries.append(summary)
    return summaries


def check_episodes(episodes: int) -> None:
    """A ValueError naming ``episodes`` unless it is at least 1."""
    if episodes < 1:
        raise ValueError(f"episodes={episodes} must be >= 1")


def scripted_policy(name: str, env, seed: int, standoff: float):
    """A policy that needs neither training nor planning, by name: ``random`` (uniform actions from ``seed``'s
    stream) or ``pursuit`` (the belief-pursuit heuristic at ``standoff`` of the sensor range)."""
    from aia.policies import BeliefPursuitPolicy, RandomPolicy

    if name == "random":
        return RandomPolicy(env.action_spec.n, seed=seed, device=env.device)
    if name == "pursuit":
        return BeliefPursuitPolicy(env.base_env, standoff=standoff)
    raise ValueError(f"unknown policy {name!r}: expected one of {list(ROLLOUT_POLICIES)}")


def score_scripted(cfg: DictConfig, name: str) -> dict:
    """``aia-rollout``'s score of scripted policy ``name`` (:func:`scripted_policy`): one episode in each of
    ``cfg.num_worlds`` worlds of ``cfg.env``, with a progress bar; the scores' mean and std, the shaped return,
    the belief error, the fractions of steps observed and in collision, and the frames per second."""
    from aia.envs import make_env
    from aia.evaluation.rollouts import run_episodes
    from aia.evaluation.scores import evaluation_summary

    env = make_env(to_tracking_config(cfg.env), batch_size=cfg.num_worlds, device=cfg.device, seed=cfg.seed,
                   compile=cfg.compile)
    policy = scripted_policy(name, env, cfg.seed, cfg.pursuit_standoff)
    steps = env.base_env.config.max_steps
    start = time.perf_counter()
    with tqdm(total=steps * cfg.num_worlds, desc=f"{name:>8}", unit="frame", unit_scale=True, leave=False) as bar:

        def act(td):
            bar.update(cfg.num_worlds)
            return policy(td)

        rollout = run_episodes(env, act)
    seconds = time.perf_counter() - start
    summary = evaluation_summary(rollout)  # aia-eval's scores of the same episodes
    returns = rollout.get(("next", "reward")).sum((1, 2))
    return {
        "policy": name,
        "episodes": cfg.num_worlds,
        "score_mean": summary["score_mean"],
        "score_std": summary["score_std"],
        "return_mean": returns.mean().item(),
        "belief_error": summary["belief_error"],
        "observed_fraction": rollout.get(("next", "observed")).float().mean().item(),
        "collision_fraction": rollout.get(("next", "collision")).float().mean().item(),
        "frames_per_s": steps * cfg.num_worlds / seconds,
    }
