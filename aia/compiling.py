"""One way to ``torch.compile`` the env's and the transforms' pure step functions."""

from __future__ import annotations

from collections.abc import Callable

import torch

# Dynamo caches compiled code per Python function and specialises it on the env (its shapes and
# constants): every env in a process adds an entry. The default limit (8) would silently send the ninth
# env of a process (a sweep, a benchmark, a test suite) back to eager mode.
_RECOMPILE_LIMIT = 256


def compiled(fn: Callable) -> Callable:
    """``torch.compile(fn, dynamic=False)`` with room for one specialisation per env in the process."""
    config = torch._dynamo.config
    config.recompile_limit = max(config.recompile_limit, _RECOMPILE_LIMIT)
    config.accumulated_recompile_limit = max(config.accumulated_recompile_limit, 4 * _RECOMPILE_LIMIT)
    return torch.compile(fn, dynamic=False)
