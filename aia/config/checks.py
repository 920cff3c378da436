"""Checks of single config values: each raises :class:`~aia.config.errors.ConfigError` naming the key, the value and
what is allowed. The env config (:mod:`aia.envs.config`), the map loader and the apps' validation
(:mod:`aia.config.validation`) are written with them."""

from __future__ import annotations

from collections.abc import Iterable
from numbers import Integral, Real
from typing import Any

import torch

from aia.config.errors import ConfigError


def require(ok: bool, key: str, value: Any, allowed: str, source: str | None = None) -> None:
    """Raise ``ConfigError(key, value, allowed, source)`` unless ``ok``."""
    if not ok:
        raise ConfigError(key, value, allowed, source)


def check_number(key: str, value: Any, *, gt: float | None = None, ge: float | None = None,
                 le: float | None = None, integer: bool = False, optional: bool = False,
                 source: str | None = None) -> None:
    """``value`` is a number (an integer if ``integer``) with ``> gt``, ``>= ge``, ``<= le``; ``None`` passes
    when ``optional``."""
    if value is None and optional:
        return
    kind = Integral if integer else Real
    bounds = [f"> {gt}" if gt is not None else "", f">= {ge}" if ge is not None else "",
              f"<= {le}" if le is not None else ""]
    allowed = " and ".join(b for b in bounds if b)
    allowed = f"{'an integer' if integer else 'a number'}{' ' + allowed if allowed else ''}"
    allowed += " or null" if optional else ""
    ok = isinstance(value, kind) and not isinstance(value, bool)
    ok = ok and (gt is None or value > gt) and (ge is None or value >= ge) and (le is None or value <= le)
    require(ok, key, value, allowed, source)


def check_choice(key: str, value: Any, choices: Iterable[Any], source: str | None = None) -> None:
    """``value`` is one of ``choices``."""
    choices = list(choices)
    require(value in choices, key, value, f"one of {choices}", source)


def check_flag(key: str, value: Any) -> None:
    """``value`` is a boolean."""
    require(isinstance(value, bool), key, value, "true or false")


def check_device(key: str, value: Any) -> None:
    """``value`` names a torch device that this machine has (``cpu``, ``cuda``, ``cuda:1``, ``mps``)."""
    try:
        device = torch.device(value)
    except (RuntimeError, TypeError):
        raise ConfigError(key, value, "a torch device such as cpu, cuda or cuda:0") from None
    if device.type == "cuda":
        count = torch.cuda.device_count() if torch.cuda.is_available() else 0
        require(count > (device.index or 0), key, value,
                f"a device this machine has: torch sees {count} CUDA device(s); use device=cpu")
    elif device.type == "mps":
        require(torch.backends.mps.is_available(), key, value, "a device this machine has: no MPS; use device=cpu")
    else:
        require(device.type == "cpu", key, value, "cpu, cuda or mps")
