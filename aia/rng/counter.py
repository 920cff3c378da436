"""Counter-based random streams: one independent, reproducible stream per world (the numbers passed as
``stream`` and ``purpose`` are declared in :mod:`aia.rng.streams`).

A batched env cannot hold one ``torch.Generator`` per world, and a single generator couples the worlds:
what world 3 draws would depend on how many other worlds were reset before it. Here every draw is a
pure function of ``(seed, world, episode, step, stream, slot)``, hashed into 32 random bits with integer
tensor ops, so

* a world's trajectory depends only on the seed, its own index and its own history (partial resets and
  the batch size of the others change nothing);
* the same seed gives the same numbers on CPU and CUDA (integer arithmetic is exact);
* there is no generator state to save beyond the counters the env already keeps.

The hash is Chris Wellons' ``lowbias32`` integer finaliser, applied as a keyed cascade; values live in
the low 32 bits of ``int64`` tensors (products wrap modulo 2**64 and are masked back to 32 bits).
"""

from __future__ import annotations

import math

import torch
from torch import Tensor

_MASK32 = 0xFFFFFFFF
_GOLDEN = 0x9E3779B9


def mix32(x: Tensor) -> Tensor:
    """Bijective 32-bit integer hash (lowbias32) of an int64 tensor holding values in [0, 2**32)."""
    x = x ^ (x >> 16)
    x = (x * 0x7FEB352D) & _MASK32
    x = x ^ (x >> 15)
    x = (x * 0x846CA68B) & _MASK32
    return x ^ (x >> 16)


def world_keys(seed: int, num_worlds: int, device: torch.device | str = "cpu") -> Tensor:
    """Per-world 32-bit keys derived from a user seed (any Python int) and the world index."""
    seed_lo = seed & _MASK32
    seed_hi = (seed >> 32) & _MASK32
    base = mix32(torch.tensor(seed_lo ^ mix32(torch.tensor(seed_hi)).item(), dtype=torch.int64))
    index = torch.arange(num_worlds, dtype=torch.int64, device=device)
    return mix32(mix32(index + _GOLDEN) ^ base.to(device))


def seed_keys(seeds: list[int], purpose: int, device: torch.device | str = "cpu") -> Tensor:
    """``[len(seeds)]`` 32-bit keys, one per seed, for draws made for ``purpose`` (a :class:`~aia.rng.streams.Purpose`:
    it keeps the streams of different users of one seed apart, and apart from the seed's world streams)."""
    keys = [world_keys(int(seed), 1)[0] for seed in seeds]
    return mix32(torch.stack(keys) ^ mix32(torch.tensor(purpose * 0x632BE5AB + _GOLDEN) & _MASK32)).to(device)


def episode_keys(world_key: Tensor, episode: Tensor) -> Tensor:
    """The key of each world's current episode: one fresh stream per (world, episode)."""
    return mix32(world_key ^ mix32((episode + _GOLDEN) & _MASK32))


def random_bits(key: Tensor, counter: Tensor, stream: int, n: int, slots: Tensor | None = None) -> Tensor:
    """``[B, n]`` int64 tensor of 32 random bits for each world's (key, counter, stream) and slot 0..n-1.

    ``key`` and ``counter`` are ``[B]`` int64 tensors; ``stream`` separates the draws made for different
    purposes within the same step; ``counter`` is normally the world's step index within its episode.
    """
    slots = slot_keys(n, key.device) if slots is None else slots
    if slots.shape != (n,):
        raise ValueError(f"slots shaped {tuple(slots.shape)} for {n} draws (slot_keys({n}))")
    step_key = mix32(key ^ mix32((counter * 0x10001 + stream * 0x3C6EF372 + _GOLDEN) & _MASK32))
    return mix32(step_key.unsqueeze(-1) ^ slots)


def slot_keys(n: int, device: torch.device | str = "cpu") -> Tensor:
    """``[n]`` the hashed slot indices that :func:`random_bits` mixes into each draw.

    A caller whose draws run inside ``torch.compile`` passes them in (computed once): traced, ``arange(n) +
    0x9E3779B9`` becomes an index expression that torch 2.11's Triton code generation types as int32, and the
    compile fails ("Scalar 2654435769 is out of range for type int32", seen on an H200 on 2026-12-04)."""
    return mix32(torch.arange(n, dtype=torch.int64, device=device) + _GOLDEN)


def uniform(key: Tensor, counter: Tensor, stream: int, n: int, dtype: torch.dtype = torch.float32,
            slots: Tensor | None = None) -> Tensor:
    """``[B, n]`` uniforms in [0, 1) with 24 random bits each (exact in float32)."""
    bits = random_bits(key, counter, stream, n, slots) >> 8
    return bits.to(dtype) * (1.0 / (1 << 24))


def normal(key: Tensor, counter: Tensor, stream: int, n: int, dtype: torch.dtype = torch.float32,
           slots: Tensor | None = None) -> Tensor:
    """``[B, n]`` standard normals by the Box-Muller transform of ``2 * ceil(n / 2)`` uniforms (``slots``:
    ``slot_keys(2 * ceil(n / 2))``, or ``None``)."""
    half = (n + 1) // 2
    u = uniform(key, counter, stream, 2 * half, dtype, slots)
    radius = torch.sqrt(-2.0 * torch.log1p(-u[:, :half]))  # 1 - u lies in (0, 1]: no log(0)
    angle = (2.0 * math.pi) * u[:, half:]
    return torch.cat((radius * torch.cos(angle), radius * torch.sin(angle)), dim=-1)[:, :n]


class CounterStream:
    """Successive draws of ``draw(keys, counter, stream, n)`` (:func:`uniform` or :func:`normal`) for
    counters ``start, start + 1, ...``, computed ``chunk`` counters at a time.

    The same numbers as one call per counter (a draw depends only on its key, counter, stream and slot), at a
    fraction of the cost: a draw is a cascade of about 20 small integer ops, so a loop that draws every step
    pays their per-op overhead once per ``chunk`` steps instead of every step. :attr:`counter` is the next
    counter; setting it (a restored checkpoint) drops the cached block.
    """

    def __init__(self, draw, keys: Tensor, stream: int, n: int, dtype: torch.dtype = torch.float64,
                 start: int = 0, chunk: int | None = None) -> None:
        self.draw, self.keys, self.stream, self.n, self.dtype = draw, keys, stream, n, dtype
        self.chunk = chunk or max(1, min(256, (1 << 20) // max(1, keys.shape[0] * n)))
        self._block: Tensor | None = None
        self._first = start
        self.counter = start

    @property
    def counter(self) -> int:
        """The counter of the next draw."""
        return self._counter

    @counter.setter
    def counter(self, value: int) -> None:
        self._counter = int(value)
        if not self._first <= self._counter < self._first + self.chunk:
            self._block = None

    def next(self) -> Tensor:
        """``[len(keys), n]``: the draws at :attr:`counter`, which then advances by one."""
        if self._block is None:
            self._first = self._counter
            members = self.keys.shape[0]
            counters = torch.arange(self._first, self._first + self.chunk, device=self.keys.device)
            flat = self.draw(self.keys.repeat(self.chunk), counters.repeat_interleave(members), self.stream, self.n,
                             self.dtype)
            self._block = flat.reshape(self.chunk, members, self.n)
        out = self._block[self._counter - self._first]
        self.counter = self._counter + 1
        return out
