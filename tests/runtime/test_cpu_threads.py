"""Tests of aia/runtime/cpu_threads.py: the shares cover the batch once, in order, and a forked child's calls run."""

from __future__ import annotations

import multiprocessing

import torch

from aia.runtime.cpu_threads import in_shares


def test_shares_cover_the_batch_in_order():
    threads = torch.get_num_threads()
    try:
        torch.set_num_threads(3)
        shares = in_shares(lambda start, stop: (start, stop), 10)
        assert shares == [(0, 3), (3, 7), (7, 10)]
        assert in_shares(lambda start, stop: (start, stop), 2) == [(0, 1), (1, 2)]
        assert in_shares(lambda start, stop: (start, stop), 0) == []
    finally:
        torch.set_num_threads(threads)


def _child(queue) -> None:
    queue.put(in_shares(lambda start, stop: stop - start, 8))


def test_a_forked_child_gets_threads_of_its_own():
    """The parent's pool exists before the fork; the child's calls must not wait on threads it does not have."""
    threads = torch.get_num_threads()
    try:
        torch.set_num_threads(2)
        assert in_shares(lambda start, stop: stop - start, 8) == [4, 4]
        context = multiprocessing.get_context("fork")
        queue = context.Queue()
        child = context.Process(target=_child, args=(queue,))
        child.start()
        child.join(timeout=20)
        assert child.exitcode == 0 and queue.get(timeout=1) == [4, 4]
    finally:
        torch.set_num_threads(threads)
