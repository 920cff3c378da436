"""Checks of single config values: each raises :class:`~aia.config.errors.ConfigError` naming the key, the value
and what is allowed. The env config (:mod:`aia.envs.config`), the map loader and the apps' validation
(:mod:`aia.config.validation`) are written with them.

The check classes (:class:`Number`, :class:`Choice`, :class:`Flag`, :class:`Device`, :class:`Widths`,
:class:`NamesFrom`) are the same checks as values: the typed schemas (:mod:`aia.config.schemas`) declare a
field's range with one, the validation layer calls it, and its ``allowed`` text also words a value of the wrong
type that Hydra refuses while composing.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass
from numbers import Integral, Real
from typing import Any, Protocol

from omegaconf import ListConfig, OmegaConf

from aia.config.errors import ConfigError


def require(ok: bool, key: str, value: Any, allowed: str, source: str | None = None) -> None:
    """Raise ``ConfigError(key, value, allowed, source)`` unless ``ok``."""
    if not ok:
        raise ConfigError(key, value, allowed, source)


class Check(Protocol):
    """A declared range of one config value: ``allowed`` in words, and a call that raises ``ConfigError``."""

    @property
    def allowed(self) -> str: ...

    def __call__(self, key: str, value: Any) -> None: ...


@dataclass(frozen=True)
class Number:
    """A number (an integer if ``integer``) with ``> gt``, ``>= ge``, ``<= le``; ``None`` passes when
    ``optional``."""

    gt: float | None = None
    ge: float | None = None
    le: float | None = None
    integer: bool = False
    optional: bool = False

    @property
    def allowed(self) -> str:
        bounds = [f"> {self.gt}" if self.gt is not None else "", f">= {self.ge}" if self.ge is not None else "",
                  f"<= {self.le}" if self.le is not None else ""]
        bounds_text = " and ".join(b for b in bounds if b)
        text = f"{'an integer' if self.integer else 'a number'}{' ' + bounds_text if bounds_text else ''}"
        return text + (" or null" if self.optional else "")

    def __call__(self, key: str, value: Any, source: str | None = None) -> None:
        if value is None and self.optional:
            return
        ok = isinstance(value, Integral if self.integer else Real) and not isinstance(value, bool)
        ok = ok and ((self.gt is None or value > self.gt) and (self.ge is None or value >= self.ge)
                     and (self.le is None or value <= self.le))
        require(ok, key, value, self.allowed, source)


@dataclass(frozen=True)
class Choice:
    """One of ``choices``."""

    choices: tuple[Any, ...]

    @property
    def allowed(self) -> str:
        return f"one of {list(self.choices)}"

    def __call__(self, key: str, value: Any, source: str | None = None) -> None:
        require(value in self.choices, key, value, self.allowed, source)


@dataclass(frozen=True)
class Flag:
    """A boolean."""

    @property
    def allowed(self) -> str:
        return "true or false"

    def __call__(self, key: str, value: Any) -> None:
        require(isinstance(value, bool), key, value, self.allowed)


@dataclass(frozen=True)
class Device:
    """A torch device that this machine has (``cpu``, ``cuda``, ``cuda:1``, ``mps``)."""

    @property
    def allowed(self) -> str:
        return "a torch device such as cpu, cuda or cuda:0"

    def __call__(self, key: str, value: Any) -> None:
        if value == "cpu":  # the default: the apps' --help and refusals of other keys answer without loading torch
            return
        import torch

        try:
            device = torch.device(value)
        except (RuntimeError, TypeError):
            raise ConfigError(key, value, self.allowed) from None
        if device.type == "cuda":
            count = torch.cuda.device_count() if torch.cuda.is_available() else 0
            require(count > (device.index or 0), key, value,
                    f"a device this machine has: torch sees {count} CUDA device(s); use device=cpu")
        elif device.type == "mps":
            require(torch.backends.mps.is_available(), key, value,
                    "a device this machine has: no MPS; use device=cpu")
        else:
            require(device.type == "cpu", key, value, "cpu, cuda or mps")


@dataclass(frozen=True)
class Widths:
    """A non-empty list of layer widths, each an integer >= 1."""

    @property
    def allowed(self) -> str:
        return "a non-empty list of layer widths >= 1, e.g. [128, 128, 128]"

    def __call__(self, key: str, value: Any) -> None:
        widths = _plain_list(value)
        require(isinstance(widths, list) and len(widths) > 0 and all(map(_positive_integer, widths)),
                key, widths, self.allowed)


@dataclass(frozen=True)
class ConvLayers:
    """A non-empty list of convolutions, each ``[filters, kernel, stride]`` of integers >= 1."""

    @property
    def allowed(self) -> str:
        return "a non-empty list of [filters, kernel, stride], each an integer >= 1"

    def __call__(self, key: str, value: Any) -> None:
        layers = _plain_list(value)
        require(isinstance(layers, (list, tuple)) and len(layers) > 0
                and all(isinstance(layer, (list, tuple)) and len(layer) == 3 and all(map(_positive_integer, layer))
                        for layer in layers), key, layers, self.allowed)


@dataclass(frozen=True)
class NamesFrom:
    """A non-empty list of names from ``names``."""

    names: tuple[str, ...]

    @property
    def allowed(self) -> str:
        return f"a non-empty list of {list(self.names)}"

    def __call__(self, key: str, value: Any) -> None:
        names = _plain_list(value)
        require(isinstance(names, list) and len(names) > 0 and set(names) <= set(self.names), key, names,
                self.allowed)


def _positive_integer(value: Any) -> bool:
    """An int (not a bool) >= 1: a layer width, a filter count, a kernel size or a stride."""
    return isinstance(value, int) and not isinstance(value, bool) and value >= 1


def _plain_list(value: Any) -> Any:
    """A ListConfig as a plain list (shown as ``[1, 2]`` in a message); anything else as it is."""
    return OmegaConf.to_container(value) if isinstance(value, ListConfig) else value


def check_number(key: str, value: Any, *, gt: float | None = None, ge: float | None = None,
                 le: float | None = None, integer: bool = False, optional: bool = False,
                 source: str | None = None) -> None:
    """``value`` is a number (an integer if ``integer``) with ``> gt``, ``>= ge``, ``<= le``; ``None`` passes
    when ``optional``."""
    Number(gt=gt, ge=ge, le=le, integer=integer, optional=optional)(key, value, source)


def check_choice(key: str, value: Any, choices: Iterable[Any], source: str | None = None) -> None:
    """``value`` is one of ``choices``."""
    Choice(tuple(choices))(key, value, source)


def check_flag(key: str, value: Any) -> None:
    """``value`` is a boolean."""
    Flag()(key, value)
