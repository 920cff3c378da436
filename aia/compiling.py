"""One way to ``torch.compile`` the env's and the transforms' pure step functions, and the optimiser step."""

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


def compiled_update(fn: Callable) -> Callable:
    """:func:`compiled` for a whole optimiser step: ``torch.autograd.grad`` is traced into the graph.

    Without ``trace_autograd_ops`` dynamo breaks the graph at ``torch.autograd.grad``; with it the loss,
    its backward and the optimiser arithmetic become one graph. The function must not return tensors that
    still need the consumed autograd graph (return detached results).
    """
    torch._dynamo.config.trace_autograd_ops = True
    return compiled(fn)
