"""keep_freed_memory: freed blocks serve the next allocations without faulting their pages in again."""

from __future__ import annotations

import resource
import subprocess
import sys
from pathlib import Path

import torch

_ELEMENTS = 2**20  # float32s of one tensor: 4 MiB, 1,024 pages
_LIVE = 10  # tensors alive at once, then all freed (as a training step's temporaries are)
_PAGES = _LIVE * _ELEMENTS * 4 // 4096  # pages of one step's tensors
ROOT = Path(__file__).resolve().parents[2]


def _faults_of_steps(steps: int) -> int:
    """Minor page faults of ``steps`` steps, each allocating and writing ``_LIVE`` tensors, then freeing them.

    Counted for this thread alone, with torch on this thread: a process-wide count also takes the faults of any
    other thread of the pytest worker (it failed once at 7,192 against the bound of 5,120)."""
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        before = resource.getrusage(resource.RUSAGE_THREAD).ru_minflt
        for _ in range(steps):
            live = [torch.ones(_ELEMENTS) for _ in range(_LIVE)]
            del live
        return resource.getrusage(resource.RUSAGE_THREAD).ru_minflt - before
    finally:
        torch.set_num_threads(threads)


def _faults_in_a_fresh_process() -> int:
    """:func:`_faults_of_steps` of 5 steps after 3 that grow the heap, in a fresh interpreter that first calls
    :func:`keep_freed_memory`, as an app calls it at its start. In a long-lived pytest worker, what its earlier
    tests left in the heap once had one tensor a step fault in again (5,121 against the bound of 5,120)."""
    code = ("from aia.runtime.memory import keep_freed_memory; from tests.runtime.test_memory import _faults_of_steps; "
            "assert keep_freed_memory(); _faults_of_steps(3); print(_faults_of_steps(5))")
    done = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, check=True)
    return int(done.stdout.split()[-1])


def test_freed_memory_serves_the_next_steps_without_page_faults():
    # With glibc's defaults the heap's free top is trimmed after most steps, whose pages then fault in again:
    # 1.1-3 steps' pages per step on this VM (the thresholds glibc adapts depend on the process's history: with
    # keep_freed_memory made a no-op, 12 of 20 fresh processes faulted 51,040 pages here, the others 0-1,024).
    assert _faults_in_a_fresh_process() < _PAGES // 2
