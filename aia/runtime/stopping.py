"""Stopping a run cleanly on a signal: what a cluster's preemption or time limit sends (SIGTERM, SIGUSR1 with
SLURM's ``--signal``) and Ctrl-C (SIGINT).

:class:`StopOnSignals` only records the signal; the training loop checks :attr:`StopOnSignals.signal` after
every step and, at the end of the current episode (at most ``env.max_steps`` steps: a fraction of a second
for one learner, a few seconds for a large population), ends as at the end of its budget: it plays the
pending evaluations, writes every member's checkpoint, marks the logs stopped and closes them. The app then
exits with status ``128 + signal`` (143 for SIGTERM).
"""

from __future__ import annotations

import signal
import threading
from collections.abc import Callable
from types import FrameType

from aia.config.errors import Stopped

STOP_SIGNALS = (signal.SIGTERM, signal.SIGINT, signal.SIGUSR1)


class StopOnSignals:
    """A context manager that turns :data:`STOP_SIGNALS` into a request to stop (``signal``: the first one).

    ``on_signal(signum, first)`` is called after each signal is recorded (the population launcher forwards it to
    its workers); it runs in a signal handler, so it should only record, send signals or raise. Outside the main
    thread (where Python cannot install handlers, e.g. a launcher's worker thread) it installs nothing and the
    signals keep their default effect.
    """

    def __init__(self, on_signal: Callable[[int, bool], None] | None = None) -> None:
        self.signal: int | None = None
        self.on_signal = on_signal
        self._previous: dict[int, object] = {}

    def _handle(self, signum: int, frame: FrameType | None) -> None:
        first = self.signal is None
        if first:
            self.signal = signum
        if self.on_signal is not None:
            self.on_signal(signum, first)

    def __enter__(self) -> StopOnSignals:
        if threading.current_thread() is threading.main_thread():
            self._previous = {signum: signal.signal(signum, self._handle) for signum in STOP_SIGNALS}
        return self

    def __exit__(self, *exc_info: object) -> None:
        for signum, previous in self._previous.items():
            signal.signal(signum, previous)
        self._previous = {}

    @property
    def exit_status(self) -> int:
        """``128 + signal`` once a signal came (the shell's convention), else 0."""
        return 128 + self.signal if self.signal else 0


def interrupting() -> StopOnSignals:
    """A :class:`StopOnSignals` under which a stop signal raises :class:`~aia.config.errors.Stopped` at once: what
    runs without a loop that could stop at an episode's end (an evaluation, a population being set up) ends
    there, its ``finally`` clauses marking its logs stopped. A :class:`StopOnSignals` entered inside takes the
    signals over while it runs and hands them back when it ends."""
    def interrupt(signum: int, first: bool) -> None:
        raise Stopped(signum)

    return StopOnSignals(on_signal=interrupt)
