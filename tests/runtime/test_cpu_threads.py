"""Tests of aia/runtime/cpu_threads.py: a kernel's chunks cover the batch once, on torch's OpenMP team and on
threads of our own, with every kind of argument read back as packed; a forked child's calls run, on torch's team when
its parent was a fork server; bad arguments are refused."""

from __future__ import annotations

import multiprocessing
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch

from aia.runtime import cpu_threads
from aia.runtime.cpu_threads import array1, array2, array3, claim, descriptor, integer, kernel_entry, real, run_kernel


@kernel_entry("int64[1]", "float64[1]", "float32[2]", "int32[3]", "float", "int")
def _visit(data):  # pragma: no cover - compiled
    """visits[i] += 1 and values[i] = i * scale + offset + grid[i % 2, i % 3] + cube[0, 1, i % 2] for each claimed i."""
    d = descriptor(data)
    visits, values = array1(d, 0, np.int64), array1(d, 1, np.float64)
    grid, cube = array2(d, 2, np.float32), array3(d, 3, np.int32)
    start, stop = claim(d)
    while start < stop:
        for i in range(start, stop):
            visits[i] += 1
            values[i] = i * real(d, 4) + integer(d, 5) + grid[i % 2, i % 3] + cube[0, 1, i % 2]
        start, stop = claim(d)


def _run(count: int, chunk: int | None, team: bool) -> tuple[torch.Tensor, torch.Tensor]:
    visits, values = torch.zeros(count, dtype=torch.int64), torch.zeros(count, dtype=torch.float64)
    grid = torch.arange(6, dtype=torch.float32).view(2, 3)
    cube = torch.arange(8, dtype=torch.int32).view(2, 2, 2) * 10
    run_kernel(_visit, count, (visits, values, grid, cube, 0.5, -3), chunk=chunk, team=team)
    return visits, values


@pytest.mark.parametrize("team", [True, False])
@pytest.mark.parametrize("threads", [1, 2, 3])
def test_chunks_cover_the_batch_once_with_the_arguments_as_packed(team, threads):
    previous = torch.get_num_threads()
    try:
        torch.set_num_threads(threads)
        for count, chunk in ((1, None), (7, 1), (7, 3), (1000, None), (1000, 64)):
            visits, values = _run(count, chunk, team)
            i = torch.arange(count, dtype=torch.float64)
            expected = i * 0.5 - 3 + (i % 2) * 3 + (i % 3) + torch.where(i % 2 == 0, 20.0, 30.0)
            assert torch.equal(visits, torch.ones(count, dtype=torch.int64)), (count, chunk)
            assert torch.equal(values, expected), (count, chunk)
        visits, _ = _run(0, None, team)
        assert visits.numel() == 0
    finally:
        torch.set_num_threads(previous)


def test_the_team_is_torch_openmp_runtime():
    """torch's CPU wheels run on OpenMP (libgomp), which exports GOMP_parallel: the team is used there."""
    assert "OpenMP" in torch.__config__.parallel_info()
    assert cpu_threads._TEAM is not None


def _child(queue) -> None:
    visits, _ = _run(100, 7, team=None)
    queue.put((cpu_threads._FORKED, int(visits.sum())))


def test_a_forked_child_runs_in_threads_of_its_own():
    """The parent's team and pool exist before the fork; the child's calls must not wait on threads it does not
    have, nor use its copy of the OpenMP runtime."""
    previous = torch.get_num_threads()
    try:
        torch.set_num_threads(2)
        assert int(_run(100, 7, team=None)[0].sum()) == 100
        assert int(_run(100, 7, team=False)[0].sum()) == 100
        context = multiprocessing.get_context("fork")
        queue = context.Queue()
        child = context.Process(target=_child, args=(queue,))
        child.start()
        child.join(timeout=30)
        assert child.exitcode == 0 and queue.get(timeout=1) == (True, 100)
    finally:
        torch.set_num_threads(previous)


# A fresh interpreter that declares itself a fork server (what a population launcher's fork server does) and forks
# a worker, which forks again: each line says which process, its _FORKED and (the worker) a 2-thread kernel's visits.
FORK_SERVER = """
import os
import sys
import torch
from aia.runtime import cpu_threads
sys.path.insert(0, "tests/runtime")
from test_cpu_threads import _run  # as pytest names it: numba's cached kernel names its module
cpu_threads.serve_forks()
torch.set_num_threads(2)
if os.fork() == 0:
    print("worker", cpu_threads._FORKED, int(_run(1000, 7, team=None)[0].sum()), flush=True)
    if os.fork() == 0:
        print("its child", cpu_threads._FORKED, flush=True)
        os._exit(0)
    os.wait()
    os._exit(0)
os.wait()
print("server", cpu_threads._FORKED, flush=True)
"""


def test_a_fork_servers_child_runs_on_the_team_and_its_own_children_do_not():
    """The server ran no parallel region, so its child's copy of the OpenMP runtime is as good as a fresh one;
    the child's own children are forked from a process that ran the team."""
    root = Path(__file__).resolve().parents[2]
    result = subprocess.run([sys.executable, "-c", FORK_SERVER], cwd=root, capture_output=True, text=True,
                            timeout=120)
    assert result.stdout.splitlines() == ["worker False 1000", "its child True", "server False"], result.stderr[-2000:]


def test_bad_arguments_are_refused():
    visits, values = torch.zeros(4, dtype=torch.int64), torch.zeros(4, dtype=torch.float64)
    grid, cube = torch.zeros(2, 3), torch.zeros(2, 2, 2, dtype=torch.int32)
    with pytest.raises(ValueError, match="contiguous CPU tensors"):
        run_kernel(_visit, 4, (torch.zeros(8, dtype=torch.int64)[::2], values, grid, cube, 0.5, 1))
    with pytest.raises(ValueError, match=r"_visit takes 6 arguments \(int64\[1\], float64\[1\], .*\), got 2"):
        run_kernel(_visit, 4, (visits, values))
    for k, bad, words in ((0, visits.int(), "int32 tensor [4]"), (2, grid.double(), "float64 tensor [2, 3]"),
                          (3, cube[0], "int32 tensor [2, 2]"), (4, "0.5", "str '0.5'"), (5, 1.5, "float 1.5")):
        args = [visits, values, grid, cube, 0.5, 1]
        args[k] = bad
        with pytest.raises(ValueError, match=f"_visit argument {k}: expected .*, got {re.escape(words)}$"):
            run_kernel(_visit, 4, tuple(args))
    with pytest.raises(ValueError, match="at most 24 arguments"):
        kernel_entry(*["int"] * 25)(lambda data: None)
    with pytest.raises(ValueError, match="kernel argument 'float16.1.'"):
        kernel_entry("float16[1]")(lambda data: None)


def test_a_declared_float_is_packed_as_one_when_given_an_int():
    visits, values = torch.zeros(3, dtype=torch.int64), torch.zeros(3, dtype=torch.float64)
    run_kernel(_visit, 3, (visits, values, torch.zeros(2, 3), torch.zeros(2, 2, 2, dtype=torch.int32), 2, 0))
    assert values.tolist() == [0.0, 2.0, 4.0]  # i * 2.0: the int 2 read as the float 2.0, not as its bits


def test_real_tensors_share_one_float_dtype_and_its_size():
    entry = kernel_entry("real[1]", "real[2]", "real_size", "int64[1]")(lambda data: None)  # checked, not compiled
    index = torch.zeros(2, dtype=torch.int64)
    for dtype in (torch.float32, torch.float64):
        entry.check((torch.zeros(2, dtype=dtype), torch.zeros(2, 2, dtype=dtype), dtype.itemsize, index))
    with pytest.raises(ValueError, match=r"argument 1: expected real\[2\] \(as the real tensors before it\), got "
                                         r"float64 tensor \[2, 2\]$"):
        entry.check((torch.zeros(2), torch.zeros(2, 2, dtype=torch.float64), 4, index))
    with pytest.raises(ValueError, match="argument 0: expected real.1., got int64 tensor"):
        entry.check((index, torch.zeros(2, 2), 4, index))
    with pytest.raises(ValueError, match=r"argument 2: expected real_size, the real tensors' element size \(4\), "
                                         r"got 8"):
        entry.check((torch.zeros(2), torch.zeros(2, 2), 8, index))
