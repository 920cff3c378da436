"""``TargetCache``: every replay row's ADFQ target, computed once per target period instead of once per sample.

A transition's ADFQ target (the posterior :meth:`~aia.losses.ADFQLoss.targets` regresses onto) depends only on
the transition and the target network, which changes only at a hard target update. In the paper's regime (a
buffer of 1,000 transitions, a batch of 64, a target copy every 51 updates) the loss would compute it for
51 x 64 = 3,264 sampled transitions per target period; the cache computes it for the buffer's 1,000 rows at the
period's start and for each transition as it is written (one per member per frame), and the update reads it
with the sampled rows. The arithmetic is the same, row by row (a test checks the cached targets against the
loss's own to the bit). Measured on the 2-core CPU (2026-12-03, one thread, 10 members of the 3 x 256 ADFQ
network, bfloat16 inner layers, compiled): the update step 9.7-11.4 ms with cached targets against
17.8-20.7 ms computing them; the buffer's refresh 124-158 ms per period (2.4-3.1 ms a step; 109-157 ms in
chunks, see ``_CHUNK_TRANSITIONS``) and a written transition's targets 0.5-1.8 ms a step (among 4, see
``_MIN_WRITTEN``). In the whole protocol the ADFQ
populations' update and targets took 0.88x the update's time before (docs/speed.md).
"""

from __future__ import annotations

import torch
from tensordict import TensorDict, TensorDictBase
from tensordict.utils import NestedKey

from aia.compiling import compiled_update
from aia.losses import ADFQLoss
from aia.modules import StackedQNetwork
from aia.training.replay import MemberReplay

# Transitions per member that a write's targets are computed on, the first repeated to fill: the target network
# sees each transition's two observations, and torch 2.13's CPU batched matmul rounds float32 rows of a
# multiplication of 1-3 rows otherwise than the same rows among 4 or more (tested on this VM for every paper
# layer shape): with 4 rows or more, a row's target is the one the buffer's refresh computes, to the bit.
_MIN_WRITTEN = 4


# Transitions (rows x members) whose targets the buffer's refresh computes at a time: the posterior's per-action
# intermediates of about this many transitions fit in a core's L2 cache. Measured (2026-12-03, one thread, 10
# members, 12 actions, compiled): the posterior of the buffer's 10,000 transitions took 53 ms in chunks of 125
# rows against 85 ms at once (and 56-57 ms in chunks of 50 or 250 rows), with the same results to the bit.
_CHUNK_TRANSITIONS = 1250


def _chunks(rows: int, members: int) -> list[slice]:
    """Row ranges of one size (one compiled graph) covering ``rows``: about ``_CHUNK_TRANSITIONS / members`` rows
    each, at least ``_MIN_WRITTEN``; the last one ends at ``rows`` and overlaps its predecessor where the size
    does not divide ``rows`` (its overlapping rows are computed twice, to the same values)."""
    size = min(rows, max(_MIN_WRITTEN, _CHUNK_TRANSITIONS // members))
    starts = list(range(0, rows - size + 1, size))
    if starts[-1] + size < rows:
        starts.append(rows - size)
    return [slice(start, start + size) for start in starts]


def _rows_dynamic(leaves: tuple[torch.Tensor, ...]) -> tuple[torch.Tensor, ...]:
    """``leaves`` (``[P, rows, ...]``) with their rows dimension marked dynamic where it has more than one row, so
    that the buffer's chunks and a write's rows share one compiled graph (dynamo specialises sizes 0 and 1)."""
    if leaves[0].shape[1] > 1:
        for leaf in leaves:
            torch._dynamo.mark_dynamic(leaf, 1)
    return leaves


def _targets(loss: ADFQLoss, keys: tuple[NestedKey, ...], leaves: tuple[torch.Tensor, ...],
             target_params: TensorDictBase) -> TensorDictBase:
    """:meth:`ADFQLoss.targets` ``[P, rows]`` of the transitions whose entries ``keys`` are ``leaves``.

    Tensors rather than a tensordict go in, so that a compiled copy is one graph for any number of rows (the
    rows dimension marked dynamic): a tensordict's batch size would fix it. A second graph (the buffer's
    chunks and a write's rows each had one) cost 11 s of compiling from a cold cache (10 members of 3 x 128,
    2026-12-03)."""
    transitions = TensorDict(batch_size=leaves[0].shape[:2])
    for key, leaf in zip(keys, leaves, strict=True):
        transitions.set(key, leaf)
    return loss.targets(transitions, target_params)


class TargetCache:
    """The ADFQ targets of ``replay``'s rows under ``loss``'s current target parameters, sampled with the rows.

    :meth:`refresh` computes every row's target and attaches them to ``replay`` (its samples then carry
    ``target_mean`` and ``target_var``, which :class:`~aia.losses.ADFQLoss` uses instead of computing them);
    :meth:`record` computes the targets of rows as they are written; :meth:`invalidate` marks them all stale
    (call it when the target parameters change). Stale targets are never sampled as long as the caller
    refreshes before sampling whenever :attr:`fresh` is false. ``compile=True`` compiles the computation (one
    graph for the buffer's chunks and a write's rows, dynamic in the number of rows).
    """

    def __init__(self, loss: ADFQLoss, network: StackedQNetwork, replay: MemberReplay, compile: bool = False
                 ) -> None:
        self.loss = loss
        self.network = network
        self.replay = replay
        self.fresh = False
        self.first_calls = True  # until the first refresh has run (it compiles)
        self._params: TensorDictBase | None = None  # the target parameters, in the dtypes their layers multiply in
        self._columns: TensorDictBase | None = None  # [capacity, P], attached to the replay
        self._targets = compiled_update(_targets) if compile else _targets
        self._staged: _StagedRows | None = None  # what record computes on

    def invalidate(self) -> None:
        """Mark every cached target stale (the target parameters changed)."""
        self.fresh = False

    def refresh(self) -> None:
        """Compute every row's target under the current target parameters (the replay must hold a row)."""
        rows = self.replay.rows
        if rows is None:
            raise RuntimeError("the replay buffer is empty: nothing to compute targets for")
        self._params = self._in_layer_dtypes(self.loss.target_value_network_params.data)
        capacity, members = rows.shape
        for chunk in _chunks(capacity, members):
            values = self._compute(rows[chunk].transpose(0, 1)).transpose(0, 1)
            if self._columns is None:
                self._columns = values[:1].expand(capacity, members).clone()
                self.replay.attach(self._columns)
            self._columns[chunk] = values
        self.fresh = True
        self.first_calls = False

    def record(self, transitions: TensorDictBase, rows: torch.Tensor) -> None:
        """Compute the targets of ``transitions`` (``[T, P]``), just written to ``rows``; nothing while stale
        (the next :meth:`refresh` covers them)."""
        if not self.fresh:
            return
        written = transitions.batch_size[0]
        if self._staged is None or self._staged.rows != max(written, _MIN_WRITTEN):
            self._staged = _StagedRows(transitions)
        values = self._targets(self.loss, self._staged.keys, self._staged.fill(transitions), self._params)
        for key, column in self._columns.items(include_nested=True, leaves_only=True):
            column.index_copy_(0, rows, values.get(key)[:, :written].transpose(0, 1))

    def _compute(self, transitions: TensorDictBase) -> TensorDictBase:
        """The targets ``[P, rows]`` of ``transitions`` (``[P, rows]``) under this period's target parameters."""
        keys = tuple(transitions.keys(include_nested=True, leaves_only=True))
        leaves = _rows_dynamic(tuple(transitions.get(key) for key in keys))
        return self._targets(self.loss, keys, leaves, self._params)

    def _in_layer_dtypes(self, params: TensorDictBase) -> TensorDictBase:
        """``params`` (the loss's nested parameters) with each layer's tensors cast as the network's forward
        would cast them at every call (:meth:`StackedQNetwork.in_layer_dtypes`), once for the whole period."""
        layers = {key.rsplit(".", 1)[-1]: (key, value) for key, value in params.flatten_keys(".").items()}
        cast = self.network.in_layer_dtypes({name: value for name, (_, value) in layers.items()})
        return TensorDict({key: cast[name] for name, (key, _) in layers.items()}).unflatten_keys(".")


class _StagedRows:
    """Buffers, allocated once, that a write's ``[T, P]`` transitions are copied into for :meth:`TargetCache.record`:
    at least ``_MIN_WRITTEN`` rows, the rows past ``T`` holding earlier staged transitions (the first one, at
    first; a row's targets do not depend on the other rows' values, only on their number: see ``_MIN_WRITTEN``),
    handed to the targets' graph as ``[P, rows]`` views marked dynamic once. Before, each write concatenated the
    repeated rows as a tensordict and read its keys and the result through tensordict calls: 0.35 ms of Python a
    write. Measured on the 2-core VM (2026-12-04, compiled ADFQ-TS 3 x 256, three interleaved rounds), a write's
    targets took 0.42-0.47 against 0.74-0.83 ms for one member and 1.68-1.97 against 2.12-2.25 ms for twenty,
    with the same targets to the bit."""

    def __init__(self, transitions: TensorDictBase) -> None:
        self.keys = tuple(transitions.keys(include_nested=True, leaves_only=True))
        written = transitions.batch_size[0]
        self.rows = max(written, _MIN_WRITTEN)
        first = transitions[:1].expand(self.rows, *transitions.batch_size[1:])
        self._buffers = tuple(first.get(key).clone() for key in self.keys)  # [rows, P, ...] each
        self._views = _rows_dynamic(tuple(buffer.transpose(0, 1) for buffer in self._buffers))  # [P, rows, ...]

    def fill(self, transitions: TensorDictBase) -> tuple[torch.Tensor, ...]:
        """``transitions`` (``[T, P]``) copied into the first ``T`` rows; returns the ``[P, rows]`` views."""
        written = transitions.batch_size[0]
        for key, buffer in zip(self.keys, self._buffers, strict=True):
            buffer[:written].copy_(transitions.get(key))
        return self._views
