"""The training loop's progress bar: tqdm on this process's terminal, or its state forwarded to whoever draws it.

Populations that run in worker processes (``hydra/launcher=population`` with ``n_jobs > 1``) do not draw their
own bars: several processes' bars on one terminal line overwrite each other. A worker installs a sink
(:func:`forwarding`); the loop's bar then sends its state there, and the launcher draws one bar per running
population (``hydra_plugins/aia_population_launcher/display.py``).
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager

from tqdm import tqdm

# where a forwarded bar sends its state (None: bars draw themselves)
_sink: Callable[[dict], None] | None = None


@contextmanager
def forwarding(send: Callable[[dict], None]) -> Iterator[None]:
    """Within the block, :func:`progress_bar` returns bars that pass their state to ``send``."""
    global _sink
    previous, _sink = _sink, send
    try:
        yield
    finally:
        _sink = previous


def progress_bar(total: int, initial: int, desc: str) -> tqdm | ForwardedBar:
    """A bar counting frames: a ``tqdm`` bar, or inside :func:`forwarding` a :class:`ForwardedBar`."""
    if _sink is not None:
        return ForwardedBar(_sink, total, initial, desc)
    return tqdm(total=total, initial=initial, unit="frame", unit_scale=True, mininterval=1.0, desc=desc)


class ForwardedBar:
    """The part of tqdm's interface the loop uses (``update``, ``set_postfix``, ``close``), passing the bar's
    state (``{"n", "total", "desc", "postfix", "closed"}``) to ``send`` at most every ``interval_s`` seconds,
    and once more when it closes."""

    def __init__(self, send: Callable[[dict], None], total: int, initial: int, desc: str,
                 interval_s: float = 1.0) -> None:
        self.send, self.total, self.n, self.desc = send, total, initial, desc
        self.postfix = ""
        self.interval_s = interval_s
        self._sent_at = -float("inf")
        self._closed = False

    def update(self, n: int = 1) -> None:
        """Count ``n`` more frames."""
        self.n += n
        if time.monotonic() - self._sent_at >= self.interval_s:
            self._send()

    def set_postfix(self, **values: object) -> None:
        """Show ``key=value`` pairs after the count (as tqdm's ``set_postfix``)."""
        self.postfix = ", ".join(f"{key}={value}" for key, value in values.items())

    def close(self) -> None:
        """Send the final state (once)."""
        if not self._closed:
            self._closed = True
            self._send()

    def _send(self) -> None:
        self._sent_at = time.monotonic()
        self.send({"n": self.n, "total": self.total, "desc": self.desc, "postfix": self.postfix,
                   "closed": self._closed})
