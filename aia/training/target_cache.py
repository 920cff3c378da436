"""``TargetCache``: every replay row's ADFQ target, computed once per target period instead of once per sample.

A transition's ADFQ target (the posterior :meth:`~aia.losses.ADFQLoss.targets` regresses onto) depends only on
the transition and the target network, which changes only at a hard target update. In the paper's regime (a
buffer of 1,000 transitions, a batch of 64, a target copy every 51 updates) the loss would compute it for
51 x 64 = 3,264 sampled transitions per target period; the cache computes it for the buffer's 1,000 rows at the
period's start and for each transition as it is written (one per member per frame), and the update reads it
with the sampled rows. The arithmetic is the same, row by row (a test checks the cached targets against the
loss's own to the bit). Measured on the 2-core CPU (2026-12-03, one thread, 10 members of the 3 x 256 ADFQ
network, bfloat16 inner layers, compiled): the update step 9.7-11.4 ms with cached targets against
17.8-20.7 ms computing them; the buffer's refresh 124-158 ms per period (2.4-3.1 ms a step) and a written
transition's targets 0.5-1.8 ms a step (among 4, see ``_MIN_WRITTEN``). In the whole protocol the ADFQ
populations' update and targets took 0.88x the update's time before (docs/speed.md).
"""

from __future__ import annotations

import torch
from tensordict import TensorDict, TensorDictBase

from aia.compiling import compiled_update
from aia.losses import ADFQLoss
from aia.modules import StackedQNetwork
from aia.training.replay import MemberReplay

# Transitions per member that a write's targets are computed on, the first repeated to fill: the target network
# sees each transition's two observations, and torch 2.13's CPU batched matmul rounds float32 rows of a
# multiplication of 1-3 rows otherwise than the same rows among 4 or more (tested on this VM for every paper
# layer shape): with 4 rows or more, a row's target is the one the buffer's refresh computes, to the bit.
_MIN_WRITTEN = 4


def _targets(loss: ADFQLoss, transitions: TensorDictBase, target_params: TensorDictBase) -> TensorDictBase:
    return loss.targets(transitions, target_params)


class TargetCache:
    """The ADFQ targets of ``replay``'s rows under ``loss``'s current target parameters, sampled with the rows.

    :meth:`refresh` computes every row's target and attaches them to ``replay`` (its samples then carry
    ``target_mean`` and ``target_var``, which :class:`~aia.losses.ADFQLoss` uses instead of computing them);
    :meth:`record` computes the targets of rows as they are written; :meth:`invalidate` marks them all stale
    (call it when the target parameters change). Stale targets are never sampled as long as the caller
    refreshes before sampling whenever :attr:`fresh` is false. ``compile=True`` compiles the two computations
    (the buffer's and one write's shapes, one graph each).
    """

    def __init__(self, loss: ADFQLoss, network: StackedQNetwork, replay: MemberReplay, compile: bool = False
                 ) -> None:
        self.loss = loss
        self.network = network
        self.replay = replay
        self.fresh = False
        self.first_calls = True  # until both computations have run once (they compile on their first call)
        self._params: TensorDictBase | None = None  # the target parameters, in the dtypes their layers multiply in
        self._columns: TensorDictBase | None = None  # [capacity, P]
        self._all_rows = compiled_update(_targets) if compile else _targets
        self._written_rows = compiled_update(_targets) if compile else _targets

    def invalidate(self) -> None:
        """Mark every cached target stale (the target parameters changed)."""
        self.fresh = False

    def refresh(self) -> None:
        """Compute every row's target under the current target parameters (the replay must hold a row)."""
        rows = self.replay.rows
        if rows is None:
            raise RuntimeError("the replay buffer is empty: nothing to compute targets for")
        self._params = self._in_layer_dtypes(self.loss.target_value_network_params.data)
        values = self._all_rows(self.loss, rows.transpose(0, 1), self._params).transpose(0, 1)
        if self._columns is None:
            self._columns = values.contiguous()
            self.replay.attach(self._columns)
        else:
            self._columns.update_(values)
        self.fresh = True

    def record(self, transitions: TensorDictBase, rows: torch.Tensor) -> None:
        """Compute the targets of ``transitions`` (``[T, P]``), just written to ``rows``; nothing while stale
        (the next :meth:`refresh` covers them)."""
        if not self.fresh:
            return
        written = transitions.shape[0]
        if written < _MIN_WRITTEN:  # repeated: see _MIN_WRITTEN
            repeats = transitions[:1].expand(_MIN_WRITTEN - written, *transitions.shape[1:])
            transitions = torch.cat([transitions, repeats])
        values = self._written_rows(self.loss, transitions.transpose(0, 1), self._params)[:, :written]
        for key, column in self._columns.items(include_nested=True, leaves_only=True):
            column.index_copy_(0, rows, values.get(key).transpose(0, 1))
        self.first_calls = False

    def _in_layer_dtypes(self, params: TensorDictBase) -> TensorDictBase:
        """``params`` (the loss's nested parameters) with each layer's tensors cast as the network's forward
        would cast them at every call (:meth:`StackedQNetwork.in_layer_dtypes`), once for the whole period."""
        layers = {key.rsplit(".", 1)[-1]: (key, value) for key, value in params.flatten_keys(".").items()}
        cast = self.network.in_layer_dtypes({name: value for name, (_, value) in layers.items()})
        return TensorDict({key: cast[name] for name, (key, _) in layers.items()}).unflatten_keys(".")
