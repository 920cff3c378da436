"""Validation of the apps' composed configs: every value, once, before a run starts.

``validate_train_config``, ``validate_eval_config`` and ``validate_rollout_config`` raise
:class:`~aia.config.errors.ConfigError` (key, value, what is allowed) for the first bad value: types, ranges,
choices, cross-field rules (``batch_size <= buffer_size``, Thompson sampling needs ADFQ), devices this
machine has, and the env setting with its map (:func:`aia.envs.factory.to_tracking_config`).
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

from omegaconf import DictConfig, OmegaConf

from aia.config.checks import check_choice, check_device, check_flag, check_number, require
from aia.config.errors import ConfigError, one_line
from aia.envs.factory import to_tracking_config
from aia.logging.mcap_logger import COMPRESSIONS
from aia.modules.exploration import ALGORITHMS, EXPLORATIONS
from aia.planners import to_arvi_config

LOGGERS = ("mcap", "csv", "none")
LOSS_FUNCTIONS = ("smooth_l1", "l2", "l1")
EVAL_POLICIES = ("checkpoint", "arvi")
ROLLOUT_POLICIES = ("random", "pursuit")

_TRAIN_POSITIVE_INTEGERS = ("frames", "collector.num_envs", "batch_size", "buffer_size", "target_update_interval",
                            "checkpoint_every_frames", "eval.every_episodes", "eval.episodes", "eval.per_rollout")


def _value(cfg: DictConfig, key: str):
    """The value at dotted ``key``; a required value left unset (``???``) is named as missing."""
    require(not OmegaConf.is_missing(cfg, key), key, "???", "a value (this one is required)")
    return OmegaConf.select(cfg, key)


def _check_run_basics(cfg: DictConfig) -> None:
    """``seed``, ``device`` and ``threads``, which every app has."""
    check_number("seed", _value(cfg, "seed"), ge=0, integer=True)
    check_device("device", _value(cfg, "device"))
    check_number("threads", _value(cfg, "threads"), ge=1, integer=True, optional=True)


def validate_train_config(cfg: DictConfig) -> None:
    """Check the composed ``aia-train`` config (conf/train.yaml); raise ``ConfigError`` on the first bad value."""
    _check_run_basics(cfg)
    check_flag("keep_freed_memory", _value(cfg, "keep_freed_memory"))
    for key in _TRAIN_POSITIVE_INTEGERS:
        check_number(key, _value(cfg, key), ge=1, integer=True)
    check_number("warmup_frames", _value(cfg, "warmup_frames"), ge=0, integer=True)
    check_number("updates_per_frame", _value(cfg, "updates_per_frame"), gt=0)
    check_number("lr", _value(cfg, "lr"), gt=0)
    check_number("grad_clip", _value(cfg, "grad_clip"), gt=0)
    check_number("gamma", _value(cfg, "gamma"), ge=0, le=1)
    check_number("eval.epsilon", _value(cfg, "eval.epsilon"), ge=0, le=1)
    hidden = _value(cfg, "hidden")
    hidden = list(hidden) if OmegaConf.is_list(hidden) else hidden
    require(isinstance(hidden, list) and len(hidden) > 0
            and all(isinstance(h, int) and not isinstance(h, bool) and h >= 1 for h in hidden),
            "hidden", hidden, "a non-empty list of layer widths >= 1, e.g. [128, 128, 128]")
    check_choice("inner_dtype", _value(cfg, "inner_dtype"), ["float32", "bfloat16"])
    require(cfg.batch_size <= cfg.buffer_size, "batch_size", cfg.batch_size,
            f"at most buffer_size={cfg.buffer_size} (a batch is drawn from the replay buffer)")
    for switch in ("update", "env", "policy"):
        check_flag(f"compile.{switch}", _value(cfg, f"compile.{switch}"))
    resume = _value(cfg, "resume")
    if resume is not None and str(resume) != "auto":
        require(Path(str(resume)).is_file(), "resume", resume, "null, auto or an existing checkpoint .pt file")
    check_number("checkpoint_every_s", _value(cfg, "checkpoint_every_s"), gt=0)
    check_number("lock_wait_s", _value(cfg, "lock_wait_s"), ge=0)
    _check_learner(cfg)
    _check_logger(cfg)
    to_tracking_config(cfg.env)


def _check_learner(cfg: DictConfig) -> None:
    """The algorithm, its parameters and the exploration it is paired with."""
    algo, exploration = _value(cfg, "algo.name"), _value(cfg, "exploration.name")
    check_choice("algo", algo, ALGORITHMS)
    check_choice("exploration", exploration, EXPLORATIONS)
    require(exploration != "thompson" or algo == "adfq", "exploration", exploration,
            f"egreedy with algo={algo} (thompson samples the per-action sds of algo=adfq)")
    check_choice("algo.loss_function", _value(cfg, "algo.loss_function"), LOSS_FUNCTIONS)
    if algo == "adfq":
        check_number("algo.noise", _value(cfg, "algo.noise"), ge=0)
        for key in ("algo.var_min", "algo.sd_max", "algo.reward_var"):
            check_number(key, _value(cfg, key), gt=0)
        require(cfg.algo.sd_max**2 > cfg.algo.var_min, "algo.sd_max", cfg.algo.sd_max,
                f"a value whose square exceeds algo.var_min={cfg.algo.var_min}")
    if exploration == "egreedy":
        for key in ("exploration.eps_init", "exploration.eps_end", "exploration.annealing_fraction"):
            check_number(key, _value(cfg, key), ge=0, le=1)


def _check_logger(cfg: DictConfig) -> None:
    """The logger choice and, for MCAP, its file options and how they fit the evaluations."""
    name = _value(cfg, "logger.name")
    check_choice("logger", name, LOGGERS)
    if name != "mcap":
        return
    check_choice("logger.compression", _value(cfg, "logger.compression"), sorted(COMPRESSIONS))
    check_number("logger.chunk_size", _value(cfg, "logger.chunk_size"), ge=1, integer=True)
    check_number("logger.flush_interval_s", _value(cfg, "logger.flush_interval_s"), gt=0)
    record_every = _value(cfg, "logger.record_every_evaluations")
    check_number("logger.record_every_evaluations", record_every, ge=0, integer=True)
    require(record_every == 0 or cfg.eval.per_rollout <= record_every, "eval.per_rollout", cfg.eval.per_rollout,
            f"at most logger.record_every_evaluations={record_every} (one recorded episode per rollout)")


def validate_eval_config(cfg: DictConfig, overrides: Sequence[str] = ()) -> None:
    """Check the composed ``aia-eval`` config (conf/eval.yaml); ``overrides`` are the command line's
    (``HydraConfig.get().overrides.task``): with ``policy=checkpoint`` the checkpoint carries its own setting,
    so an ``env`` or ``planner`` override, which it would ignore, is refused."""
    _check_run_basics(cfg)
    check_flag("keep_freed_memory", _value(cfg, "keep_freed_memory"))
    policy = _value(cfg, "policy")
    check_choice("policy", policy, EVAL_POLICIES)
    check_number("episodes", _value(cfg, "episodes"), ge=1, integer=True)
    check_number("epsilon", _value(cfg, "epsilon"), ge=0, le=1)
    if policy == "arvi":
        to_tracking_config(cfg.env)
        try:
            to_arvi_config(cfg.planner)
        except ValueError as err:
            raise ConfigError("policy", policy, f"a valid planner config ({one_line(err)})") from None
        return
    ignored = [o for o in overrides if o.lstrip("+~").split("=")[0].split(".")[0] in ("env", "planner")]
    if ignored:
        key, _, value = ignored[0].lstrip("+~").partition("=")
        raise ConfigError(key, value, "no env or planner override with policy=checkpoint: the checkpoint "
                                      "carries its own setting (env and planner apply to policy=arvi)")
    require(not OmegaConf.is_missing(cfg, "checkpoint"), "checkpoint", "???",
            "the path of a checkpoint .pt written by aia-train (required with policy=checkpoint)")
    check_checkpoint_file("checkpoint", Path(str(cfg.checkpoint)))


def check_checkpoint_file(key: str, path: Path) -> None:
    """``path`` is an existing, undamaged checkpoint file (every record's CRC-32 checked)."""
    from aia.training.checkpoint import PREVIOUS_CHECKPOINT_NAME  # imported here: aia.training imports this module
    from aia.training.checkpoint_files import checkpoint_damage

    require(path.is_file(), key, str(path), "an existing checkpoint .pt file written by aia-train")
    problem = checkpoint_damage(path)
    require(problem is None, key, str(path), f"an undamaged torch checkpoint written by aia-train, but {problem}: "
            f"use another checkpoint (the run's {PREVIOUS_CHECKPOINT_NAME} is the one before its last)")


def validate_rollout_config(cfg: DictConfig) -> None:
    """Check the composed ``aia-rollout`` config (conf/rollout.yaml)."""
    _check_run_basics(cfg)
    policies = _value(cfg, "policies")
    policies = list(policies) if OmegaConf.is_list(policies) else policies
    require(isinstance(policies, list) and len(policies) > 0 and set(policies) <= set(ROLLOUT_POLICIES),
            "policies", policies, f"a non-empty list of {list(ROLLOUT_POLICIES)}")
    check_number("num_worlds", _value(cfg, "num_worlds"), ge=1, integer=True)
    check_flag("compile", _value(cfg, "compile"))
    check_number("pursuit_standoff", _value(cfg, "pursuit_standoff"), ge=0, le=1)
    to_tracking_config(cfg.env)
