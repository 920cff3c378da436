"""Where a loop's wall-clock time goes (seconds accumulated per named phase), and how fast the machine is now.

``python -m aia.timing`` prints the machine's float32 matmul rate (:func:`sgemm_gflops`) in GFLOP/s.
"""

from __future__ import annotations

import time


class PhaseTimer:
    """Accumulates wall-clock seconds per phase: ``with timer("update"): ...``.

    ``seconds`` maps each phase to its total; it is the dict passed in (updated in place, so a counter
    object that holds it, such as a checkpointed training state, always has the current totals). A phase
    costs about a microsecond to time (a plain context object, no generator), so the training loop can time
    several per frame.
    """

    def __init__(self, seconds: dict[str, float] | None = None) -> None:
        self.seconds: dict[str, float] = {} if seconds is None else seconds

    def add(self, phase: str, seconds: float) -> None:
        """Count ``seconds`` more for ``phase``."""
        self.seconds[phase] = self.seconds.get(phase, 0.0) + seconds

    def summary(self) -> str:
        """One line, largest phase first: ``"update 52% (41.0 s), collect 30% (23.7 s), ..."``."""
        total = sum(self.seconds.values())
        if total <= 0:
            return "no time measured"
        ranked = sorted(self.seconds.items(), key=lambda item: -item[1])
        return ", ".join(f"{phase} {100 * seconds / total:.0f}% ({seconds:.1f} s)" for phase, seconds in ranked)

    def __call__(self, phase: str) -> _TimedPhase:
        """A context manager that counts the wall-clock time of its block for ``phase``."""
        return _TimedPhase(self, phase)


class _TimedPhase:
    """One timed ``with`` block of a :class:`PhaseTimer` (counted also when the block raises)."""

    __slots__ = ("timer", "phase", "start")

    def __init__(self, timer: PhaseTimer, phase: str) -> None:
        self.timer = timer
        self.phase = phase

    def __enter__(self) -> None:
        self.start = time.perf_counter()

    def __exit__(self, *exc_info: object) -> None:
        self.timer.add(self.phase, time.perf_counter() - self.start)


def sgemm_gflops(size: int = 1024, calls: int = 30) -> float:
    """The machine's float32 matmul rate now, in GFLOP/s, on torch's current threads: ``calls`` products of two
    ``size x size`` matrices after three warm-up products. The ceiling of a batched update, and a gauge of a
    shared VM's speed at the hour a timing was taken (on the project's 2-core VM it swings by up to 3x)."""
    import torch  # here: the phase timer itself needs no torch

    a, b = torch.randn(size, size), torch.randn(size, size)
    for _ in range(3):
        a @ b
    start = time.perf_counter()
    for _ in range(calls):
        a @ b
    return 2 * size**3 * calls / (time.perf_counter() - start) / 1e9


if __name__ == "__main__":
    print(f"{sgemm_gflops():.0f}")
