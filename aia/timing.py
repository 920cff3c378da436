"""Where a loop's wall-clock time goes: seconds accumulated per named phase."""

from __future__ import annotations

import time
from collections.abc import Iterator
from contextlib import contextmanager


class PhaseTimer:
    """Accumulates wall-clock seconds per phase: ``with timer("update"): ...``.

    ``seconds`` maps each phase to its total; it is the dict passed in (updated in place, so a counter
    object that holds it, such as a checkpointed training state, always has the current totals).
    """

    def __init__(self, seconds: dict[str, float] | None = None) -> None:
        self.seconds: dict[str, float] = {} if seconds is None else seconds

    def add(self, phase: str, seconds: float) -> None:
        """Count ``seconds`` more for ``phase``."""
        self.seconds[phase] = self.seconds.get(phase, 0.0) + seconds

    @contextmanager
    def __call__(self, phase: str) -> Iterator[None]:
        start = time.perf_counter()
        try:
            yield
        finally:
            self.add(phase, time.perf_counter() - start)

    def summary(self) -> str:
        """One line, largest phase first: ``"update 52% (41.0 s), collect 30% (23.7 s), ..."``."""
        total = sum(self.seconds.values())
        if total <= 0:
            return "no time measured"
        ranked = sorted(self.seconds.items(), key=lambda item: -item[1])
        return ", ".join(f"{phase} {100 * seconds / total:.0f}% ({seconds:.1f} s)" for phase, seconds in ranked)
