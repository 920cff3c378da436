"""One way to ``torch.compile`` the env's and the transforms' pure step functions, and the optimiser step."""

from __future__ import annotations

import types
import warnings
from collections.abc import Callable, Sequence

import torch

# Dynamo caches compiled code per Python function and specialises it on the env (its shapes and
# constants): every env in a process adds an entry. The default limit (8) would silently send the ninth
# env of a process (a sweep, a benchmark, a test suite) back to eager mode.
_RECOMPILE_LIMIT = 256

# Deprecation notices that torch 2.13's compiler and tensordict 0.14 raise from their own internals while compiling
# (FutureWarnings, so Python prints them, into the progress bar): nothing a user of aia could change.
LIBRARY_NOTICES = (
    r"torch\._dynamo\.config\.inline_inbuilt_nn_modules is deprecated",  # tensordict.utils, every first compile
    r"`torch\._prims_common\.check` is deprecated",  # torch._inductor.lowering
)


def quiet_library_notices() -> None:
    """Leave :data:`LIBRARY_NOTICES` unprinted (done when this module is imported: before any compile of aia)."""
    for notice in LIBRARY_NOTICES:
        warnings.filterwarnings("ignore", message=notice, category=FutureWarning)


quiet_library_notices()

# The guards that a private compiled copy keeps (:func:`compiled_update`): every tensor's shape, dtype,
# device and strides, and the global state (grad mode, default device, deterministic algorithms, ...).
_KEPT_GUARDS = frozenset({
    "TENSOR_MATCH", "SHAPE_ENV", "GRAD_MODE", "GLOBAL_STATE", "DETERMINISTIC_ALGORITHMS", "TORCH_FUNCTION_STATE",
    "DEFAULT_DEVICE", "AUTOGRAD_SAVED_TENSORS_HOOKS",
})


def compiled(fn: Callable, options: dict | None = None) -> Callable:
    """``torch.compile(fn, dynamic=False)`` with room for one specialisation per env in the process."""
    config = torch._dynamo.config
    config.recompile_limit = max(config.recompile_limit, _RECOMPILE_LIMIT)
    config.accumulated_recompile_limit = max(config.accumulated_recompile_limit, 4 * _RECOMPILE_LIMIT)
    return torch.compile(fn, dynamic=False, options=options)


def tensor_and_global_guards(entries: Sequence) -> list[bool]:
    """A ``guard_filter_fn`` keeping only tensor-metadata and global-state guards (see :func:`compiled_update`)."""
    return [entry.guard_type in _KEPT_GUARDS for entry in entries]


def private_copy(fn: types.FunctionType) -> types.FunctionType:
    """``fn`` with a code object of its own, so that dynamo's cache of compiled code (kept per code object,
    shared by every ``torch.compile`` of the same function) holds only this copy's entries."""
    copy = types.FunctionType(fn.__code__.replace(), fn.__globals__, fn.__name__, fn.__defaults__, fn.__closure__)
    copy.__kwdefaults__ = fn.__kwdefaults__
    copy.__doc__ = fn.__doc__
    return copy


def compiled_update(fn: types.FunctionType) -> Callable:
    """A private compiled copy of a whole optimiser step, guarded only on tensors and global state.

    ``torch.autograd.grad`` is traced into the graph (``trace_autograd_ops``): the loss, its backward and
    the optimiser arithmetic become one graph. The function must not return tensors that still need the
    consumed autograd graph (return detached results).

    A step function receives a loss module, a tensordict and lists of tensors: dynamo installs about 900
    guards on their Python structure (module attributes, hooks, tensordict internals), whose check costs
    about 0.2 ms per call, a sixth of a whole update of the paper's network. The copy keeps only the guards
    on its tensors' metadata and on the global state, which is sound because the copy is private
    (:func:`private_copy`: no other caller can reach its cache) and its caller passes the same objects with
    the same settings at every call (:class:`aia.train.Updater`: one loss module, whose hyperparameters are
    fixed, and replayed batches of one layout). A changed shape, dtype or device still recompiles. The
    graph's own checks of its inputs' sizes and strides (``size_asserts``) are off: the kept guards have
    checked them before the graph runs (4 % of a 3x128 ADFQ step).
    """
    torch._dynamo.config.trace_autograd_ops = True
    options = {"guard_filter_fn": tensor_and_global_guards, "size_asserts": False}
    return compiled(private_copy(fn), options=options)
