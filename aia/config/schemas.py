"""Typed schemas of the apps' configs: ``aia-train`` (:class:`TrainConfig`), ``aia-eval`` (:class:`EvalConfig`)
and ``aia-rollout`` (:class:`RolloutConfig`), and of the train config's groups (algo, exploration, logger).

The YAML files under ``conf/`` hold the values and their comments; a schema holds each field's type and, in its
metadata (:func:`setting`), the range the validation layer checks (a :mod:`~aia.config.checks` check), whether
the members of one population may differ in it (``member``) and whether a resumed run must match its checkpoint
in it (``resume``). :data:`~aia.training.members.MEMBER_KEYS` and :data:`~aia.training.resuming.RESUME_KEYS` are
read from here (:func:`keys_where`), so a new field states both where it is declared.

Each schema is registered with Hydra's ConfigStore as a root config (``train_schema``, ``algo_schema``, ...), the
first entry of its YAML's defaults list as the env presets have ``env_schema``: a misspelt key or a value of the
wrong type is refused while composing. Numbers that may be integers or reals are typed ``Any``: OmegaConf 2.3
has no ``Union[int, float]``, and a ``float`` field would show ``lr=1`` as ``1.0``; their :class:`Number`
check refuses anything else. The env's schema is :class:`aia.envs.config.TrackingConfig`; the planner's is
:class:`aia.planners.ARVIConfig`, checked when it is built.
"""

from __future__ import annotations

import dataclasses
import typing
from collections.abc import Iterator
from dataclasses import dataclass, field
from typing import Any, Optional

from hydra.core.config_store import ConfigStore
from omegaconf import MISSING

from aia.config.checks import Check, Choice, ConvLayers, Device, Flag, NamesFrom, Number, Widths
from aia.logging.metadata import COMPRESSIONS

LOSS_FUNCTIONS = ("smooth_l1", "l2", "l1")
EVAL_POLICIES = ("checkpoint", "arvi", "pursuit")
ROLLOUT_POLICIES = ("random", "pursuit")

SEED = Number(ge=0, integer=True)
THREADS = Number(ge=1, integer=True, optional=True)
COUNT = Number(ge=1, integer=True)
POSITIVE = Number(gt=0)
PROBABILITY = Number(ge=0, le=1)


def setting(default: Any = MISSING, *, check: Check | None = None, member: bool = False,
            resume: bool = False) -> Any:
    """A schema field (``???``: its value comes from the YAML): ``check`` its range, ``member``: members of one
    population may differ in it, ``resume``: a resumed run must match its checkpoint in it (a field holding a
    whole sub-config, such as ``env``, in every key under it)."""
    return field(default=default, metadata={"check": check, "member": member, "resume": resume})


def group(**options: type) -> Any:
    """The field of a config group (``algo``, ``exploration``, ``logger``), typed by its chosen option: each
    option's ``name`` and schema. The fields of the options' schemas carry their own metadata."""
    return field(default=MISSING, metadata={"options": options})


@dataclass
class AlgoConfig:
    """``algo=dqn`` and ``algo=ddqn`` (conf/algo/)."""

    name: str = setting(member=True, resume=True)  # only within a family: aia.training.members.FAMILIES
    loss_function: str = setting(check=Choice(LOSS_FUNCTIONS), resume=True)


@dataclass
class ADFQConfig(AlgoConfig):
    """``algo=adfq``: the ADF posterior's variances (SPEC 8)."""

    noise: Any = setting(check=Number(ge=0), resume=True)
    var_min: Any = setting(check=POSITIVE, resume=True)
    sd_max: Any = setting(check=POSITIVE, resume=True)
    reward_var: Any = setting(check=POSITIVE, resume=True)


@dataclass
class ExplorationConfig:
    """``exploration=thompson`` (conf/exploration/)."""

    name: str = setting(member=True, resume=True)


@dataclass
class EGreedyConfig(ExplorationConfig):
    """``exploration=egreedy``: each member may anneal its own epsilon."""

    eps_init: Any = setting(check=PROBABILITY, member=True)
    eps_end: Any = setting(check=PROBABILITY, member=True)
    annealing_fraction: Any = setting(check=PROBABILITY, member=True)


@dataclass
class LoggerConfig:
    """``logger=csv`` and ``logger=none`` (conf/logger/)."""

    name: str = setting()


@dataclass
class MCAPConfig(LoggerConfig):
    """``logger=mcap``: the run's MCAP file."""

    file: str = setting()
    compression: str = setting(check=Choice(tuple(sorted(COMPRESSIONS))))
    chunk_size: int = setting(check=COUNT)
    flush_interval_s: Any = setting(check=POSITIVE)
    record_every_evaluations: int = setting(check=Number(ge=0, integer=True))


@dataclass
class CollectorConfig:
    """How many worlds each member steps per collector batch."""

    num_envs: int = setting(check=COUNT, resume=True)


@dataclass
class EvalSettings:
    """The training loop's evaluations."""

    every_episodes: int = setting(check=COUNT)
    episodes: int = setting(check=COUNT)
    epsilon: Any = setting(check=PROBABILITY)
    per_rollout: int = setting(check=COUNT)


@dataclass
class CompileConfig:
    """The torch.compile switches: numbers equal up to float rounding, so a resume may change them."""

    update: bool = setting(check=Flag())
    env: bool = setting(check=Flag())
    policy: bool = setting(check=Flag())


@dataclass
class TrainConfig:
    """``aia-train`` (conf/train.yaml). Fields in the order a population's message lists its member keys."""

    seed: int = setting(check=SEED, member=True, resume=True)
    lr: Any = setting(check=POSITIVE, member=True)
    method: Optional[str] = setting(None, member=True)  # set by conf/method/, as runs are grouped by
    algo: Any = group(dqn=AlgoConfig, ddqn=AlgoConfig, adfq=ADFQConfig)
    exploration: Any = group(egreedy=EGreedyConfig, thompson=ExplorationConfig)
    env: Any = setting(resume=True)
    logger: Any = group(mcap=MCAPConfig, csv=LoggerConfig, none=LoggerConfig)
    device: str = setting(check=Device())
    threads: Optional[int] = setting(check=THREADS)
    keep_freed_memory: bool = setting(check=Flag())
    frames: int = setting(check=COUNT)
    collector: CollectorConfig = field(default_factory=CollectorConfig)
    updates_per_frame: Any = setting(check=POSITIVE, resume=True)
    warmup_frames: int = setting(check=Number(ge=0, integer=True), resume=True)
    buffer_size: int = setting(check=COUNT, resume=True)
    batch_size: int = setting(check=COUNT, resume=True)
    gamma: Any = setting(check=PROBABILITY, resume=True)
    hidden: list[int] = setting(check=Widths(), resume=True)
    conv_layers: list[list[int]] = setting(check=ConvLayers(), resume=True)
    inner_dtype: str = setting(check=Choice(("float32", "bfloat16")))
    target_update_interval: int = setting(check=COUNT, resume=True)
    grad_clip: Any = setting(check=POSITIVE)
    eval: EvalSettings = field(default_factory=EvalSettings)
    checkpoint_every_frames: int = setting(check=COUNT)
    checkpoint_every_s: Any = setting(check=POSITIVE)
    resume: Optional[str] = setting(member=True)  # checked with the run folder: aia.config.validation
    lock_wait_s: Any = setting(check=Number(ge=0))
    compile: CompileConfig = field(default_factory=CompileConfig)


@dataclass
class EvalConfig:
    """``aia-eval`` (conf/eval.yaml)."""

    env: Any = setting()
    planner: Any = setting()
    policy: str = setting(check=Choice(EVAL_POLICIES))
    checkpoint: str = setting()  # required by policy=checkpoint only: aia.config.validation
    episodes: int = setting(check=COUNT)
    epsilon: Any = setting(check=PROBABILITY)
    seed: int = setting(check=SEED)
    device: str = setting(check=Device())
    threads: Optional[int] = setting(check=THREADS)
    keep_freed_memory: bool = setting(check=Flag())
    pursuit_standoff: Any = setting(check=PROBABILITY)


@dataclass
class RolloutConfig:
    """``aia-rollout`` (conf/rollout.yaml)."""

    env: Any = setting()
    num_worlds: int = setting(check=COUNT)
    policies: list[str] = setting(check=NamesFrom(ROLLOUT_POLICIES))
    seed: int = setting(check=SEED)
    device: str = setting(check=Device())
    compile: bool = setting(check=Flag())
    pursuit_standoff: Any = setting(check=PROBABILITY)


@dataclass
class EnvSettingConfig:
    """``conf/env_setting.yaml``: one env preset, as :func:`aia.envs.load_env_config` composes it."""

    env: Any = setting()


# The schemas by config name (conf/<name>.yaml): the apps' and the env factory's.
SCHEMAS: dict[str, type] = {"train": TrainConfig, "eval": EvalConfig, "rollout": RolloutConfig,
                            "env_setting": EnvSettingConfig}


def settings(schema: type, prefix: str = "") -> Iterator[tuple[str, dataclasses.Field]]:
    """Every leaf field of ``schema`` as ``(dotted key, field)``, in declaration order: nested schemas walked,
    a group's options walked in turn (a key two options share, once)."""
    seen: set[str] = set()
    types = typing.get_type_hints(schema)
    for item in dataclasses.fields(schema):
        key = prefix + item.name
        if "options" in item.metadata:
            children = (pair for option in dict.fromkeys(item.metadata["options"].values())
                        for pair in settings(option, key + "."))
        elif dataclasses.is_dataclass(types[item.name]):
            children = settings(types[item.name], key + ".")
        else:
            children = iter([(key, item)])
        for child_key, child in children:
            if child_key not in seen:
                seen.add(child_key)
                yield child_key, child


def keys_where(schema: type, flag: str) -> tuple[str, ...]:
    """The dotted keys of ``schema`` whose metadata sets ``flag`` (``"member"`` or ``"resume"``)."""
    return tuple(key for key, item in settings(schema) if item.metadata[flag])


def declared_check(schema: type, key: str) -> Check | None:
    """The check declared for dotted ``key`` (an entry of a list field: its list's) in ``schema``, if any."""
    key = key.split("[")[0]
    return next((item.metadata.get("check") for k, item in settings(schema) if k == key), None)


_STORE = ConfigStore.instance()
for _name, _schema in (("train_schema", TrainConfig), ("eval_schema", EvalConfig), ("rollout_schema", RolloutConfig),
                       ("algo_schema", AlgoConfig), ("adfq_schema", ADFQConfig),
                       ("exploration_schema", ExplorationConfig), ("egreedy_schema", EGreedyConfig),
                       ("logger_schema", LoggerConfig), ("mcap_schema", MCAPConfig)):
    _STORE.store(name=_name, node=_schema)
