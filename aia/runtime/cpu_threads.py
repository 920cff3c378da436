"""Run a GIL-releasing kernel (numba ``nogil``) over shares of a batch in torch's CPU threads."""

from __future__ import annotations

import os
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from typing import TypeVar

import numpy as np
import torch

T = TypeVar("T")

# One thread per torch CPU thread but the caller's, made on first use, kept for the process (a kernel called every
# env step would otherwise pay for a pool each call), and made again in a forked child, which inherits the pool but
# not its threads.
_POOL: tuple[int, ThreadPoolExecutor] | None = None


def _pool(threads: int) -> ThreadPoolExecutor:
    global _POOL
    if _POOL is None or _POOL[0] < threads:
        if _POOL is not None:
            _POOL[1].shutdown(wait=False)
        _POOL = (threads, ThreadPoolExecutor(threads))
    return _POOL[1]


def _forget_pool() -> None:
    global _POOL
    _POOL = None


os.register_at_fork(after_in_child=_forget_pool)


def in_shares(work: Callable[[int, int], T], count: int) -> list[T]:
    """``work(start, stop)`` for each of ``torch.get_num_threads()`` contiguous shares of ``range(count)``, each in
    its own thread (one share runs in the caller's); the results in the shares' order."""
    parts = max(1, min(torch.get_num_threads(), count))
    bounds = np.linspace(0, count, parts + 1).round().astype(np.int64).tolist()
    shares = [(a, b) for a, b in zip(bounds[:-1], bounds[1:], strict=True) if b > a]
    if len(shares) <= 1:
        return [work(*share) for share in shares]
    others = [_pool(len(shares) - 1).submit(work, *share) for share in shares[1:]]
    first = work(*shares[0])
    return [first, *(future.result() for future in others)]
