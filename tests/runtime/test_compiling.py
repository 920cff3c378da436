"""aia.runtime.compiling: private compiled copies keep their own cache, guarded only on tensors and global state; the
libraries' compile-time deprecation notices stay out of the console."""

from __future__ import annotations

import subprocess
import sys
import warnings

import pytest
import torch
from torch import nn

from aia.runtime.compiling import compiled_update, private_copy, quiet_library_notices


class Scaled(nn.Module):
    """A module whose Python float (baked into a compiled graph as a constant) differs between instances."""

    def __init__(self, factor: float) -> None:
        super().__init__()
        self.factor = factor
        self.weight = nn.Parameter(torch.ones(3))


def scaled_sum(module: Scaled, x: torch.Tensor) -> torch.Tensor:
    """Returns ``sum(weight * x) * factor``; the weight is detached (no autograd graph is returned)."""
    return (module.weight * x).sum().detach() * module.factor


def test_private_copy_is_the_same_function_with_its_own_code_object():
    copy = private_copy(scaled_sum)
    assert copy.__code__ is not scaled_sum.__code__
    assert copy.__doc__ == scaled_sum.__doc__ and copy.__name__ == scaled_sum.__name__
    assert copy(Scaled(2.0), torch.ones(3)) == scaled_sum(Scaled(2.0), torch.ones(3)) == 6.0


def test_each_compiled_copy_keeps_its_own_constants():
    # With the module guards dropped, a shared cache would serve the first module's factor to the second.
    x = torch.ones(3)
    first, second = compiled_update(scaled_sum), compiled_update(scaled_sum)
    assert first(Scaled(2.0), x) == 6.0
    assert second(Scaled(5.0), x) == 15.0
    assert first(Scaled(2.0), 2 * x) == 12.0  # a new tensor value, same metadata: the cached graph


def test_a_copy_recompiles_for_new_tensor_metadata():
    update = compiled_update(scaled_sum)
    module = Scaled(1.0)
    assert update(module, torch.ones(3)) == 3.0
    assert update(module, torch.ones(3, dtype=torch.float64)) == 3.0
    with pytest.raises(RuntimeError):  # a new shape is traced again and fails as eager code would
        update(module, torch.ones(4))


def test_the_libraries_compile_notices_are_silenced_and_other_warnings_are_not():
    """The two notices torch and tensordict print on a first compile (seen in a cold ``aia-train`` run), as those
    libraries raise them, each with a fresh registry. The filters are installed again inside the test: pytest drops
    those that a module installs while it is imported for collection."""
    raised = ["torch._dynamo.config.inline_inbuilt_nn_modules is deprecated and does not do anything, "
              "inline_inbuilt_nn_modules is always True.",
              "`torch._prims_common.check` is deprecated and will be removed in the future.",
              "another deprecation"]
    with warnings.catch_warnings(record=True) as caught:
        quiet_library_notices()
        for line, message in enumerate(raised):
            warnings.warn_explicit(message, FutureWarning, "tensordict/utils.py", line, module="tensordict.utils",
                                   registry={})
        warnings.warn_explicit(raised[0], UserWarning, "tensordict/utils.py", 9, module="tensordict.utils",
                               registry={})
    assert [(str(w.message), w.category) for w in caught] == [(raised[2], FutureWarning), (raised[0], UserWarning)]


def test_importing_the_module_installs_the_filters():
    """Outside pytest (which drops filters installed during collection): a process that imports aia.runtime.compiling
    prints no notice of :data:`~aia.runtime.compiling.LIBRARY_NOTICES`, and still prints other FutureWarnings."""
    code = ("import warnings, aia.runtime.compiling\n"
            "for message in ('torch._dynamo.config.inline_inbuilt_nn_modules is deprecated', 'another notice'):\n"
            "    warnings.warn_explicit(message, FutureWarning, 'tensordict/utils.py', 1, module='tensordict.utils')\n")
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert "another notice" in result.stderr and "inline_inbuilt" not in result.stderr
