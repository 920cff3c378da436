"""What the launcher shows of populations running in worker processes: one progress bar per population.

Workers forward their printed lines and their training bar's state (``aia.training.progress``) instead of
writing to the terminal themselves, so this process is the terminal's only writer: on a terminal each running
population has a bar of its own line (``jobs 0-9: dqn,ddqn x10  41%|████ | 12.3k/30.0k [...] score=..``),
and lines (the workers' and the launcher's) are printed above the bars; elsewhere (a log file, a SLURM job's
output) a population's progress is one plain line at most every ``every_s`` seconds (the launcher's
``progress_every_s``), and one at its end.
"""

from __future__ import annotations

import sys
import time
from collections.abc import Sequence

from tqdm import tqdm


class PopulationDisplay:
    """Bars or progress lines for the populations (by their index in ``names``), at most ``slots`` at once."""

    def __init__(self, names: Sequence[str], slots: int, terminal: bool | None = None, every_s: float = 30.0
                 ) -> None:
        self.names = names
        self.terminal = sys.stderr.isatty() if terminal is None else terminal
        self.every_s = every_s
        self._free = list(range(slots))  # bar lines not in use
        self._bars: dict[int, tuple[tqdm, int]] = {}  # population -> its bar and line
        self._started: dict[int, tuple[float, int]] = {}  # population -> when and at which frame it first reported
        self._reported: dict[int, float] = {}  # population -> when its last progress line was printed

    def progress(self, index: int, state: dict) -> None:
        """Show population ``index``'s bar state (``aia.training.progress.ForwardedBar``)."""
        now = time.monotonic()
        self._started.setdefault(index, (now, state["n"]))
        if self.terminal:
            self._bar(index, state)
        elif state["closed"] or now - self._reported.get(index, -float("inf")) >= self.every_s:
            self._reported[index] = now
            self.write(self._line(index, state, now))

    def write(self, line: str) -> None:
        """Print ``line`` (to stdout) above the bars."""
        if self._bars:
            tqdm.write(line, file=sys.stdout)
        else:
            print(line, flush=True)

    def finish(self, index: int) -> None:
        """Population ``index`` has ended: its bar goes, its line is free."""
        self._started.pop(index, None)
        self._reported.pop(index, None)
        if index in self._bars:
            bar, line = self._bars.pop(index)
            bar.close()
            self._free.append(line)

    def close(self) -> None:
        """Remove every bar."""
        for index in list(self._bars):
            self.finish(index)

    def _bar(self, index: int, state: dict) -> None:
        if index not in self._bars:
            self._free.sort()
            line = self._free.pop(0) if self._free else len(self._bars)
            bar = tqdm(total=state["total"], initial=state["n"], desc=f"{self.names[index]}: {state['desc']}",
                       unit="frame", unit_scale=True, position=line, leave=False, mininterval=1.0)
            self._bars[index] = bar, line
        bar, _ = self._bars[index]
        bar.n = state["n"]
        bar.set_postfix_str(state["postfix"], refresh=False)
        bar.refresh()

    def _line(self, index: int, state: dict, now: float) -> str:
        """``population launcher: jobs 0-9: dqn x10 12,000/30,000 frames (40%), 150 frames/s, score=..``."""
        n, total = state["n"], state["total"]
        since, first = self._started[index]
        rate = f", {(n - first) / (now - since):,.0f} frames/s" if now > since and n > first else ""
        postfix = f", {state['postfix']}" if state["postfix"] else ""
        percent = f" ({100 * n / total:.0f}%)" if total else ""
        return (f"population launcher: {self.names[index]}: {state['desc']} {n:,}/{total:,} frames"
                f"{percent}{rate}{postfix}")
