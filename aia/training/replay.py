"""``MemberReplay``: the replay buffers of ``P`` learners in one TorchRL storage with a member dimension.

A ``LazyTensorStorage`` of shape ``[capacity, P]`` holds every member's transitions; members collect in
lockstep (one frame each per world per step), so one write cursor serves all. Each member samples its own
uniform indices from a counter-based stream (:mod:`aia.envs.rng`) keyed by its seed and the number of
batches drawn so far (drawn a block of batches at a time): what member ``k`` replays does not depend on the
other members, the sampler has no state but that count, and sampling needs no host sync on CUDA.
"""

from __future__ import annotations

from collections.abc import Sequence

import torch
from tensordict import TensorDictBase
from torchrl.data import LazyTensorStorage

from aia.envs import rng

# rng purpose of the replay's keys (apart from the env's world streams and the policy's)
REPLAY_PURPOSE = 2


class MemberReplay:
    """Per-member FIFO replay of ``capacity`` transitions and uniform batches of ``batch_size``.

    :meth:`extend` takes ``[T, P]`` transitions (``T`` per member), :meth:`sample` returns ``[P, batch_size]``,
    member ``k``'s row drawn from member ``k``'s own transitions only.
    """

    def __init__(self, capacity: int, batch_size: int, seeds: Sequence[int], device: torch.device | str = "cpu"
                 ) -> None:
        self.capacity = capacity
        self.batch_size = batch_size
        self.num_members = len(seeds)
        self.storage = LazyTensorStorage(capacity * self.num_members, ndim=2, device=device)
        self.keys = rng.seed_keys(list(seeds), REPLAY_PURPOSE, device)
        self.members = torch.arange(self.num_members, device=device).unsqueeze(-1).expand(-1, batch_size)
        self.cursor = 0  # next row written
        self.size = 0  # rows filled
        self._uniforms = rng.CounterStream(rng.uniform, self.keys, 0, batch_size)  # counter: batches drawn

    def __len__(self) -> int:
        return self.size

    @property
    def draws(self) -> int:
        """Batches sampled so far (the members sample in lockstep)."""
        return self._uniforms.counter

    def extend(self, transitions: TensorDictBase) -> None:
        """Append ``[T, P]`` transitions (the oldest rows are overwritten once the buffer is full)."""
        T = transitions.batch_size[0]
        rows = (torch.arange(T) + self.cursor) % self.capacity
        self.storage.set(rows, transitions)
        self.cursor = (self.cursor + T) % self.capacity
        self.size = min(self.size + T, self.capacity)

    def sample(self) -> TensorDictBase:
        """``[P, batch_size]`` transitions, member ``k``'s drawn uniformly (with replacement) from its rows."""
        rows = (self._uniforms.next() * self.size).long()
        return self.storage.get((rows, self.members))

    def member_state(self, member: int) -> dict:
        """Member ``member``'s rows (in their storage order), the write cursor and its sampler's count: what
        a checkpoint keeps (a restored buffer samples the same rows as the one saved)."""
        index = torch.arange(self.size)
        rows = self.storage.get((index, torch.full_like(index, member))).clone() if self.size else None
        return {"transitions": rows, "cursor": self.cursor, "draws": self.draws}

    def load_member_state(self, member: int, state: dict) -> None:
        """Restore member ``member`` from :meth:`member_state` (every member must restore the same rows)."""
        rows: TensorDictBase | None = state["transitions"]
        count = 0 if rows is None else rows.batch_size[0]
        if count > self.capacity:
            raise ValueError(f"a checkpoint of {count} transitions does not fit a buffer of {self.capacity}")
        if count:
            index = torch.arange(count)
            self._ensure_storage(rows)
            self.storage.set((index, torch.full_like(index, member)), rows.to(self.storage.device))
        self.size, self.cursor = count, state["cursor"]
        self._uniforms.counter = state["draws"]

    def _ensure_storage(self, rows: TensorDictBase) -> None:
        """Allocate the storage from one member's rows (a lazy storage takes its layout from its first write)."""
        if not self.storage.initialized:
            self.storage.set(torch.arange(1), rows[:1].unsqueeze(1).expand(1, self.num_members).clone())

