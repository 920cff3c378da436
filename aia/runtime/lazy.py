"""Names of a package imported on first use (PEP 562), so that importing the package loads none of their modules:
the apps read their configs, and ``aia-log`` its logs, without loading torch."""

from __future__ import annotations

from collections.abc import Callable, Mapping
from importlib import import_module


def lazy_names(package: str, modules: Mapping[str, str]) -> Callable[[str], object]:
    """A module ``__getattr__`` for ``package`` that imports name ``n`` from module ``modules[n]`` when first asked
    for; any other name is an ``AttributeError``, as for a module without it."""

    def __getattr__(name: str) -> object:
        if name in modules:
            return getattr(import_module(modules[name]), name)
        raise AttributeError(f"module {package!r} has no attribute {name!r}")

    return __getattr__
