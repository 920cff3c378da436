"""Run a numba kernel over a batch on torch's own CPU threads (its OpenMP team).

A kernel here is a numba ``cfunc`` *entry* of signature :data:`ENTRY` (declared with :func:`kernel_entry` and its
arguments' dtypes and dimensions, which :func:`run_kernel` checks; compiled on its first run, so that importing a
module of kernels costs nothing) that reads its arguments from a *descriptor* (:func:`run_kernel` packs it: the
batch's size, a chunk size, a shared counter and up to :data:`MAX_ARGS` arguments, each a contiguous tensor's
address and shape or a scalar) and works through the batch in chunks it claims from the counter (:func:`claim`),
until none are left. Any number of threads may run the entry at once; which thread takes which chunk never changes a
result.

:func:`run_kernel` hands the entry to torch's OpenMP team (``GOMP_parallel``, the call compiled OpenMP code makes)
where torch's OpenMP runtime exports it, and to threads of its own otherwise. The team is the point: after each
parallel region of a compiled step, torch's OpenMP threads spin on their cores for milliseconds (libgomp's
``GOMP_SPINCOUNT``), so a kernel run in threads of our own shares the second core with a spinning thread and gains
nothing from it. The ray walk of a 4,096-world ``random_obstacles`` step took 11.5 ms in two threads of our own
inside the compiled step (10.3 ms in one, 6.0 ms in two outside it) and 5.4 ms on the team (docs/speed.md).
"""

from __future__ import annotations

import ctypes
import math
import os
from collections.abc import Sequence
from concurrent.futures import ThreadPoolExecutor

import numba
import numpy as np
import torch
from numba import types
from numba.core import cgutils
from numba.extending import intrinsic

# The signature of a kernel's entry: void entry(int64 *descriptor).
ENTRY = types.void(types.voidptr)
MAX_ARGS = 24
# The descriptor: the batch's size, the chunk size, the next unclaimed index, then 4 slots per argument (an array's
# address and up to 3 sizes, or a scalar; a float's bits in its first slot).
_HEADER, _SLOTS = 3, 4

_Scalar = int | float


def _find_team_entry():
    """torch's ``GOMP_parallel(fn, data, num_threads, flags)`` when its OpenMP runtime exports one, else None."""
    try:
        entry = ctypes.CDLL(None).GOMP_parallel
    except (AttributeError, OSError):
        return None
    entry.restype = None
    entry.argtypes = [ctypes.c_void_p, ctypes.c_void_p, ctypes.c_uint, ctypes.c_uint]
    return entry


_TEAM = _find_team_entry()
# Threads of our own, for a runtime without GOMP_parallel and for a forked child (whose copy of the OpenMP runtime
# may not be usable, unless its parent was a fork server: serve_forks): one per torch thread but the caller's, made
# on first use and kept for the process.
_POOL: tuple[int, ThreadPoolExecutor] | None = None
_FORKED = False
# Whether this process is a fork server that only imports and forks (:func:`serve_forks`).
_FORK_SERVER = False


def serve_forks() -> None:
    """Declare this process a fork server that runs no parallel region (a population launcher's, which only
    imports aia before it forks the workers): the OpenMP runtime its children copy has no team yet, so they run
    kernels on torch's team as any process does. Their own children count as forked again."""
    global _FORK_SERVER
    _FORK_SERVER = True


def _pool(threads: int) -> ThreadPoolExecutor:
    global _POOL
    if _POOL is None or _POOL[0] < threads:
        if _POOL is not None:
            _POOL[1].shutdown(wait=False)
        _POOL = (threads, ThreadPoolExecutor(threads))
    return _POOL[1]


def _after_fork() -> None:
    global _POOL, _FORKED, _FORK_SERVER
    _POOL, _FORKED, _FORK_SERVER = None, _FORKED or not _FORK_SERVER, False


os.register_at_fork(after_in_child=_after_fork)


# A kernel argument's declaration (:func:`kernel_entry`): a tensor ``"<dtype>[<ndim>]"`` (``"int64[1]"``, ``"bool[3]"``;
# ``"real[2]"``: float32 or float64, the same for all of a call's ``real`` tensors), a scalar ``"int"`` or
# ``"float"``, or ``"real_size"`` (an int: the element size of the call's ``real`` tensors, which
# :func:`in_float_dtype` switches on).
_TENSOR_DTYPES = {"bool": torch.bool, "uint8": torch.uint8, "int16": torch.int16, "int32": torch.int32,
                  "int64": torch.int64, "float32": torch.float32, "float64": torch.float64, "real": None}
_SCALARS = ("int", "float", "real_size")
_REAL_DTYPES = (torch.float32, torch.float64)


def _declared(spec: str) -> tuple[str, torch.dtype | None, int]:
    """``(kind, dtype, ndim)`` of an argument's declaration; kind ``"tensor"``, ``"real"`` or a scalar's."""
    if spec in _SCALARS:
        return spec, None, 0
    name, _, rest = spec.partition("[")
    if name not in _TENSOR_DTYPES or rest not in ("1]", "2]", "3]"):
        raise ValueError(f"kernel argument {spec!r}: expected <dtype>[1|2|3] with a dtype of "
                         f"{', '.join(_TENSOR_DTYPES)}, or one of {', '.join(_SCALARS)}")
    return ("real" if name == "real" else "tensor"), _TENSOR_DTYPES[name], int(rest[0])


def _described(arg: object) -> str:
    if isinstance(arg, torch.Tensor):
        return f"{str(arg.dtype).removeprefix('torch.')} tensor {list(arg.shape)}"
    return f"{type(arg).__name__} {arg!r}"


class KernelEntry:
    """A kernel's entry with its arguments' declarations, compiled as a ``cfunc`` (or loaded from numba's cache)
    on its first run: loading the env's seven entries at import took about a second in every process, the CLI's
    and each test's included. :func:`run_kernel` checks each call's arguments against the declarations before the
    entry reads them as declared (the descriptor holds addresses and sizes, not dtypes)."""

    def __init__(self, function, arguments: Sequence[str]) -> None:
        if len(arguments) > MAX_ARGS:
            raise ValueError(f"a kernel takes at most {MAX_ARGS} arguments, got {len(arguments)}")
        self.function = function
        self.arguments = tuple(arguments)
        self._declared = [_declared(spec) for spec in self.arguments]
        self.floats = tuple(kind == "float" for kind, _, _ in self._declared)  # packed as floats (read by real())
        self._cfunc = None

    @property
    def cfunc(self):
        """The compiled entry."""
        if self._cfunc is None:
            self._cfunc = numba.cfunc(ENTRY, nogil=True, cache=True)(self.function)
        return self._cfunc

    def check(self, args: Sequence[torch.Tensor | _Scalar]) -> None:
        """Raise a ValueError naming the first argument that is not as declared."""
        name = self.function.__name__
        if len(args) != len(self.arguments):
            raise ValueError(f"{name} takes {len(self.arguments)} arguments ({', '.join(self.arguments)}), "
                             f"got {len(args)}")
        real = None
        for k, (arg, (kind, dtype, ndim)) in enumerate(zip(args, self._declared, strict=True)):
            if kind == "tensor":
                good = isinstance(arg, torch.Tensor) and arg.dtype == dtype and arg.ndim == ndim
            elif kind == "real":
                good = (isinstance(arg, torch.Tensor) and arg.dtype in _REAL_DTYPES and arg.ndim == ndim
                        and arg.dtype == (real or arg.dtype))
                real = arg.dtype if good else real
            elif kind == "float":
                good = isinstance(arg, (int, float)) and not isinstance(arg, bool)
            else:
                good = isinstance(arg, int) and not isinstance(arg, bool)
            if not good:
                raise ValueError(f"{name} argument {k}: expected {self.arguments[k]}"
                                 f"{' (as the real tensors before it)' if kind == 'real' and real else ''}, "
                                 f"got {_described(arg)}")
        for k, (kind, _, _) in enumerate(self._declared):
            if kind == "real_size" and (real is None or args[k] != real.itemsize):
                raise ValueError(f"{name} argument {k}: expected real_size, the real tensors' element size "
                                 f"({real.itemsize if real else 'no real tensor'}), got {args[k]!r}")


def kernel_entry(*arguments: str):
    """Declare ``function(data)`` a kernel's entry taking ``arguments`` (their declarations, in order; see
    :data:`_TENSOR_DTYPES`), a decorator: ``@kernel_entry("bool[3]", "int64[1]", "float")``."""

    def declare(function) -> KernelEntry:
        return KernelEntry(function, arguments)

    return declare


def run_kernel(entry, count: int, args: Sequence[torch.Tensor | _Scalar], chunk: int | None = None,
               team: bool | None = None) -> None:
    """Run the entry ``entry`` (a :class:`KernelEntry` or a cfunc) over ``range(count)`` with the arguments
    ``args`` (contiguous CPU tensors of up to 3 dimensions, ints and floats, read by the entry through
    :func:`array1`, :func:`array2`, :func:`array3`, :func:`integer` and :func:`real` by position) in
    ``torch.get_num_threads()`` threads, in chunks of ``chunk`` (default: an eighth of a thread's share). A
    :class:`KernelEntry`'s arguments must be as it declares them (a ValueError names the first that is not; a
    declared float may be given as an int); a bare cfunc's are not checked. ``team``: run on torch's OpenMP team
    where it can (default: unless in a forked child), or on threads of our own (False)."""
    floats = None
    if isinstance(entry, KernelEntry):
        entry.check(args)
        floats = entry.floats
    if count <= 0:
        return
    entry = entry.cfunc if isinstance(entry, KernelEntry) else entry
    threads = max(1, min(torch.get_num_threads(), count))
    chunk = chunk or max(1, math.ceil(count / (8 * threads)))
    descriptor = _descriptor(count, chunk, args, floats)
    address = descriptor.ctypes.data
    if threads == 1:
        entry.ctypes(address)
    elif _TEAM is not None and (not _FORKED if team is None else team):
        _TEAM(entry.address, address, threads, 0)
    else:
        others = [_pool(threads - 1).submit(entry.ctypes, address) for _ in range(threads - 1)]
        entry.ctypes(address)
        for other in others:
            other.result()


def _descriptor(count: int, chunk: int, args: Sequence[torch.Tensor | _Scalar],
                floats: Sequence[bool] | None = None) -> np.ndarray:
    """The descriptor of a call; ``floats``: per argument, whether to pack it as a float (default: the floats)."""
    if len(args) > MAX_ARGS:
        raise ValueError(f"a kernel takes at most {MAX_ARGS} arguments, got {len(args)}")
    descriptor = np.zeros(_HEADER + _SLOTS * MAX_ARGS, dtype=np.int64)
    descriptor[:2] = count, chunk
    for k, arg in enumerate(args):
        slot = _HEADER + _SLOTS * k
        if isinstance(arg, torch.Tensor):
            if arg.device.type != "cpu" or not arg.is_contiguous() or arg.ndim > 3:
                raise ValueError(f"argument {k}: a kernel reads contiguous CPU tensors of up to 3 dimensions, got "
                                 f"{arg.device} {tuple(arg.shape)} with strides {arg.stride()}")
            descriptor[slot] = arg.data_ptr()
            descriptor[slot + 1: slot + 1 + arg.ndim] = arg.shape
        elif floats[k] if floats is not None else isinstance(arg, float):
            descriptor[slot: slot + 1].view(np.float64)[0] = float(arg)
        else:
            descriptor[slot] = int(arg)
    return descriptor


# ------------------------------------------------------------------ what an entry calls (numba, inlined)
@intrinsic
def _pointer(typingctx, address):
    """The address ``address`` (an int64) as a ``void *``."""
    def codegen(context, builder, signature, llvm_args):
        return builder.inttoptr(llvm_args[0], cgutils.voidptr_t)
    return types.voidptr(types.int64), codegen


@intrinsic
def _fetch_add(typingctx, descriptor, index, value):
    """Atomically add ``value`` to ``descriptor[index]`` and return what it held."""
    def codegen(context, builder, signature, llvm_args):
        array = context.make_array(signature.args[0])(context, builder, llvm_args[0])
        pointer = builder.gep(array.data, [llvm_args[1]])
        return builder.atomic_rmw("add", pointer, llvm_args[2], "monotonic")
    return types.int64(descriptor, types.intp, types.int64), codegen


@numba.njit(inline="always", nogil=True)
def descriptor(data):  # pragma: no cover - compiled
    """The descriptor an entry receives (its ``void *``) as an int64 array."""
    return numba.carray(data, (_HEADER + _SLOTS * MAX_ARGS,), np.int64)


@numba.njit(inline="always", nogil=True)
def claim(d):  # pragma: no cover - compiled
    """``(start, stop)`` of the next unclaimed chunk of the batch; ``start >= stop`` when none is left."""
    start = _fetch_add(d, 2, d[1])
    return start, min(start + d[1], d[0])


@numba.njit(inline="always", nogil=True)
def in_chunks(d, kernel, args):  # pragma: no cover - compiled
    """``kernel(*args, start, stop)`` for each chunk this thread claims, until none is left (an entry's loop)."""
    start, stop = claim(d)
    while start < stop:
        kernel(*args, start, stop)
        start, stop = claim(d)


@numba.njit(inline="always", nogil=True)
def in_float_dtype(data, k, share):  # pragma: no cover - compiled
    """``share(data, dtype)`` with ``dtype`` the float whose size in bytes is argument ``k`` (4 or 8): one entry for a
    kernel's float32 and float64 arguments."""
    if integer(descriptor(data), k) == 8:
        share(data, np.float64)
    else:
        share(data, np.float32)


@numba.njit(inline="always", nogil=True)
def array1(d, k, dtype):  # pragma: no cover - compiled
    """Argument ``k``, a 1-dimensional array of ``dtype``."""
    s = _HEADER + _SLOTS * k
    return numba.carray(_pointer(d[s]), (d[s + 1],), dtype)


@numba.njit(inline="always", nogil=True)
def array2(d, k, dtype):  # pragma: no cover - compiled
    """Argument ``k``, a 2-dimensional array of ``dtype``."""
    s = _HEADER + _SLOTS * k
    return numba.carray(_pointer(d[s]), (d[s + 1], d[s + 2]), dtype)


@numba.njit(inline="always", nogil=True)
def array3(d, k, dtype):  # pragma: no cover - compiled
    """Argument ``k``, a 3-dimensional array of ``dtype``."""
    s = _HEADER + _SLOTS * k
    return numba.carray(_pointer(d[s]), (d[s + 1], d[s + 2], d[s + 3]), dtype)


@numba.njit(inline="always", nogil=True)
def integer(d, k):  # pragma: no cover - compiled
    """Argument ``k``, an int."""
    return d[_HEADER + _SLOTS * k]


@numba.njit(inline="always", nogil=True)
def real(d, k):  # pragma: no cover - compiled
    """Argument ``k``, a float."""
    return d[_HEADER + _SLOTS * k: _HEADER + _SLOTS * k + 1].view(np.float64)[0]
