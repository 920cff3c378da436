"""Composing a config of ``pkg://aia.conf`` from code, inside a running Hydra app or outside one, and the one-line
error of a command line (or a list of overrides) that Hydra could not compose."""

from __future__ import annotations

import dataclasses
import re
import typing
from collections.abc import Mapping, Sequence
from contextlib import nullcontext
from typing import Any

from hydra import compose, initialize_config_module
from hydra.core.global_hydra import GlobalHydra
from omegaconf import DictConfig, OmegaConf
from omegaconf.errors import ConfigKeyError, OmegaConfBaseException, ValidationError

from aia.config.errors import ConfigError, one_line
from aia.config.schemas import declared_check

# the override in Hydra's message on a key the config does not have (or a key under a value)
_OVERRIDE_IN_MESSAGE = re.compile(r"(?:use \+|Error merging override )(?P<key>[^=\s]+)=(?P<value>.*)")


def compose_config(config_name: str, overrides: Sequence[str] = ()) -> DictConfig:
    """``config_name`` (``conf/<name>.yaml``) composed with Hydra-style ``overrides``: in the running app's Hydra
    when there is one (an app's job), else in a Hydra context of its own. Hydra's and OmegaConf's errors pass
    through to the caller."""
    context = (nullcontext() if GlobalHydra.instance().is_initialized()
               else initialize_config_module(config_module="aia.conf", version_base="1.3"))
    with context:
        return compose(config_name=config_name, overrides=list(overrides))


def composition_error(err: Exception, schema: type) -> ConfigError | None:
    """The :class:`ConfigError` of an override Hydra could not compose into a config of ``schema`` (an app's, or
    :class:`~aia.config.schemas.EnvSettingConfig`), where it names one: a value of the wrong type, worded as the
    validation layer words a bad value where its field declares a check (``frames='abc': expected an integer
    >= 1``), else by the field's type (``env.sensor.range='abc': expected a number``); a key the config does not
    have, with the keys it has there (:func:`~aia.config.validation.unknown_key_allowed`; Hydra would suggest
    adding it with ``+``). ``None`` otherwise."""
    # imported here: the validation layer checks env configs through the env factory, which composes through
    # this module
    from aia.config.validation import keys_allowed, unknown_key_allowed

    cause = err.__cause__
    wrong_type = isinstance(cause, ValidationError) and bool(cause.full_key)
    if wrong_type:
        check = declared_check(schema, cause.full_key)
        if check is not None:
            return ConfigError(cause.full_key, cause.value, check.allowed)
    override = _OVERRIDE_IN_MESSAGE.search(str(err))
    if override and not override["key"].startswith("hydra."):
        allowed = unknown_key_allowed(schema, override["key"])
        owner = getattr(cause, "object_type", None)
        if allowed is None and dataclasses.is_dataclass(owner):
            parent, _, part = override["key"].rpartition(".")
            names = [item.name for item in dataclasses.fields(owner)]
            if part not in names:  # a key of another option of its group (algo=dqn has no sd_max)
                allowed = keys_allowed(names, parent, part)
        if allowed is not None:
            return ConfigError(override["key"], override["value"], allowed)
    return ConfigError(cause.full_key, cause.value, _type_wanted(cause)) if wrong_type else None


def node_error(err: OmegaConfBaseException, node: Any, schema: type, prefix: str) -> ConfigError:
    """The :class:`ConfigError` of a config ``node`` (a user's dict or ``DictConfig``) that OmegaConf could not
    merge into its dataclass ``schema`` (``err``): the node sits at dotted ``prefix`` (``"env."``,
    ``"planner."``), and the error is worded as :func:`composition_error` words the same value on a command line
    (a field's declared check, else its type; a key it does not have, with the keys it has there)."""
    from aia.config.validation import unknown_key_allowed  # see composition_error

    key, value = err.full_key, err.value
    if not key:  # a value where the dataclass has a group of keys: OmegaConf's merge does not say where
        key, value = _value_for_group(node, err.object_type) or ("", value)
    elif isinstance(err, ConfigKeyError):
        value = OmegaConf.select(OmegaConf.create(node), key)
    named = (prefix + key).rstrip(".")
    if isinstance(err, ValidationError):
        check = declared_check(schema, key) if key else None
        return ConfigError(named, value, check.allowed if check is not None else _type_wanted(err, named))
    allowed = unknown_key_allowed(schema, key, prefix) if isinstance(err, ConfigKeyError) else None
    return ConfigError(named, value, allowed or f"a value of the field's type ({one_line(err.msg)})")


def _value_for_group(node: Any, dataclass: type | None, prefix: str = "") -> tuple[str, Any] | None:
    """The first dotted key of ``node`` (a mapping) holding a value where ``dataclass`` has a dataclass field (a
    group of keys), and the value; None if there is none."""
    if dataclass is None or not isinstance(node, Mapping | DictConfig):
        return None
    hints = typing.get_type_hints(dataclass)
    for name, value in node.items():
        hint = hints.get(str(name))
        if dataclasses.is_dataclass(hint):
            if not isinstance(value, Mapping | DictConfig):
                return prefix + str(name), value
            found = _value_for_group(value, hint, f"{prefix}{name}.")
            if found:
                return found
    return None


# OmegaConf's words for a field's type in its conversion errors, and ours
_TYPE_WORDS = {"Float": "a number", "Integer": "an integer", "Boolean": "true or false"}


def _type_wanted(cause: ValidationError, key: str | None = None) -> str:
    """What the field at ``key`` (the error's own by default) wants, from OmegaConf's error on a value of another
    type."""
    key = key or cause.full_key
    message = cause.msg.splitlines()[0]
    for word, wanted in _TYPE_WORDS.items():
        if message.endswith(f"could not be converted to {word}"):
            return wanted
    if "is not a ListConfig" in message:
        return "a list ([a, b, ...])"
    if "is not a subclass of" in message:
        return f"keys under {key} ({key}.<key>=<value>), not a value"
    return f"a value of the field's type ({message})"
