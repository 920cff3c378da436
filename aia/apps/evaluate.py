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

What is played and scored is :mod:`aia.evaluation.standalone`'s, the checkpoint's reading and layout guard
:mod:`aia.evaluation.checkpoints`'s; torch, TorchRL and the policies load inside their functions, so that
``--help`` and a refused config answer before they load (``aia-eval --help``: 4.3 s when this app imported
them, 1.3 s since).
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING

from hydra.core.hydra_config import HydraConfig
from omegaconf import DictConfig, OmegaConf

from aia.apps.hydra_app import hydra_app, run_valid_jobs
from aia.apps.output_files import write_json
from aia.config.checks import require
from aia.config.validation import overrides_group, validate_eval_config
from aia.evaluation.checkpoints import check_setting, load_checkpoint
from aia.evaluation.standalone import evaluate_checkpoint, evaluate_scripted_seeds
from aia.logging.metadata import RUN_LOG
from aia.runtime.memory import keep_freed_memory

if TYPE_CHECKING:
    from aia.logging import MCAPLogger

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


@hydra_app("aia-eval", config_name="eval", population="aia.apps.evaluate.evaluate_jobs")  # bad input: exit 2
def main(cfg: DictConfig) -> float:
    """Entry point of ``aia-eval``; returns the score mean."""
    out_dir = Path(HydraConfig.get().runtime.output_dir)
    setting = _validate(cfg, HydraConfig.get().overrides.task, out_dir)
    return run_jobs([cfg], [out_dir], [setting])[0]


def _validate(cfg: DictConfig, overrides: Sequence[str], out_dir: Path) -> DictConfig | None:
    """:func:`~aia.config.validation.validate_eval_config`, a checkpoint's setting checked
    (:func:`~aia.evaluation.checkpoints.check_setting`), and the job's folder ``out_dir`` checked to hold no run
    log (one is never overwritten), before any run log is written; returns that setting
    (:func:`checkpoint_setting`)."""
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
    to its folder: ``policy=arvi`` or ``pursuit`` in one rollout
    (:func:`~aia.evaluation.standalone.evaluate_scripted_seeds`), checkpoints one by one, job ``k``'s in
    ``settings[k]`` (:func:`checkpoint_setting`; ``None``, or no ``settings``: its own). Each job's score mean."""
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
