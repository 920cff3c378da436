"""A run's log in segments: ``run.mcap``, then ``run.1.mcap``, ``run.2.mcap``, ... one per resume.

A resumed run never rewrites the log it continues (a log cut by ``kill -9`` stays as it was): it writes the
next segment, whose metadata ``run.resumed_after_ns`` is the wall-clock time its checkpoint was written.
:func:`aia.logging.read_run` joins the segments into one history, dropping what an earlier segment logged
after that time (the steps the resumed run does again).
"""

from __future__ import annotations

import re
from pathlib import Path

RESUMED_AFTER_KEY = "resumed_after_ns"  # metadata ``run`` of a later segment: its checkpoint's time
_SEGMENT = re.compile(r"^(?P<stem>.+)\.(?P<index>\d+)(?P<suffix>\.mcap)$")


def later_segments(base: Path) -> list[Path]:
    """The segments after ``base`` that exist, in order (``run.1.mcap``, ``run.2.mcap``, ...)."""
    found = []
    while (segment := base.with_name(f"{base.stem}.{len(found) + 1}{base.suffix}")).exists():
        found.append(segment)
    return found


def last_segment(base: Path) -> Path:
    """The last segment of the log ``base`` that exists (``base`` itself when it has no later one)."""
    return (later_segments(base) or [base])[-1]


def next_segment(base: Path) -> Path:
    """Where a run logging to ``base`` writes: ``base`` itself if it does not exist, else the next segment."""
    if not base.exists():
        return base
    return base.with_name(f"{base.stem}.{len(later_segments(base)) + 1}{base.suffix}")


def is_later_segment(path: Path) -> bool:
    """Whether ``path`` is a later segment of a log beside it (``run.1.mcap`` next to ``run.mcap``)."""
    match = _SEGMENT.match(path.name)
    return bool(match) and path.with_name(match["stem"] + match["suffix"]).exists()
