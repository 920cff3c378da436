"""Running populations: in this process, or in worker processes that each run one population at a time.

A worker that dies (killed for its memory, a segfault) fails the population it was running, and only that
one: the launcher watches each worker's process, reports that population's jobs as failed with the worker's
exit code, starts a fresh worker and goes on with the others. Why not joblib's loky executor (used before):
when one of its workers dies, loky shuts the whole executor down, so every other running population died with
it and the sweep ended in a ``TerminatedWorkerError`` traceback with no job results (measured on
2026-12-04: a population whose process called ``os._exit(9)`` took its sibling population with it).

A worker forwards what its population prints and its training bar's state through its pipe (the launcher
shows them, :mod:`.display`), so that several populations' bars and lines do not overwrite each other.

Signals (SIGINT, SIGTERM, SIGUSR1: :mod:`aia.runtime.stopping`) stop a sweep as they stop a solo run. The
launcher forwards each one it gets to the running workers, since a ``kill PID``, a container's stop or a
scheduler may signal the launcher alone; a Ctrl-C in a terminal reaches the workers as well, and a worker keeps
the first signal of each population. Each running population stops at the end of its episode with its
checkpoints and logs marked stopped (one still being set up ends at once), none is started after,
and the launcher exits with status 128 + signal; a second Ctrl-C kills the workers. A worker whose launcher is
gone (killed outright: its pipe is broken) stops its population the same way instead of failing it.
"""

from __future__ import annotations

import contextlib
import importlib
import io
import multiprocessing
import os
import pickle
import signal
import sys
from collections.abc import Callable, Iterator, Sequence
from multiprocessing.connection import Connection, wait
from pathlib import Path
from types import ModuleType

from omegaconf import OmegaConf

from hydra_plugins.aia_population_launcher.display import PopulationDisplay

# (ok, result or error) per member of a population
Outcome = list[tuple[bool, object]]
# what a population is run with: (task, member configs as dicts, job folders, torch threads or None)
Call = tuple[str, list[dict], list[str], int | None]


def training() -> ModuleType:
    """:mod:`aia.training.sweeps`, the launcher's one entry into training, imported on first use: Hydra's plugin
    scan imports this package for every app's start, which must not pay for torch."""
    return importlib.import_module("aia.training.sweeps")


def import_entry(path: str) -> Callable:
    """The object at dotted ``path`` (``aia.apps.train.train_jobs``)."""
    module, _, name = path.rpartition(".")
    return getattr(importlib.import_module(module), name)


def run_group(task: str, cfgs: list[dict], out_dirs: list[str], threads: int | None) -> Outcome:
    """Run one population (in a worker process or in-process): ``(ok, result or error)`` per member.

    A ``SystemExit`` (the task stopped by a signal after checkpointing) passes through."""
    if threads:
        import torch

        torch.set_num_threads(threads)
    configs = [OmegaConf.create(cfg) for cfg in cfgs]
    try:
        results = import_entry(task)(configs, [Path(d) for d in out_dirs])
    except Exception as err:  # the whole population failed: every member's job reports it
        return [(False, err)] * len(cfgs)
    return [(not isinstance(r, BaseException), r) for r in results]


def run_stoppable(call: Call) -> tuple[str, object]:
    """Run one population (:func:`run_group`) so that a stop signal ends it rather than the process:
    ``("done", outcome)`` (its results picklable) or ``("stopped", exit status)`` (the task checkpointed and
    stopped, :func:`aia.apps.train.exit_if_stopped`, or a signal came while no training loop was listening and
    ended the call at once, :func:`aia.runtime.stopping.interrupting`: a population still being set up, or a
    task that handles no signals, such as an evaluation). What a worker process and a population's SLURM job
    run."""
    from aia.config.errors import Stopped  # see run_in_workers

    try:
        with training().interrupting():
            outcome = run_group(*call)
    except SystemExit as stop:
        return "stopped", stop.code if isinstance(stop.code, int) else 1
    except Stopped as stop:
        return "stopped", stop.exit_status
    return "done", [(ok, _picklable(result)) for ok, result in outcome]


def run_in_workers(calls: Sequence[Call], processes: int, names: Sequence[str], display: PopulationDisplay
                   ) -> Iterator[tuple[int, Outcome]]:
    """Run ``calls`` in ``processes`` worker processes, each call in the order given as a worker frees up;
    yields ``(index of the call, its outcome)`` as each ends. What the workers print and their progress go to
    ``display``. A call whose worker died fails each member with a :class:`~aia.config.errors.JobFailed` naming the
    call (``names``, e.g. its job numbers) and how the process ended. See the module docstring for signals (a
    stop raises ``SystemExit`` with the workers' exit status once the running calls have ended)."""
    # imported here: Hydra's plugin scan imports this package for every app
    from aia.config.errors import JobFailed

    context = _worker_context()
    pending = list(enumerate(calls))
    running: list[tuple[multiprocessing.Process, Connection, int]] = []  # worker, its pipe, its call's index
    idle: list[tuple[multiprocessing.Process, Connection]] = []
    stop_status: int | None = None

    def forward(signum: int, first: bool) -> None:
        """To every running worker; a second Ctrl-C kills them (raised out of ``wait``, see ``finally``)."""
        if signum == signal.SIGINT and not first:
            raise KeyboardInterrupt
        for process, _, _ in running:
            with contextlib.suppress(ProcessLookupError):
                os.kill(process.pid, signum)

    try:
        with training().StopOnSignals(on_signal=forward) as stop:
            while pending or running:
                while pending and stop_status is None and stop.signal is None and len(running) < processes:
                    process, conn = _idle_worker(idle) or _start_worker(context)
                    index, call = pending.pop(0)
                    conn.send(call)
                    running.append((process, conn, index))
                if not running:
                    break
                ready = wait([conn for _, conn, _ in running] + [process.sentinel for process, _, _ in running])
                if stop.signal is not None and stop_status is None:
                    stop_status = 128 + stop.signal
                    display.write(f"population launcher: {signal.Signals(stop.signal).name}: the running "
                                  "populations stop at the end of their episodes and write their checkpoints "
                                  "(a second Ctrl-C kills them)")
                for worker in [w for w in running if w[1] in ready or w[0].sentinel in ready]:
                    process, conn, index = worker
                    kind, payload = _receive(conn, index, display)
                    if kind is None:  # only progress so far
                        if process.is_alive():
                            continue
                        kind = "died"
                    running.remove(worker)
                    display.finish(index)
                    if kind == "done":
                        idle.append((process, conn))
                        yield index, payload
                        continue
                    process.join()
                    if kind == "stopped":
                        stop_status = payload if stop_status is None else stop_status
                    else:
                        error = JobFailed(f"{names[index]}: the process running their population "
                                          f"{_exit_reason(process.exitcode)}; the other populations ran on")
                        yield index, [(False, error)] * len(calls[index][1])
            if stop_status is not None:
                raise SystemExit(stop_status)
    finally:
        for _, conn in idle:
            with contextlib.suppress(OSError):
                conn.send(None)  # an idle worker ends its loop
        for process, _ in idle:
            process.join(timeout=60)
        for process in [process for process, _ in idle] + [process for process, _, _ in running]:
            if process.is_alive():  # after an error here, or a second Ctrl-C
                process.kill()
                process.join()


def _receive(conn: Connection, index: int, display: PopulationDisplay) -> tuple[str | None, object]:
    """What a worker sent: its printed lines and progress (shown on ``display`` as population ``index``'s),
    then ``("done", outcome)`` or ``("stopped", exit status)``; ``("died", None)`` if its pipe closed without
    one, ``(None, None)`` if nothing more has come yet."""
    try:
        while conn.poll():
            kind, payload = conn.recv()
            if kind == "print":
                display.write(payload)
            elif kind == "progress":
                display.progress(index, payload)
            else:
                return kind, payload
    except (EOFError, OSError):
        return "died", None
    return None, None


def _idle_worker(idle: list[tuple[multiprocessing.Process, Connection]]
                 ) -> tuple[multiprocessing.Process, Connection] | None:
    """An idle worker that is still alive (one signalled between populations has ended), or ``None``."""
    while idle:
        process, conn = idle.pop()
        if process.is_alive():
            return process, conn
        process.join()
    return None


def _worker_context() -> multiprocessing.context.BaseContext:
    """Workers forked from a fork server, a fresh interpreter that imports aia's training stack and then only
    forks (:mod:`aia.runtime.fork_server`): no torch or OpenMP threads are forked, and each worker starts with
    torch and TorchRL imported (spawned, each imported them itself: 4.5 s of CPU a worker on the 2-core CPU). The
    server starts with the first worker and serves this process's later sweeps; a worker imports its task's
    module itself, so that a task edited between two sweeps runs as it now is. Spawned workers where the platform
    has no fork server (Windows)."""
    if "forkserver" not in multiprocessing.get_all_start_methods():
        return multiprocessing.get_context("spawn")
    context = multiprocessing.get_context("forkserver")
    context.set_forkserver_preload(["aia.training.sweeps", "aia.runtime.fork_server"])
    return context


def _start_worker(context) -> tuple[multiprocessing.Process, Connection]:
    """A worker process (not a daemon: inductor's compile workers are its children) and the launcher's end
    of its pipe."""
    here, there = context.Pipe()
    process = context.Process(target=_serve, args=(there,), name="aia-population-worker")
    process.start()
    there.close()
    return process, here


def _serve(conn: Connection) -> None:
    """A worker's loop: run each call received and send back ``("done", outcome)``; a task stopped by a
    signal sends ``("stopped", exit status)`` and ends the worker; ``None`` ends it."""
    from aia.runtime.process_exit import freeze_at_exit  # imported here, as training()

    forwarding = training().forwarding  # the worker's own import of aia (see run_in_workers)
    freeze_at_exit()

    sys.stdout.reconfigure(line_buffering=True)  # what is printed between populations, as it comes
    launcher = _LauncherPipe(conn)
    try:
        while (call := conn.recv()) is not None:
            with forwarding(lambda state: launcher.send(("progress", state))), _LinesTo(launcher) as lines:
                try:
                    kind, payload = run_stoppable(call)
                finally:
                    lines.flush()
            launcher.send((kind, payload))
            if kind == "stopped":
                return
    except (KeyboardInterrupt, EOFError):  # interrupted between populations, or the launcher is gone
        return


class _LauncherPipe:
    """A worker's end of its pipe to the launcher. If a send fails, the launcher is gone (killed outright): the
    worker then stops as on a SIGTERM (its population ends its episode, writes its checkpoints and marks its
    logs stopped) instead of failing on the broken pipe, and what it would still send is dropped."""

    def __init__(self, conn: Connection) -> None:
        self.conn = conn
        self.gone = False

    def send(self, message: tuple[str, object]) -> None:
        if self.gone:
            return
        try:
            self.conn.send(message)
        except OSError:
            self.gone = True
            print("population launcher's worker: the launcher is gone: this population stops as on a SIGTERM",
                  file=sys.stderr)
            os.kill(os.getpid(), signal.SIGTERM)


class _LinesTo(io.TextIOBase):
    """``sys.stdout`` of a worker while it runs a population: each complete line printed goes to the launcher
    as ``("print", line)`` (the rest of a line waits for its end, or for :meth:`flush`)."""

    def __init__(self, conn: _LauncherPipe) -> None:
        self.conn = conn
        self._partial = ""

    def __enter__(self) -> _LinesTo:
        self._stdout, sys.stdout = sys.stdout, self
        return self

    def __exit__(self, *exc) -> None:
        sys.stdout = self._stdout

    def writable(self) -> bool:
        return True

    def write(self, text: str) -> int:
        *lines, self._partial = (self._partial + text).split("\n")
        for line in lines:
            self.conn.send(("print", line))
        return len(text)

    def flush(self) -> None:
        if self._partial:
            self.conn.send(("print", self._partial))
            self._partial = ""


def _picklable(result: object) -> object:
    """``result``, or for an error that cannot be pickled a ``RuntimeError`` with its type and message."""
    try:
        pickle.dumps(result)
    except Exception:
        return RuntimeError(f"{type(result).__name__}: {result}")
    return result


def _exit_reason(exitcode: int | None) -> str:
    """``"was killed by SIGKILL (out of memory?)"``, ``"exited with status 9 before returning its results"``."""
    if exitcode is not None and exitcode < 0:
        name = signal.Signals(-exitcode).name
        return f"was killed by {name}" + (" (out of memory?)" if name == "SIGKILL" else "")
    return f"exited with status {exitcode} before returning its results"
