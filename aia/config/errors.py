"""The errors the apps report in one line: invalid user input (a config value, a map file, a command-line
argument; exit status 2), a run that failed for a reason outside its config (:class:`RunFailed`: a sweep job
lost with its process, a file that could not be written, a run folder in use; exit status 1), and a run ended by
a stop signal (:class:`Stopped`; exit status 128 + signal)."""

from __future__ import annotations

import signal
from typing import Any


class ConfigError(ValueError):
    """An invalid input: the ``key`` (a dotted config key or a map field), its ``value`` and what is
    ``allowed``; ``source`` names the file the value came from, if any. ``str()`` is one line:
    ``[source: ]key=value: expected allowed`` (``None`` as ``null``). The apps print it and exit with status 2
    (:mod:`aia.apps.hydra_app`)."""

    def __init__(self, key: str, value: Any, allowed: str, source: str | None = None) -> None:
        self.key, self.value, self.allowed, self.source = key, value, allowed, source
        super().__init__(key, value, allowed, source)  # the arguments: pickling (sweep workers) rebuilds it

    def __str__(self) -> str:
        where = f"{self.source}: " if self.source else ""
        value = "null" if self.value is None else repr(self.value)  # as a command line or a YAML file spells it
        return " ".join(f"{where}{self.key}={value}: expected {self.allowed}".split())


class RunFailed(RuntimeError):
    """A run that could not go on for a reason outside its config; ``str()`` is one line saying what to do.
    The apps print it and exit with status 1 (:mod:`aia.apps.hydra_app`)."""


class JobFailed(RunFailed):
    """A sweep job whose process died (killed for its memory, a crash)."""


class WriteFailed(RunFailed):
    """A file of the run could not be written (a full disk, a lost mount, no permission): its ``path`` and the
    OS's ``reason``."""

    def __init__(self, path: object, reason: str) -> None:
        self.path, self.reason = str(path), reason
        super().__init__(path, reason)  # the arguments: pickling (sweep workers) rebuilds it

    def __str__(self) -> str:
        return (f"could not write {self.path} ({self.reason}): make room or fix the folder, then run again "
                "(aia-train: resume=auto continues from the last whole checkpoint, which is kept)")


class Stopped(BaseException):
    """A run ended at once by a stop signal (SIGINT, SIGTERM, SIGUSR1; :func:`aia.runtime.stopping.interrupting`),
    where no training loop was there to end it at an episode's end. A ``BaseException``, as ``KeyboardInterrupt``
    is: no ``except Exception`` takes it for a failure. ``str()`` is the signal's name; the apps exit with
    :attr:`exit_status`."""

    def __init__(self, signum: int) -> None:
        self.signum = signum
        super().__init__(signum)  # the argument: pickling rebuilds it

    def __str__(self) -> str:
        return signal.Signals(self.signum).name

    @property
    def exit_status(self) -> int:
        """``128 + signal``, the shell's convention (143 for SIGTERM)."""
        return 128 + self.signum


def os_error_text(error: OSError) -> str:
    """``"[Errno 28] No space left on device"`` without the file name (the caller names the file)."""
    return f"[Errno {error.errno}] {error.strerror}" if error.errno is not None else str(error)


class FolderLocked(RunFailed):
    """A run folder in use by another run (:mod:`aia.training.folder_lock`)."""


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
