"""``TargetCache``: every replay row's ADFQ target, computed once per target period instead of once per sample.

A transition's ADFQ target (:meth:`~aia.losses.ADFQLoss.target_posterior`, which the loss regresses onto) depends
only on the transition and the target network, which changes only at a hard target update. In the paper's regime (a
buffer of 1,000 transitions, a batch of 64, a target copy every 51 updates) the loss would compute it for
51 x 64 = 3,264 sampled transitions per target period; the cache computes it for the buffer's 1,000 rows at the
period's start and for each transition as it is written (one per member per frame), and the update reads it
with the sampled rows. The arithmetic is the same, row by row (a test checks the cached targets against the
loss's own to the bit). Measured on the 2-core CPU (one thread, 10 members of the 3 x 256 ADFQ
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

from aia.losses import ADFQLoss
from aia.modules import StackedConvQNetwork, StackedQNetwork
from aia.runtime.compiling import compiled_update
from aia.training.replay import MemberReplay

# Transitions per member that a write's targets are computed on, the first repeated to fill: the target network
# sees each transition's two observations, and torch 2.13's CPU batched matmul rounds float32 rows of a
# multiplication of 1-3 rows otherwise than the same rows among 4 or more (tested for every paper
# layer shape): with 4 rows or more, a row's target is the one the buffer's refresh computes, to the bit.
_MIN_WRITTEN = 4

# The refresh's network calls take a multiple of this many rows (repeating some): with one member and two threads,
# MKL splits a call's rows between the threads, and a thread's share of other than a multiple of 4 rows rounds
# its last rows otherwise (measured: the last 2 of 10 rows, against the same rows among 4 or 128).
_NETWORK_ROWS_MULTIPLE = 8


# Transitions (rows x members) whose targets the buffer's refresh computes at a time: the posterior's per-action
# intermediates of about this many transitions fit in a core's L2 cache. Measured (one thread, 10
# members, 12 actions, compiled): the posterior of the buffer's 10,000 transitions took 53 ms in chunks of 125
# rows against 85 ms at once (and 56-57 ms in chunks of 50 or 250 rows), with the same results to the bit.
_CHUNK_TRANSITIONS = 1250

# Observations (rows x members) the refresh's target network runs on at a time: each call packs every member's
# weights for MKL's products anew, so the network takes larger chunks than the posterior. Measured (one thread, 40
# members of 3 x 256, small3, a full buffer, compiled, two runs): the network's rows 184 ms a refresh in chunks of
# 250 rows against about 280 ms in the posterior's chunks of 31, the refresh 371-390 against 433-465 ms; with 3 x
# 128 (empty1) 269 against 363 ms; at 10 members no change (111 against 114 ms). The same beliefs to the bit in
# every case (and in chunks of 62, 125 and all 1,000 rows).
_NETWORK_CHUNK_TRANSITIONS = 10000


def _chunks(rows: int, members: int, transitions: int = _CHUNK_TRANSITIONS) -> list[slice]:
    """Row ranges of one size (one compiled graph) covering ``rows``: about ``transitions / members`` rows
    each, at least ``_MIN_WRITTEN``; the last one ends at ``rows`` and overlaps its predecessor where the size
    does not divide ``rows`` (its overlapping rows are computed twice, to the same values)."""
    size = min(rows, max(_MIN_WRITTEN, transitions // members))
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


def _tensordict(keys: tuple[NestedKey, ...], leaves: tuple[torch.Tensor, ...]) -> TensorDictBase:
    """The ``[P, rows]`` tensordict of entries ``keys`` = ``leaves``, built inside a compiled function.

    Tensors rather than a tensordict go into the graphs below, so that a compiled copy is one graph for any
    number of rows (the rows dimension marked dynamic): a tensordict's batch size would fix it."""
    tensordict = TensorDict(batch_size=leaves[0].shape[:2])
    for key, leaf in zip(keys, leaves, strict=True):
        tensordict.set(key, leaf)
    return tensordict


def _targets(loss: ADFQLoss, keys: tuple[NestedKey, ...], leaves: tuple[torch.Tensor, ...],
             target_params: TensorDictBase) -> tuple[torch.Tensor, torch.Tensor]:
    """:meth:`ADFQLoss.target_posterior` ``[P, rows]`` of the transitions whose entries ``keys`` are ``leaves``
    (a write's rows: the network on their ``s`` and ``s'`` and the posterior in one graph)."""
    return loss.target_posterior(_tensordict(keys, leaves), target_params)


def _beliefs(loss: ADFQLoss, keys: tuple[NestedKey, ...], leaves: tuple[torch.Tensor, ...],
             target_params: TensorDictBase) -> tuple[torch.Tensor, torch.Tensor]:
    """:meth:`ADFQLoss.target_beliefs` ``[P, rows, A]`` at the observations whose in_keys ``keys`` are ``leaves``
    (``[P, rows, ...]``): the refresh's network rows."""
    return loss.target_beliefs(_tensordict(keys, leaves), target_params)


def _posterior(loss: ADFQLoss, keys: tuple[NestedKey, ...], leaves: tuple[torch.Tensor, ...], means: torch.Tensor,
               log_sds: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """:meth:`ADFQLoss.posterior_of_beliefs` ``[P, rows]`` of the transitions whose entries ``keys`` (the action,
    the next reward and terminated flag) are ``leaves``, from the target beliefs ``[P, rows, 2, A]`` at their
    ``s`` (``[..., 0, :]``) and ``s'`` (``[..., 1, :]``): the refresh's posterior."""
    return loss.posterior_of_beliefs(_tensordict(keys, leaves), (means[..., 0, :], log_sds[..., 0, :]),
                                     (means[..., 1, :], log_sds[..., 1, :]))


class TargetCache:
    """The ADFQ targets of ``replay``'s rows under ``loss``'s current target parameters, sampled with the rows.

    :meth:`refresh` computes every filled row's target and attaches them to ``replay`` (its samples then carry
    ``target_mean`` and ``target_var``, which :class:`~aia.losses.ADFQLoss` uses instead of computing them);
    :meth:`record` computes the targets of rows as they are written; :meth:`invalidate` marks them all stale
    (call it when the target parameters change). Stale targets are never sampled as long as the caller
    refreshes before sampling whenever :attr:`fresh` is false. ``worlds``: the transitions written per member
    at a time, one per world (row ``i``'s ``s`` is usually row ``i - worlds``'s ``s'``, see :meth:`refresh`).
    ``compile=True`` compiles the computations (a write's, the refresh's network rows and its posterior: each
    one graph, dynamic in the number of rows).
    """

    def __init__(self, loss: ADFQLoss, network: StackedQNetwork | StackedConvQNetwork, replay: MemberReplay,
                 worlds: int = 1, compile: bool = False) -> None:
        self.loss = loss
        self.network = network
        self.replay = replay
        self.worlds = worlds
        self.fresh = False
        self._first_calls = {"refresh", "record"}  # not yet run (their first calls compile)
        keys = loss.tensor_keys
        self._observation_keys = tuple(loss.value_network.in_keys)
        self._posterior_keys = (keys.action, ("next", keys.reward), ("next", keys.terminated))
        self._params: TensorDictBase | None = None  # the target parameters, in the dtypes their layers multiply in
        self._columns: TensorDictBase | None = None  # [capacity, P], attached to the replay
        self._beliefs_store: tuple[torch.Tensor, ...] = ()  # means, log sds [P, capacity, 2, A]: s, s' per row
        self._targets = compiled_update(_targets) if compile else _targets
        self._beliefs = compiled_update(_beliefs) if compile else _beliefs
        self._posterior = compiled_update(_posterior) if compile else _posterior
        self._staged: _StagedRows | None = None  # what record computes on

    @property
    def first_calls(self) -> bool:
        """Whether :meth:`refresh` or a computing :meth:`record` has yet to run once (a first call compiles)."""
        return bool(self._first_calls)

    def invalidate(self) -> None:
        """Mark every cached target stale (the target parameters changed)."""
        self.fresh = False

    def refresh(self) -> None:
        """Compute every filled row's target under the current target parameters (the replay must hold a row).

        The target network runs once on every row's ``s'`` and, for ``s``, only on the rows whose ``s`` is not
        the ``s'`` of the row written ``worlds`` rows before (the same world's previous step; not so at an
        episode's first step and at the write cursor): a row's network outputs do not depend on the other rows
        of its call (see ``_MIN_WRITTEN``), so a shared row's beliefs at ``s`` are those its own call would
        give. Rows not yet filled are left out (never sampled). Measured on the 2-core CPU (20 members
        of 3 x 256, compiled, a full buffer of 1,000 rows, two jobs each): a refresh took 117 ms against 150-177
        ms with the network on both observations of every row, 1.9 against 2.5-2.9 ms a step."""
        rows = self.replay.rows
        if rows is None:
            raise RuntimeError("the replay buffer is empty: nothing to compute targets for")
        self._params = self._in_layer_dtypes(self.loss.target_value_network_params.data)
        capacity, members = rows.shape
        filled = max(len(self.replay), min(_MIN_WRITTEN, capacity))  # rows sampled (past them: copies)
        rows = rows[:filled]
        observations = tuple(rows.get(key) for key in self._observation_keys)
        next_observations = tuple(rows.get(("next", key)) for key in self._observation_keys)
        indices = torch.arange(filled, device=self.replay.device)
        self._network_rows(next_observations, indices, 1)
        previous = (indices - self.worlds) % filled
        shared = torch.ones(filled, dtype=torch.bool, device=self.replay.device)
        for now, before in zip(observations, next_observations, strict=True):
            shared &= (now == before[previous]).flatten(1).all(1)
        for store in self._beliefs_store:
            store[:, :filled, 0] = store[:, previous, 1]
        own = (~shared).nonzero().squeeze(1)  # a host read, once per target period
        if own.numel():
            self._network_rows(tuple(leaf[own] for leaf in observations), own, 0)
        leaves = tuple(rows.get(key) for key in self._posterior_keys)
        for chunk in _chunks(filled, members):
            means, log_sds = (store[:, chunk] for store in self._beliefs_store)
            values = self._posterior(self.loss, self._posterior_keys, _members_first(leaves, chunk),
                                     *_rows_dynamic((means, log_sds)))
            if self._columns is None:
                self._attach_columns(values)
            for column, value in zip(self._columns.values(), values, strict=True):
                column[chunk] = value.transpose(0, 1)
        self.fresh = True
        self._first_calls.discard("refresh")

    def record(self, transitions: TensorDictBase, rows: torch.Tensor) -> None:
        """Compute the targets of ``transitions`` (``[T, P]``), just written to ``rows``; nothing while stale
        (the next :meth:`refresh` covers them)."""
        if not self.fresh:
            return
        written = transitions.batch_size[0]
        if self._staged is None or self._staged.rows != max(written, _MIN_WRITTEN):
            self._staged = _StagedRows(transitions)
        values = self._targets(self.loss, self._staged.keys, self._staged.fill(transitions), self._params)
        for column, value in zip(self._columns.values(), values, strict=True):
            column.index_copy_(0, rows, value[:, :written].transpose(0, 1))
        self._first_calls.discard("record")

    def _network_rows(self, observations: tuple[torch.Tensor, ...], rows: torch.Tensor, slot: int) -> None:
        """The target network's beliefs at ``observations`` (``[n, P, ...]`` per in_key) into the beliefs store's
        ``rows`` at ``slot`` (0: ``s``, 1: ``s'``), in the refresh's chunks of rows, the first rows repeated
        to a multiple of ``_NETWORK_ROWS_MULTIPLE``."""
        count, members = observations[0].shape[:2]
        padded = -(-count // _NETWORK_ROWS_MULTIPLE) * _NETWORK_ROWS_MULTIPLE
        if padded != count:
            repeated = torch.arange(padded, device=rows.device) % count
            observations, rows = tuple(leaf[repeated] for leaf in observations), rows[repeated]
        for chunk in _chunks(padded, members, _NETWORK_CHUNK_TRANSITIONS):
            chunk_observations = tuple(leaf[chunk].transpose(0, 1).contiguous() for leaf in observations)
            values = self._beliefs(self.loss, self._observation_keys, _rows_dynamic(chunk_observations),
                                   self._params)
            if not self._beliefs_store:
                capacity = self.replay.capacity
                self._beliefs_store = tuple(value.new_empty((members, capacity, 2, *value.shape[2:]))
                                            for value in values)
            kept = slice(0, max(0, min(chunk.stop, count) - chunk.start))  # the repeated rows left out
            for store, value in zip(self._beliefs_store, values, strict=True):
                store[:, rows[chunk][kept], slot] = value[:, kept]

    def _attach_columns(self, values: tuple[torch.Tensor, torch.Tensor]) -> None:
        """Allocate the target columns ``[capacity, P]`` (like the first ``values``) and attach them to the replay."""
        capacity, members = self.replay.rows.shape
        keys = self.loss.tensor_keys
        columns = (value[:, :1].expand(members, capacity).transpose(0, 1).contiguous() for value in values)
        self._columns = TensorDict(dict(zip((keys.target_mean, keys.target_var), columns, strict=True)),
                                   batch_size=(capacity, members))
        self.replay.attach(self._columns)

    def _in_layer_dtypes(self, params: TensorDictBase) -> TensorDictBase:
        """``params`` (the loss's nested parameters) with each layer's tensors cast as the network's forward
        would cast them at every call (:meth:`StackedQNetwork.in_layer_dtypes`), once for the whole period."""
        flat = params.flatten_keys(".")
        # the loss keys each parameter by the actor's path to the network and the network's own name
        names = [name for name, _ in self.network.named_parameters()]
        own = {key: next(name for name in names if key.endswith(f".{name}")) for key, _ in flat.items()}
        cast = self.network.in_layer_dtypes({own[key]: value for key, value in flat.items()})
        return TensorDict({key: cast[name] for key, name in own.items()}).unflatten_keys(".")


def _members_first(leaves: tuple[torch.Tensor, ...], chunk: slice) -> tuple[torch.Tensor, ...]:
    """The ``[P, rows]`` views of ``leaves``' (``[rows, P, ...]``) rows ``chunk``, rows marked dynamic."""
    return _rows_dynamic(tuple(leaf[chunk].transpose(0, 1) for leaf in leaves))


class _StagedRows:
    """Buffers, allocated once, that a write's ``[T, P]`` transitions are copied into for :meth:`TargetCache.record`:
    at least ``_MIN_WRITTEN`` rows, the rows past ``T`` holding earlier staged transitions (the first one, at
    first; a row's targets do not depend on the other rows' values, only on their number: see ``_MIN_WRITTEN``),
    handed to the targets' graph as ``[P, rows]`` views marked dynamic once. Concatenating the
    repeated rows as a tensordict and reading its keys and the result through tensordict calls cost 0.35 ms of
    Python a write. Measured on the 2-core CPU (compiled ADFQ-TS 3 x 256, three interleaved rounds), a write's
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
