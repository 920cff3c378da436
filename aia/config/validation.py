"""Validation of the apps' composed configs: every value, once, before a run starts.

Hydra has already refused unknown keys and values of the wrong type while composing (the schemas of
:mod:`aia.config.schemas`), but not a key added with ``+`` (``+lr2=1`` composes, and a run would ignore it):
:func:`check_known_keys` refuses that first, naming the keys allowed where it stands. ``validate_train_config``,
``validate_eval_config`` and ``validate_rollout_config`` raise :class:`~aia.config.errors.ConfigError` (key,
value, what is allowed) for the first bad value: each field's declared check (:func:`check_settings`: ranges,
choices, devices this machine has), the cross-field rules (``batch_size <= buffer_size``, Thompson sampling
needs ADFQ), and the env setting with its map (:func:`aia.envs.factory.to_tracking_config`).
"""

from __future__ import annotations

import dataclasses
import difflib
import typing
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from omegaconf import DictConfig, OmegaConf

from aia.config.checks import check_choice, require
from aia.config.errors import ConfigError
from aia.config.schemas import EvalConfig, RolloutConfig, TrainConfig
from aia.envs.config import TrackingConfig, to_tracking_config
from aia.planners.config import ARVIConfig, to_arvi_config
from aia.training.checkpoint_names import PREVIOUS_CHECKPOINT_NAME

# The apps' fields typed Any that hold a sub-config with a schema of its own.
SUB_SCHEMAS: dict[str, type] = {"env": TrackingConfig, "planner": ARVIConfig}


def _value(node: DictConfig, name: str, key: str) -> Any:
    """``node[name]`` (dotted ``key`` from the root); a required value left unset (``???``) is named as missing."""
    require(name in node and not OmegaConf.is_missing(node, name), key, "???", "a value (this one is required)")
    return node[name]


def check_settings(cfg: DictConfig, schema: type, prefix: str = "") -> None:
    """Every value of ``cfg`` whose field in ``schema`` declares a check, in declaration order; of a config group
    (``algo``, ``exploration``, ``logger``), its ``name`` among the options first, then its option's fields."""
    types = typing.get_type_hints(schema)
    for item in dataclasses.fields(schema):
        key = prefix + item.name
        if "options" in item.metadata:
            node = _value(cfg, item.name, key)
            options = item.metadata["options"]
            name = _value(node, "name", f"{key}.name")
            check_choice(key, name, options)
            check_settings(node, options[name], key + ".")
        elif dataclasses.is_dataclass(types[item.name]):
            check_settings(_value(cfg, item.name, key), types[item.name], key + ".")
        elif item.metadata["check"] is not None:
            item.metadata["check"](key, _value(cfg, item.name, key))


def _fields(schema: type | dict[str, type], prefix: str) -> dict[str, Any]:
    """Each field of ``schema`` (at dotted ``prefix``) by name, with the schema of its value if it holds keys: a
    nested schema, ``env``'s or ``planner``'s (:data:`SUB_SCHEMAS`), a group's options (a dict by option name);
    ``None`` for a value. Of a group (``schema`` a dict of options), the fields of all its options."""
    if isinstance(schema, dict):
        merged: dict[str, Any] = {}
        for option in dict.fromkeys(schema.values()):
            for name, child in _fields(option, prefix).items():
                merged.setdefault(name, child)
        return merged
    types = typing.get_type_hints(schema)
    fields: dict[str, Any] = {}
    for item in dataclasses.fields(schema):
        if "options" in item.metadata:
            fields[item.name] = item.metadata["options"]
        elif dataclasses.is_dataclass(types[item.name]):
            fields[item.name] = types[item.name]
        else:
            fields[item.name] = SUB_SCHEMAS.get(prefix + item.name)
    return fields


def unknown_key_allowed(schema: type, key: str, prefix: str = "") -> str | None:
    """What is allowed in place of dotted ``key`` in a config of ``schema`` (an app's, or a node's own schema
    that sits at dotted ``prefix``, such as ``"planner."``, named so in the words): the keys of the deepest group
    of keys on its path, the closest name first if one is close; ``None`` if ``key`` is a field. A group's keys
    are its options' together."""
    parts = key.split(".")
    current: Any = schema
    for depth, part in enumerate(parts):
        path = ".".join(parts[:depth])
        fields = _fields(current, path + "." if path else "")
        last = depth + 1 == len(parts)
        if part in fields and (last or fields[part] is not None):
            if last:
                return None
            current = fields[part]
            continue
        return keys_allowed(list(fields), (prefix + path).rstrip("."), part)
    return None


def keys_allowed(names: list[str], prefix: str, part: str) -> str:
    """What is allowed in place of ``part``, a key that the group of keys at dotted ``prefix`` ("" for the top
    level) does not have: its keys ``names``, with the one close to ``part``, or that ``part`` is a value there
    (with no keys under it)."""
    dotted = prefix + "." if prefix else ""
    if part in names:
        hint = f" ({dotted}{part} is a value, not a group of keys)"
    else:
        close = difflib.get_close_matches(part, names, n=1)
        hint = f" (did you mean {dotted}{close[0]}?)" if close else ""
    owner = f"{prefix}'s" if prefix else "the config's"
    return f"one of {owner} keys{hint}: {', '.join(names)}"


def check_known_keys(cfg: DictConfig | dict, schema: type, prefix: str = "") -> None:
    """Every key of ``cfg`` (an app's composed config, or its node at dotted ``prefix`` as a dict) is a field of
    ``schema``, walked as :func:`check_settings` walks it (a group by its chosen option; ``env`` and ``planner``
    by :data:`SUB_SCHEMAS`); a :class:`ConfigError` names the first other key (one added with Hydra's ``+``) and
    the keys allowed there."""
    node = cfg if isinstance(cfg, dict) else OmegaConf.to_container(cfg, resolve=False)
    fields = _fields(schema, prefix)
    for name, value in node.items():
        key = prefix + str(name)
        if name not in fields:  # the message only then: it matches the name against every key of the group
            raise ConfigError(key, value, keys_allowed(list(fields), prefix[:-1], str(name)))
        child = fields[name]
        if isinstance(child, dict) and isinstance(value, dict):  # a group: its chosen option's schema
            child = child.get(str(value.get("name")))  # an unknown option: check_settings names it
        if child is not None and isinstance(value, dict):
            check_known_keys(value, child, key + ".")


def validate_train_config(cfg: DictConfig) -> None:
    """Check the composed ``aia-train`` config (conf/train.yaml); raise ``ConfigError`` on the first bad value."""
    check_known_keys(cfg, TrainConfig)
    check_settings(cfg, TrainConfig)
    require(cfg.batch_size <= cfg.buffer_size, "batch_size", cfg.batch_size,
            f"at most buffer_size={cfg.buffer_size} (a batch is drawn from the replay buffer)")
    resume = _value(cfg, "resume", "resume")
    if resume is not None and str(resume) != "auto":
        require(Path(str(resume)).is_file(), "resume", resume, "null, auto or an existing checkpoint .pt file")
    algo, exploration = cfg.algo.name, cfg.exploration.name
    require(exploration != "thompson" or algo == "adfq", "exploration", exploration,
            f"egreedy with algo={algo} (thompson samples the per-action sds of algo=adfq)")
    if algo == "adfq":
        require(cfg.algo.sd_max**2 > cfg.algo.var_min, "algo.sd_max", cfg.algo.sd_max,
                f"a value whose square exceeds algo.var_min={cfg.algo.var_min}")
    if cfg.logger.name == "mcap":
        record_every = cfg.logger.record_every_evaluations
        require(record_every == 0 or cfg.eval.per_rollout <= record_every, "eval.per_rollout", cfg.eval.per_rollout,
                f"at most logger.record_every_evaluations={record_every} (one recorded episode per rollout)")
    to_tracking_config(cfg.env)


def validate_eval_config(cfg: DictConfig, overrides: Sequence[str] = ()) -> None:
    """Check the composed ``aia-eval`` config (conf/eval.yaml); ``overrides`` are the command line's
    (``HydraConfig.get().overrides.task``): with ``policy=checkpoint`` or ``pursuit`` a ``planner`` override,
    which it would ignore, is refused (an ``env`` override sets the setting a checkpoint is evaluated in:
    ``aia.apps.evaluate`` checks it against the checkpoint)."""
    check_known_keys(cfg, EvalConfig)
    check_settings(cfg, EvalConfig)
    if cfg.policy == "arvi":
        to_tracking_config(cfg.env)
        to_arvi_config(cfg.planner)  # a ConfigError naming the planner's field
        return
    ignored = overrides_group(overrides, "planner")
    if ignored:
        key, _, value = ignored[0].lstrip("+~").partition("=")
        raise ConfigError(key, value, f"no planner override with policy={cfg.policy} (planner applies to policy=arvi)")
    if cfg.policy == "pursuit":
        to_tracking_config(cfg.env)
        return
    require(not OmegaConf.is_missing(cfg, "checkpoint"), "checkpoint", "???",
            "the path of a checkpoint .pt written by aia-train (required with policy=checkpoint)")
    check_checkpoint_file("checkpoint", Path(str(cfg.checkpoint)))


def overrides_group(overrides: Sequence[str], group: str) -> list[str]:
    """The command-line overrides of ``group``: ``group=<option>`` and ``group.<key>=<value>`` (``+``/``~`` too)."""
    return [o for o in overrides if o.lstrip("+~").split("=")[0].split(".")[0] == group]


def check_checkpoint_file(key: str, path: Path) -> None:
    """``path`` is an existing, undamaged checkpoint file (every record's CRC-32 checked)."""
    require(path.is_file(), key, str(path), "an existing checkpoint .pt file written by aia-train")
    from aia.training.checkpoint_files import checkpoint_damage  # a valid path only: it loads torch

    problem = checkpoint_damage(path)
    require(problem is None, key, str(path), f"an undamaged torch checkpoint written by aia-train, but {problem}: "
            f"use another checkpoint (the run's {PREVIOUS_CHECKPOINT_NAME} is the one before its last)")


def validate_rollout_config(cfg: DictConfig) -> None:
    """Check the composed ``aia-rollout`` config (conf/rollout.yaml)."""
    check_known_keys(cfg, RolloutConfig)
    check_settings(cfg, RolloutConfig)
    to_tracking_config(cfg.env)
