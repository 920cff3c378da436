"""Tests of aia/rng/counter.py: the counter-based per-world random streams."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from aia import rng

MASK = 0xFFFFFFFF


def _lowbias32(x: int) -> int:
    """Reference lowbias32 (Chris Wellons) on Python ints."""
    x ^= x >> 16
    x = (x * 0x7FEB352D) & MASK
    x ^= x >> 15
    x = (x * 0x846CA68B) & MASK
    x ^= x >> 16
    return x


def _keys(seed: int, worlds: int, episode: int = 0) -> torch.Tensor:
    return rng.episode_keys(rng.world_keys(seed, worlds), torch.full((worlds,), episode, dtype=torch.int64))


# ------------------------------------------------------------------- mix32
def test_mix32_matches_reference_lowbias32():
    g = np.random.default_rng(0)
    xs = [0, 1, 2, 0x7FFFFFFF, 0x80000000, MASK, MASK - 1] + [int(v) for v in g.integers(0, 2**32, size=200)]
    out = rng.mix32(torch.tensor(xs, dtype=torch.int64)).tolist()
    assert out == [_lowbias32(x) for x in xs]
    # lowbias32 fixes 0.
    assert out[0] == 0


@pytest.mark.parametrize("start", [0, 2**31 - 2**15, 2**32 - 2**16])
def test_mix32_bijective_on_consecutive_inputs(start):
    x = torch.arange(start, start + 2**16, dtype=torch.int64)
    out = rng.mix32(x)
    assert out.dtype == torch.int64
    assert out.min().item() >= 0 and out.max().item() < 2**32
    assert torch.unique(out).numel() == 2**16
    # Avalanche: consecutive inputs differ in about 16 of 32 output bits.
    flips = (out[1:] ^ out[:-1])
    popcount = sum(((flips >> k) & 1) for k in range(32)).double()
    assert popcount.mean().item() == pytest.approx(16.0, abs=0.2)


# --------------------------------------------------------------- uniforms
def test_uniform_moments_and_range():
    keys = _keys(seed=7, worlds=1000)
    counter = torch.zeros(1000, dtype=torch.int64)
    u = rng.uniform(keys, counter, stream=0, n=1000, dtype=torch.float64)
    assert u.shape == (1000, 1000)
    n = u.numel()
    assert u.min().item() >= 0.0 and u.max().item() < 1.0
    # 24-bit grid.
    scaled = u * 2**24
    assert (scaled == scaled.floor()).all()
    mean = u.mean().item()
    assert abs(mean - 0.5) < 4 * math.sqrt(1 / 12 / n)
    var = u.var().item()
    # Var of the sample variance of U(0,1): (mu4 - sigma^4) / n with mu4 = 1/80.
    assert abs(var - 1 / 12) < 5 * math.sqrt((1 / 80 - 1 / 144) / n)
    # Histogram: 100 bins, chi-square with 99 dof (mean 99, sd 14): well under 99 + 6 sd.
    counts = torch.bincount((u.flatten() * 100).long(), minlength=100).double()
    chi2 = (((counts - n / 100) ** 2) / (n / 100)).sum().item()
    assert chi2 < 99 + 6 * math.sqrt(2 * 99)


def test_uniform_float32_exact_and_in_range():
    u = rng.uniform(_keys(1, 64), torch.arange(64, dtype=torch.int64), stream=3, n=4096)
    assert u.dtype == torch.float32
    assert u.min().item() >= 0.0 and u.max().item() < 1.0
    u64 = rng.uniform(_keys(1, 64), torch.arange(64, dtype=torch.int64), stream=3, n=4096,
                      dtype=torch.float64)
    assert torch.equal(u.double(), u64)


# ---------------------------------------------------------------- normals
def test_normal_moments():
    z = rng.normal(_keys(seed=11, worlds=1000), torch.full((1000,), 5, dtype=torch.int64), stream=1, n=1000,
                   dtype=torch.float64)
    assert z.shape == (1000, 1000)
    n = z.numel()
    mean = z.mean().item()
    var = z.var().item()
    centred = z - mean
    kurt = ((centred**4).mean() / (centred**2).mean() ** 2).item()
    skew = ((centred**3).mean() / (centred**2).mean() ** 1.5).item()
    assert abs(mean) < 5 / math.sqrt(n)
    assert abs(var - 1) < 5 * math.sqrt(2 / n)
    assert abs(skew) < 5 * math.sqrt(6 / n)
    assert abs(kurt - 3) < 5 * math.sqrt(24 / n)
    # Tail mass P(|z| > 2) = 0.0455.
    tail = (z.abs() > 2).double().mean().item()
    assert abs(tail - 0.04550026) < 5 * math.sqrt(0.0455 * 0.9545 / n)
    assert torch.isfinite(z).all()


def test_normal_odd_n_and_shapes():
    keys = _keys(2, 3)
    counter = torch.zeros(3, dtype=torch.int64)
    z = rng.normal(keys, counter, stream=0, n=5)
    assert z.shape == (3, 5)
    z1 = rng.normal(keys, counter, stream=0, n=1)
    assert z1.shape == (3, 1)
    # Box-Muller pairs: n = 5 uses 6 uniforms (u[:3] radius, u[3:] angle); n = 6 uses the same 6 uniforms,
    # so the first 5 normals coincide.
    z6 = rng.normal(keys, counter, stream=0, n=6)
    torch.testing.assert_close(z6[:, :5], z, rtol=0, atol=0)


# ------------------------------------------------------------ independence
def test_worlds_are_uncorrelated():
    n = 200_000
    keys = _keys(seed=3, worlds=4)
    counter = torch.zeros(4, dtype=torch.int64)
    u = rng.uniform(keys, counter, stream=0, n=n, dtype=torch.float64)
    c = torch.corrcoef(u)
    off = c[~torch.eye(4, dtype=torch.bool)]
    assert off.abs().max().item() < 5 / math.sqrt(n)
    # Neighbouring counters and streams of one world are uncorrelated too.
    key = keys[:1]
    a = rng.uniform(key, torch.tensor([0]), stream=0, n=n, dtype=torch.float64)[0]
    b = rng.uniform(key, torch.tensor([1]), stream=0, n=n, dtype=torch.float64)[0]
    s = rng.uniform(key, torch.tensor([0]), stream=1, n=n, dtype=torch.float64)[0]
    for other in (b, s):
        corr = torch.corrcoef(torch.stack((a, other)))[0, 1].item()
        assert abs(corr) < 5 / math.sqrt(n)
    # Lag-1 autocorrelation within a stream.
    lag = torch.corrcoef(torch.stack((a[:-1], a[1:])))[0, 1].item()
    assert abs(lag) < 5 / math.sqrt(n)


def test_across_counters_many_worlds_uncorrelated():
    # World w at step t vs world w at step t+1, over 10k worlds: the per-step key schedule decorrelates.
    worlds = 10_000
    keys = _keys(seed=99, worlds=worlds)
    t0 = rng.uniform(keys, torch.full((worlds,), 10, dtype=torch.int64), stream=2, n=8, dtype=torch.float64)
    t1 = rng.uniform(keys, torch.full((worlds,), 11, dtype=torch.int64), stream=2, n=8, dtype=torch.float64)
    corr = torch.corrcoef(torch.stack((t0.flatten(), t1.flatten())))[0, 1].item()
    assert abs(corr) < 5 / math.sqrt(t0.numel())


# ------------------------------------------------------------- determinism
def test_same_inputs_same_bits():
    counter = torch.tensor([0, 3, 7], dtype=torch.int64)
    a = rng.random_bits(_keys(12345, 3, episode=2), counter, stream=4, n=16)
    b = rng.random_bits(_keys(12345, 3, episode=2), counter.clone(), stream=4, n=16)
    assert torch.equal(a, b)
    assert a.min().item() >= 0 and a.max().item() < 2**32
    # A world's bits depend only on its own (key, counter): evaluate world 1 alone.
    alone = rng.random_bits(_keys(12345, 3, episode=2)[1:2], counter[1:2], stream=4, n=16)
    assert torch.equal(alone[0], a[1])


def test_different_stream_counter_episode_give_different_bits():
    keys = _keys(5, 8)
    counter = torch.arange(8, dtype=torch.int64)
    base = rng.random_bits(keys, counter, stream=0, n=32)
    other_stream = rng.random_bits(keys, counter, stream=1, n=32)
    other_counter = rng.random_bits(keys, counter + 1, stream=0, n=32)
    other_episode = rng.random_bits(_keys(5, 8, episode=1), counter, stream=0, n=32)
    other_seed = rng.random_bits(_keys(6, 8), counter, stream=0, n=32)
    for other in (other_stream, other_counter, other_episode, other_seed):
        # Independent 32-bit draws coincide with probability 2^-32: none of the 256 may match.
        assert (other != base).all()
    # And the slots within one draw are all different.
    assert all(torch.unique(row).numel() == 32 for row in base)


def test_world_key_independent_of_batch_size():
    for seed in (0, 1, 2**31 + 5, 2**40 + 3):
        k4 = rng.world_keys(seed, 4)
        k2 = rng.world_keys(seed, 2)
        assert torch.equal(k4[:2], k2)
        assert torch.equal(rng.world_keys(seed, 1000)[:4], k4)
        assert torch.unique(rng.world_keys(seed, 1000)).numel() == 1000


def test_large_seeds():
    seed = 2**40 + 3
    keys = rng.world_keys(seed, 4)
    assert keys.dtype == torch.int64
    assert keys.min().item() >= 0 and keys.max().item() < 2**32
    # The high bits of the seed matter: 2**40 + 3 differs from 3 and from 2**41 + 3.
    assert not torch.equal(keys, rng.world_keys(3, 4))
    assert not torch.equal(keys, rng.world_keys(2**41 + 3, 4))
    assert not torch.equal(keys, rng.world_keys(2**40 + 4, 4))
    zeros = torch.zeros(4, dtype=torch.int64)
    u = rng.uniform(rng.episode_keys(keys, zeros), zeros, 0, 10_000, dtype=torch.float64)
    assert abs(u.mean().item() - 0.5) < 5 * math.sqrt(1 / 12 / u.numel())
    # Deterministic across calls.
    assert torch.equal(rng.world_keys(seed, 4), keys)


def test_episode_keys_distinct_per_episode():
    key = rng.world_keys(17, 1).expand(500)
    eps = torch.arange(500, dtype=torch.int64)
    ek = rng.episode_keys(key, eps)
    assert torch.unique(ek).numel() == 500
    assert ek.min().item() >= 0 and ek.max().item() < 2**32


# --------------------------------------------------------------- seed keys
def test_seed_keys_one_per_seed_independent_of_the_others():
    keys = rng.seed_keys([5, 6, 2**40 + 7], purpose=1)
    assert keys.shape == (3,) and keys.dtype == torch.int64
    assert keys.min().item() >= 0 and keys.max().item() < 2**32
    for i, seed in enumerate([5, 6, 2**40 + 7]):  # a seed's key does not depend on the seeds beside it
        assert torch.equal(rng.seed_keys([seed], purpose=1)[0], keys[i])
        assert torch.equal(rng.seed_keys([9, seed, 9], purpose=1)[1], keys[i])
    assert torch.equal(rng.seed_keys([6, 5], purpose=1), keys[[1, 0]])
    assert rng.seed_keys([2**40 + 7], 1)[0] != rng.seed_keys([7], 1)[0]  # the seed's high bits matter
    assert torch.unique(rng.seed_keys(list(range(1000)), purpose=1)).numel() == 1000


def test_seed_keys_of_different_purposes_are_apart_from_each_other_and_from_the_world_streams():
    seeds = list(range(50))
    by_purpose = [rng.seed_keys(seeds, purpose) for purpose in range(4)]
    world = torch.stack([rng.world_keys(seed, 1)[0] for seed in seeds])
    everything = torch.cat(by_purpose + [world])
    assert torch.unique(everything).numel() == everything.numel()  # 250 distinct 32-bit keys
    # and their draws are uncorrelated: purpose 1 vs purpose 2 of the same seeds
    counter = torch.zeros(50, dtype=torch.int64)
    u1 = rng.uniform(by_purpose[1], counter, 0, 200, torch.float64).flatten()
    u2 = rng.uniform(by_purpose[2], counter, 0, 200, torch.float64).flatten()
    assert abs(np.corrcoef(u1.numpy(), u2.numpy())[0, 1]) < 5 / math.sqrt(u1.numel())
    assert torch.equal(rng.seed_keys(seeds, 3, device="cpu"), by_purpose[3])


def test_slot_keys_passed_in_give_the_same_bits_and_a_wrong_count_is_refused():
    key, counter = rng.world_keys(5, 3), torch.tensor([0, 7, 2**33])
    slots = rng.slot_keys(6)
    assert torch.equal(rng.random_bits(key, counter, 1, 6, slots), rng.random_bits(key, counter, 1, 6))
    normals = rng.normal(key, counter, 2, 5, torch.float64, slots)
    assert torch.equal(normals, rng.normal(key, counter, 2, 5, torch.float64))
    with pytest.raises(ValueError, match=r"slots shaped \(6,\) for 4 draws"):
        rng.random_bits(key, counter, 1, 4, slots)
