"""One writer per run folder: a run holds ``<run folder>/run.lock`` while it writes there.

The lock file is created exclusively (``O_CREAT | O_EXCL``, atomic on local disks and NFS) and names its holder:
host, pid and start time. A run that finds the folder locked

* takes the lock over when its holder is provably gone: the same host, and no process with that pid;
* else waits up to ``lock_wait_s`` seconds (a requeued cluster job whose earlier copy is still stopping) and then
  gives up with :class:`~aia.config.errors.FolderLocked`, one line naming the holder and the lock file.

The lock is released (the file removed, if it is still this run's) on every exit that runs Python's cleanup:
the end of the run, an error, Ctrl-C, SIGTERM. A run killed outright (SIGKILL, a lost node) leaves its lock
behind: on the same host the next run takes it over; from another host it must be deleted by hand (the line
says so), since no host can tell whether a process on another is gone.
"""

from __future__ import annotations

import contextlib
import json
import os
import socket
import time
from collections.abc import Iterator, Sequence
from pathlib import Path

from aia.config.errors import FolderLocked, WriteFailed, os_error_text
from aia.runtime.timing import utc_now

LOCK_NAME = "run.lock"
_POLL_S = 0.5  # how often a waiting run looks at the lock again


def _me() -> dict[str, object]:
    return {"host": socket.gethostname(), "pid": os.getpid(),
            "since": utc_now()}


def _holder(lock: Path) -> dict | None:
    """Who holds ``lock`` (its JSON), or None when it is gone, empty or unreadable (a lock being written)."""
    try:
        holder = json.loads(lock.read_text())
    except (OSError, ValueError):
        return None
    return holder if isinstance(holder, dict) else None


def _gone(holder: dict) -> bool:
    """Whether ``holder`` is provably gone: on this host, and no process has its pid."""
    if holder.get("host") != socket.gethostname() or not isinstance(holder.get("pid"), int):
        return False
    try:
        os.kill(holder["pid"], 0)  # signal 0: only asks whether the process exists
    except ProcessLookupError:
        return True
    except PermissionError:  # it exists, another user's
        pass
    return False


def _take_over(lock: Path, stale: dict) -> None:
    """Remove ``lock`` if it is still ``stale``'s: renamed first, so that of two runs taking over one stale lock
    only one removes it, and a live lock renamed in between is put back."""
    moved = lock.with_name(f"{lock.name}.stale.{os.getpid()}")
    try:
        os.rename(lock, moved)
    except FileNotFoundError:
        return  # taken over by another run already
    if _holder(moved) == stale:
        moved.unlink()
    else:
        with contextlib.suppress(FileExistsError):
            os.link(moved, lock)
        moved.unlink()


def _create(lock: Path) -> dict | None:
    """Create ``lock`` naming this process (returned), or None if it exists; a failed write (a full disk, a
    read-only folder) raises :class:`~aia.config.errors.WriteFailed` and leaves no lock file."""
    try:
        lock.parent.mkdir(parents=True, exist_ok=True)
        descriptor = os.open(lock, os.O_CREAT | os.O_EXCL | os.O_WRONLY, 0o644)
    except FileExistsError:
        return None
    except OSError as err:
        raise WriteFailed(lock, os_error_text(err)) from None
    me = _me()
    try:
        with os.fdopen(descriptor, "w") as file:
            json.dump(me, file)
    except OSError as err:
        lock.unlink(missing_ok=True)
        raise WriteFailed(lock, os_error_text(err)) from None
    return me


def _acquire(folder: Path, wait_s: float) -> dict:
    """Hold ``folder``'s lock (waiting up to ``wait_s`` seconds for a live holder); returns the holder written."""
    lock = folder / LOCK_NAME
    deadline = time.monotonic() + wait_s
    while (me := _create(lock)) is None:
        holder = _holder(lock)
        if holder is not None and _gone(holder):
            print(f"taking over {lock}: its run (pid {holder['pid']} on this host) is gone")
            _take_over(lock, holder)
        elif time.monotonic() < deadline:
            time.sleep(min(_POLL_S, max(0.0, deadline - time.monotonic())))
        else:
            raise FolderLocked(_refusal(lock, holder, wait_s))
    return me


def _refusal(lock: Path, holder: dict | None, wait_s: float) -> str:
    """The one line of a run refused by a held lock."""
    who = (f"pid {holder.get('pid')} on host {holder.get('host')} since {holder.get('since')}" if holder
           else "a run whose lock file is empty or unreadable")
    waited = f" (waited {wait_s:g} s)" if wait_s else ""
    return (f"{lock.parent} is in use by another run: {who}{waited}; give this run its own folder or wait for "
            f"that one to end (lock_wait_s=<seconds>); if that run is gone, delete {lock}")


def _release(folder: Path, holder: dict) -> None:
    """Remove ``folder``'s lock if ``holder`` still holds it."""
    lock = folder / LOCK_NAME
    if _holder(lock) == holder:
        lock.unlink(missing_ok=True)


@contextlib.contextmanager
def folder_locks(folders: Sequence[Path], wait_s: float) -> Iterator[None]:
    """Hold every folder's lock for the ``with`` block (a population locks each member's folder); a folder in use
    raises :class:`~aia.config.errors.FolderLocked` with the locks taken so far released."""
    held: list[tuple[Path, dict]] = []
    try:
        for folder in folders:
            held.append((folder, _acquire(Path(folder), wait_s)))
        yield
    finally:
        for folder, holder in reversed(held):
            _release(folder, holder)
