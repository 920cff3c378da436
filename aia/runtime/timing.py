"""Where a loop's wall-clock time goes (seconds accumulated per named phase), and how fast the machine is now.

``python -m aia.runtime.timing`` prints the machine's float32 matmul rate (:func:`sgemm_gflops`) in GFLOP/s.
"""

from __future__ import annotations

import datetime
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


def utc_now() -> str:
    """The time now, UTC, to the second (ISO 8601): when a measurement was taken, to set beside the machine's
    speed then (a shared VM's speed swings between hours)."""
    return datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds")


def sgemm_gflops(size: int | None = None, calls: int = 30, device: str = "cpu") -> float:
    """The machine's float32 matmul rate now, in GFLOP/s, on torch's current threads (or ``device``'s GPU):
    ``calls`` products of two ``size x size`` matrices (1,024 on a CPU, 8,192 on a GPU) after three warm-up
    products. The ceiling of a batched update, and a gauge of a shared VM's speed at the hour a timing was
    taken (on the project's 2-core VM it swings by up to 3x)."""
    import torch  # here: the phase timer itself needs no torch

    on_gpu = torch.device(device).type == "cuda"
    size = size or (8192 if on_gpu else 1024)
    a, b = torch.randn(size, size, device=device), torch.randn(size, size, device=device)
    for _ in range(3):
        a @ b
    synchronize(device)
    start = time.perf_counter()
    for _ in range(calls):
        a @ b
    synchronize(device)
    return 2 * size**3 * calls / (time.perf_counter() - start) / 1e9


def synchronize(device: str) -> None:
    """Wait for ``device``'s queued work (a GPU's kernels run after their launch returns); nothing on a CPU."""
    import torch

    if torch.device(device).type == "cuda":
        torch.cuda.synchronize(device)


if __name__ == "__main__":
    from aia.runtime.process_exit import freeze_at_exit

    freeze_at_exit()
    print(f"{sgemm_gflops():.0f}")
