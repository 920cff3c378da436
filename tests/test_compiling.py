"""aia.compiling: private compiled copies keep their own cache, guarded only on tensors and global state."""

from __future__ import annotations

import pytest
import torch
from torch import nn

from aia.compiling import compiled_update, private_copy


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
