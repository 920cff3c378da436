"""Keep the memory a process frees for its next allocations instead of handing it back to the OS.

glibc's ``malloc`` serves large blocks (128 KiB and up, a threshold it raises as such blocks are freed) with
``mmap`` and returns them with ``munmap`` when freed, and trims the top of its heap when that much is free: the
next allocation of the same size then faults its pages in again, each zeroed by the kernel. PyTorch's CPU
allocator calls ``malloc`` for every tensor, so a training step that allocates and frees the same activations,
gradients and temporaries each time pays for fresh pages each time. Measured on the 2-core CPU (a
population of 10 DQN and Double DQN members of setting 4, 3 x 256, bfloat16 inner layers, compiled, one thread,
2,500 frames): 2.2-3.0 million page faults and 22.8-26.3 s of update with glibc's defaults, 0.32 million and
19.3-19.4 s with :func:`keep_freed_memory`; the ARVI planner keeps its own buffers (``ARVIPlanner.storage``).
"""

from __future__ import annotations

import ctypes
import sys

# mallopt parameters (glibc's malloc.h)
_M_TRIM_THRESHOLD = -1
_M_MMAP_MAX = -4
# the largest trim threshold mallopt takes (a C int): the heap's free top is kept up to 2 GiB
_TRIM_THRESHOLD = 2**31 - 1


def keep_freed_memory() -> bool:
    """Make glibc's ``malloc`` serve every block from its heap (no ``mmap``) and keep freed memory (no trimming
    below 2 GiB free), for the rest of the process; returns whether it could (False off Linux or without glibc:
    nothing changes). The process's resident memory then stays near its peak."""
    if not sys.platform.startswith("linux"):
        return False
    try:
        mallopt = ctypes.CDLL("libc.so.6").mallopt
    except (OSError, AttributeError):
        return False
    mallopt.argtypes, mallopt.restype = (ctypes.c_int, ctypes.c_int), ctypes.c_int
    return bool(mallopt(_M_MMAP_MAX, 0)) and bool(mallopt(_M_TRIM_THRESHOLD, _TRIM_THRESHOLD))
