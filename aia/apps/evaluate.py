"""``aia-eval``: score a policy on fresh episodes: one saved by ``aia-train``, the ARVI planner or belief pursuit.

``policy=checkpoint`` rebuilds the network from the config stored in the checkpoint and acts at ``epsilon`` in
the checkpoint's own setting, or in one the command line sets (``env.<key>=...`` changes keys of its own,
``env=<preset>`` replaces it) whose observation has the same layout (the same belief features and map image,
on any map; another is refused); ``policy=arvi`` plans with :class:`~aia.planners.ARVIPolicy` (``planner.*``)
and ``policy=pursuit`` acts by the belief-pursuit heuristic (:class:`~aia.policies.BeliefPursuitPolicy`, at
``pursuit_standoff``), both in the setting ``env``. Either way ``episodes`` episodes run as one batched rollout
through the same evaluation path; the app prints the score mean and std (SPEC 9) and writes ``eval.json`` and
``run.mcap`` (the scores, the config, and world 0's episode as Foxglove scenes: ``aia-log render`` draws it as
in the paper's Fig. 3).

``aia-eval -m policy=arvi seed=0,...,9 hydra/launcher=population`` runs :func:`evaluate_jobs`: all seeds'
episodes in one rollout, planned in one batch with a budget group per seed, so that under a node or pass
budget every job writes the scores and log its own process would (``policy=pursuit`` likewise).

torch, TorchRL and the policies are imported inside the functions that evaluate, so that ``--help`` and a refused
config answer before they load (``aia-eval --help``: 4.3 s when this module imported them, 1.3 s now).
"""

from __future__ import annotations

import functools
import math
from collections.abc import Sequence
from dataclasses import asdict
from pathlib import Path
from typing import TYPE_CHECKING

from hydra.core.hydra_config import HydraConfig
from omegaconf import DictConfig, OmegaConf

from aia.apps.hydra_app import hydra_app, run_valid_jobs
from aia.apps.output_files import write_json
from aia.config.checks import require
from aia.config.errors import ConfigError, one_line
from aia.config.validation import check_checkpoint_file, overrides_group, validate_eval_config
from aia.envs.config import to_tracking_config
from aia.logging.metadata import RUN_LOG
from aia.planners import to_arvi_config
from aia.runtime.memory import keep_freed_memory

if TYPE_CHECKING:
    from aia.logging import MCAPLogger

POLICIES = ("checkpoint", "arvi")


def load_checkpoint(path: str | Path) -> dict:
    """A checkpoint written by ``aia-train``, or a :class:`ConfigError` (a ValueError) naming the path and what is
    wrong: missing, damaged (:func:`~aia.training.checkpoint_files.checkpoint_damage`), unreadable or foreign.
    Checked and read once per state of the file (its size and modification time): the validation, the layout
    guard and the evaluation each ask for it. Callers must not change what it returns."""
    path = Path(path)
    if not path.is_file():
        check_checkpoint_file("checkpoint", path)  # its one line
    stat = path.stat()
    return _read_checkpoint(path, stat.st_mtime_ns, stat.st_size)


@functools.lru_cache(maxsize=1)
def _read_checkpoint(path: Path, mtime_ns: int, size: int) -> dict:
    """:func:`load_checkpoint` of the file at ``path`` in the state ``(mtime_ns, size)``."""
    check_checkpoint_file("checkpoint", path)
    import torch

    try:
        checkpoint = torch.load(path, weights_only=False, map_location="cpu")
    except Exception as err:  # torch raises several types for a file that is not a checkpoint
        raise ConfigError("checkpoint", str(path), f"a readable torch checkpoint ({one_line(err)})") from None
    if not isinstance(checkpoint, dict) or not {"config", "actor"} <= checkpoint.keys():
        raise ConfigError("checkpoint", str(path), "a checkpoint written by aia-train (no 'config'/'actor' entries)")
    return checkpoint


def evaluate_checkpoint(path: str | Path, episodes: int, epsilon: float, seed: int, device: str,
                        logger: MCAPLogger | None = None, setting: DictConfig | None = None) -> dict:
    """Scores of the checkpoint's policy on ``episodes`` fresh episodes (logged to ``logger`` if given), in
    ``setting`` (an env config: :func:`check_setting`) or, without one, in the checkpoint's own."""
    from tensordict.nn import TensorDictSequential

    from aia.envs import make_env
    from aia.modules import EpsilonGreedy
    from aia.training import make_actor

    _check_episodes(episodes)
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
        _check_layout(path, setting, trained)
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


def checkpoint_setting(cfg: DictConfig, overrides: Sequence[str]) -> DictConfig | None:
    """The setting ``policy=checkpoint`` evaluates in, as the command line (``overrides``) sets it: with
    ``env=<preset>``, that preset (``cfg.env``, its ``env.<key>`` overrides applied); with ``env.<key>=...``
    alone, the checkpoint's own setting with those keys as ``cfg.env`` has them; without either, ``None`` (the
    checkpoint's own)."""
    changed = [override.lstrip("+~").split("=")[0] for override in overrides_group(overrides, "env")]
    if cfg.policy != "checkpoint" or not changed:
        return None
    if "env" in changed:
        return cfg.env
    setting = OmegaConf.create(load_checkpoint(cfg.checkpoint)["config"]).env
    for key in changed:
        OmegaConf.update(setting, key.removeprefix("env."), OmegaConf.select(cfg, key), merge=False)
    return setting


def check_setting(path: str | Path, setting: DictConfig) -> None:
    """Refuse, with one line naming both layouts, to evaluate the checkpoint at ``path`` in ``setting`` (an env
    config) if its observation's layout differs from the setting the checkpoint was trained in."""
    trained = OmegaConf.create(load_checkpoint(path)["config"]).env
    _check_layout(path, setting, trained)


def _layout(setting: DictConfig) -> str:
    """The observation layout of ``setting``'s env (:func:`~aia.training.components.observation_layout`)."""
    return _layout_of(OmegaConf.to_yaml(setting, resolve=True))


@functools.cache
def _layout_of(setting: str) -> str:
    """:func:`_layout` of a setting's YAML, from a one-world env built once per setting: a population's jobs
    and the evaluation's own guard then ask again for free."""
    from aia.envs import make_env
    from aia.training.components import observation_layout

    return observation_layout(make_env(to_tracking_config(OmegaConf.create(setting)), batch_size=1).observation_spec)


# the env keys that shape the observation, named first when a setting's layout differs from a checkpoint's
_LAYOUT_KEYS = ("num_targets", "features.local_map", "features.im_size", "features.relative_velocity", "target.model")


def _check_layout(path: str | Path, setting: DictConfig, trained: DictConfig) -> None:
    """A :class:`ConfigError` on ``env`` unless ``setting``'s observation layout is that of ``trained`` (the
    checkpoint's env), naming the layouts and the keys in which the settings differ (those that shape the
    observation first, three at most)."""
    layout, expected = _layout(setting), _layout(trained)
    if layout == expected:
        return
    from aia.training.members import flat_settings

    ours, theirs = (flat_settings(OmegaConf.structured(to_tracking_config(s))) for s in (setting, trained))
    rank = {key: i for i, key in enumerate(_LAYOUT_KEYS)}
    differing = sorted((key for key in ours if ours[key] != theirs.get(key)),
                       key=lambda key: (rank.get(key, len(rank)), key))
    named = ", ".join(f"env.{key}={ours[key]!r} ({theirs.get(key)!r} there)" for key in differing[:3])
    more = f" and {len(differing) - 3} more" if len(differing) > 3 else ""
    raise ConfigError("env", layout, f"the observation layout of the setting {path} was trained in, {expected} (the "
                      f"same belief features and map image; the map itself may differ); this setting differs from "
                      f"it in {named}{more}")


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
    from aia.policies import BeliefPursuitPolicy

    _check_episodes(episodes)
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
        actor = BeliefPursuitPolicy(env.base_env, standoff=standoff)
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
    from aia.evaluation import evaluation_summary, log_score_summary, run_episodes
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


def _check_episodes(episodes: int) -> None:
    if episodes < 1:
        raise ValueError(f"episodes={episodes} must be >= 1")


@hydra_app("aia-eval", config_name="eval", population="aia.apps.evaluate.evaluate_jobs")  # bad input: exit 2
def main(cfg: DictConfig) -> float:
    """Entry point of ``aia-eval``; returns the score mean."""
    out_dir = Path(HydraConfig.get().runtime.output_dir)
    setting = _validate(cfg, HydraConfig.get().overrides.task, out_dir)
    return run_jobs([cfg], [out_dir], [setting])[0]


def _validate(cfg: DictConfig, overrides: Sequence[str], out_dir: Path) -> DictConfig | None:
    """:func:`~aia.config.validation.validate_eval_config`, a checkpoint's setting checked
    (:func:`check_setting`), and the job's folder ``out_dir`` checked to hold no run log (one is never
    overwritten), before any run log is written; returns that setting (:func:`checkpoint_setting`)."""
    validate_eval_config(cfg, overrides)
    require(not (out_dir / RUN_LOG).exists(), "output folder", str(out_dir),
            f"a folder without a run log ({RUN_LOG} is there already, and a run log is never overwritten: "
            "choose another hydra.run.dir or hydra.sweep.dir)")
    setting = checkpoint_setting(cfg, overrides)
    if setting is not None:
        check_setting(cfg.checkpoint, setting)
    return setting


def evaluate_jobs(cfgs: Sequence[DictConfig], out_dirs: Sequence[Path]) -> list[float | Exception]:
    """The population launcher's task (``hydra/launcher=population``): the jobs' configs, which differ only
    in ``seed``, evaluated together by :func:`run_jobs`, job ``k`` writing to ``out_dirs[k]``; each job's score
    mean, or the error that stopped it (an invalid config fails its own job only: the others run without it)."""
    settings: dict[int, DictConfig | None] = {}  # each valid job's setting, as its validation found it

    def validate(k: int, cfg: DictConfig) -> None:
        settings[k] = _validate(cfg, _job_overrides(out_dirs[k]), Path(out_dirs[k]))

    return run_valid_jobs(cfgs, validate,
                          lambda valid: run_jobs([cfgs[i] for i in valid], [Path(out_dirs[i]) for i in valid],
                                                 [settings[i] for i in valid]))


def run_jobs(cfgs: Sequence[DictConfig], out_dirs: Sequence[Path],
             settings: Sequence[DictConfig | None] | None = None) -> list[float]:
    """Evaluate validated configs that differ only in ``seed``, each writing its ``eval.json`` and ``run.mcap``
    to its folder: ``policy=arvi`` or ``pursuit`` in one rollout (:func:`evaluate_scripted_seeds`), checkpoints
    one by one, job ``k``'s in ``settings[k]`` (:func:`checkpoint_setting`; ``None``, or no ``settings``: its own).
    Each job's score mean."""
    import torch

    from aia.logging import MCAPLogger
    from aia.training.members import check_population

    check_population(cfgs)
    first = cfgs[0]
    if first.threads:
        torch.set_num_threads(first.threads)
    if first.keep_freed_memory:
        keep_freed_memory()
    loggers = [MCAPLogger(f"eval-{cfg.policy}-seed{cfg.seed}", out_dir,
                          run_metadata={"seed": cfg.seed, "policy": cfg.policy})
               for cfg, out_dir in zip(cfgs, out_dirs, strict=True)]
    try:
        if first.policy != "checkpoint":
            results = evaluate_scripted_seeds(first.policy, first.env, first.episodes, [cfg.seed for cfg in cfgs],
                                              first.device, loggers, first.planner, first.pursuit_standoff)
        else:
            settings = [None] * len(cfgs) if settings is None else settings
            results = [evaluate_checkpoint(cfg.checkpoint, cfg.episodes, cfg.epsilon, cfg.seed, cfg.device, logger,
                                           setting) for cfg, logger, setting in zip(cfgs, loggers, settings,
                                                                                    strict=True)]
    finally:
        for logger in loggers:
            logger.close()
    for cfg, out_dir, logger, result in zip(cfgs, out_dirs, loggers, results, strict=True):
        _report(cfg, Path(out_dir), logger, result)
    return [result["score_mean"] for result in results]


def _report(cfg: DictConfig, out_dir: Path, logger: MCAPLogger, result: dict) -> None:
    """Print a job's scores and write its ``eval.json``."""
    if cfg.policy == "checkpoint":
        what, how = f"{result['algo']} after {result['frames_trained']} frames", f"epsilon {cfg.epsilon}"
    elif cfg.policy == "arvi":
        what, how = "arvi", f"horizon {cfg.planner.horizon}, budget {_budget(cfg.planner)}"
    else:
        what, how = "pursuit", f"standoff {cfg.pursuit_standoff} of the sensor range"
    print(f"{what}: score {result['score_mean']:.1f} +- {result['score_std']:.1f} over {cfg.episodes} episodes, "
          f"belief error {result['belief_error']:.1f} m ({how})")
    out = out_dir / "eval.json"
    write_json(out, result)
    print(f"log written to {out} and {logger.path} (world 0's episode recorded: aia-log render {logger.path})")


def _job_overrides(out_dir: str | Path) -> list[str]:
    """The command-line overrides of a sweep job, from the ``.hydra/overrides.yaml`` Hydra saved in its folder."""
    path = Path(out_dir) / ".hydra" / "overrides.yaml"
    return list(OmegaConf.load(path)) if path.is_file() else []


def _budget(planner: DictConfig) -> str:
    budgets = {"time_budget": "{} s", "max_passes": "{} passes", "max_nodes": "{} nodes per world"}
    return ", ".join(form.format(planner[name]) for name, form in budgets.items() if planner[name] is not None)


if __name__ == "__main__":
    main()
