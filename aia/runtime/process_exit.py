"""A quick end for aia's processes: no collector pass over the imported libraries at exit.

As an interpreter ends, CPython tears its modules down and runs the cyclic garbage collector over every tracked
object still alive. After importing torch, TensorDict and TorchRL that takes about a second. On the 2-core CPU, a
process that imported torchrl took 1.02 s from its last line to its end, and 0.13 s with :func:`freeze_at_exit`
(best of 3). Every aia process pays it: each command (``aia-train``, ``aia-eval``, ``aia-log``), each population
worker and each SLURM task. A two-job sweep waits for it three times.
"""

from __future__ import annotations

import atexit
import gc

_REGISTERED = False


def freeze_at_exit() -> None:
    """Move every object to the collector's permanent generation (:func:`gc.freeze`) once this process's exit
    handlers start, so that the interpreter's teardown does not search the libraries' objects for cycles.
    Objects still die by reference counting and the exit handlers run as before. Only what lives in a
    reference cycle at exit is not collected, as CPython never promises that anyway. Called by aia's entry points;
    a second call does nothing."""
    global _REGISTERED
    if not _REGISTERED:
        atexit.register(gc.freeze)
        _REGISTERED = True
