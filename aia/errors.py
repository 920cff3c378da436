"""The errors the apps report in one line: invalid user input (a config value, a map file, a command-line
argument; exit status 2) and a sweep job lost with the process that ran it (exit status 1)."""

from __future__ import annotations

from typing import Any


class ConfigError(ValueError):
    """An invalid input: the ``key`` (a dotted config key or a map field), its ``value`` and what is
    ``allowed``; ``source`` names the file the value came from, if any. ``str()`` is one line:
    ``[source: ]key=value: expected allowed``. The apps print it and exit with status 2
    (:mod:`aia.apps.hydra_app`)."""

    def __init__(self, key: str, value: Any, allowed: str, source: str | None = None) -> None:
        self.key, self.value, self.allowed, self.source = key, value, allowed, source
        super().__init__(key, value, allowed, source)  # the arguments: pickling (sweep workers) rebuilds it

    def __str__(self) -> str:
        where = f"{self.source}: " if self.source else ""
        return " ".join(f"{where}{self.key}={self.value!r}: expected {self.allowed}".split())


class JobFailed(RuntimeError):
    """A sweep job that failed for a reason outside its config: the process running it died (killed for its
    memory, a crash). The apps print it in one line and exit with status 1 (:mod:`aia.apps.hydra_app`)."""


def one_line(message: object) -> str:
    """``message`` (an exception or text) on one line: a listing of indented lines (Hydra's available
    options) becomes a comma-separated list after its heading."""
    lines = [line for line in str(message).splitlines() if line.strip()]
    text = ""
    for previous, line in zip(["", *lines], lines, strict=False):
        listed = line[:1].isspace() and line.strip()
        separator = "" if not text else ", " if listed and previous[:1].isspace() else " "
        text += separator + line.strip()
    return text
