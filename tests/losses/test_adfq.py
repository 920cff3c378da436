"""Tests of the closed-form ADFQ posterior against analytic cases and a slow loop implementation."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from aia.losses import adfq_posterior
from aia.losses.adfq import adfq_posterior as adfq_posterior_direct

GAMMA = 0.99
A = 12


def gaussian_product(m1: float, v1: float, m2: float, v2: float) -> tuple[float, float]:
    v = 1.0 / (1.0 / v1 + 1.0 / v2)
    return v * (m1 / v1 + m2 / v2), v


def slow_posterior(next_mean, next_var, mean, var, reward, gamma, done, noise=0.0, var_min=1e-20, reward_var=1e-3):
    """One row at a time, one candidate at a time, one scan step at a time (float64 Python and numpy)."""
    next_mean = np.asarray(next_mean, dtype=np.float64)
    next_var = np.asarray(next_var, dtype=np.float64)
    out_mean = np.zeros(len(mean))
    out_var = np.zeros(len(mean))
    for row in range(len(mean)):
        c_mean, c_var, r = float(mean[row]), float(var[row]), float(reward[row])
        if done[row]:
            m, v = gaussian_product(c_mean, c_var, r, reward_var + noise)
            out_mean[row], out_var[row] = m, max(v, var_min)
            continue
        n = next_mean.shape[-1]
        t_mean = [r + gamma * float(next_mean[row, b]) for b in range(n)]
        t_var = [gamma * gamma * float(next_var[row, b]) for b in range(n)]
        # Decreasing target mean; tied actions by decreasing index (a stable ascending sort, flipped).
        order = sorted(range(n), key=lambda b: (t_mean[b], b), reverse=True)
        cands = []
        for b in range(n):
            bar_var = 1.0 / (1.0 / c_var + 1.0 / (t_var[b] + noise))
            bar_mean = bar_var * (c_mean / c_var + t_mean[b] / (t_var[b] + noise))
            add_var = c_var + t_var[b] + noise
            others = [c for c in order if c != b]
            best = None
            for i in range(n):
                act_m = np.array([t_mean[c] for c in others[:i]])
                act_v = np.array([t_var[c] for c in others[:i]])
                # np.sum rounds like the reference's sums (the accept test can hinge on the last bit).
                x = (np.sum(act_m / act_v) + bar_mean / bar_var) / (1.0 / bar_var + np.sum(1.0 / act_v))
                lower = t_mean[others[i]] if i < n - 1 else -1e20
                upper = t_mean[others[i - 1]] if i > 0 else 1e20
                violation = max(lower - x, 0.0) + max(x - upper, 0.0)
                if best is None or violation < best[0]:
                    best = (violation, i, x)
                if violation == 0.0:
                    break
            _, i, x = best
            act_m = [t_mean[c] for c in others[:i]]
            act_v = [t_var[c] for c in others[:i]]
            var_star = 1.0 / (1.0 / bar_var + sum(1.0 / v for v in act_v))
            pull = sum((tm - x) ** 2 / tv for tm, tv in zip(act_m, act_v, strict=True))
            log_k = 0.5 * (math.log(var_star) - math.log(bar_var) - math.log(2 * math.pi) - math.log(add_var)) - 0.5 * (
                (t_mean[b] - c_mean) ** 2 / add_var + (x - bar_mean) ** 2 / bar_var + pull
            )
            cands.append((x, var_star, log_k))
        top = max(c[2] for c in cands)
        w = [math.exp(c[2] - top) for c in cands]
        z = sum(w)
        w = [wi / z for wi in w]
        m = sum(wi * c[0] for wi, c in zip(w, cands, strict=True))
        v = sum(wi * (c[1] + (c[0] - m) ** 2) for wi, c in zip(w, cands, strict=True))
        out_mean[row], out_var[row] = m, max(v, var_min)
    return out_mean, out_var


def make_batch(rng: np.random.Generator, n: int, kind: str):
    def log_sd(size):
        return 10.0 ** rng.uniform(-5.0, 5.0, size)

    if kind == "tie":  # all next actions identical
        next_mean = np.repeat(rng.uniform(-1e3, 1e3, (n, 1)), A, 1)
        next_var = np.repeat(log_sd((n, 1)) ** 2, A, 1)
    elif kind == "near":  # differences of 1e-9
        next_mean = rng.uniform(-1e3, 1e3, (n, 1)) + 1e-9 * rng.integers(-3, 4, (n, A))
        next_var = np.repeat(log_sd((n, 1)) ** 2, A, 1) * (1.0 + 1e-9 * rng.integers(-3, 4, (n, A)))
    elif kind == "init":  # network initialisation: means near 1, sds near 10, exact ties
        next_mean = np.ones((n, A))
        next_var = np.full((n, A), 100.0)
    else:
        next_mean = rng.uniform(-1e3, 1e3, (n, A))
        next_var = log_sd((n, A)) ** 2
    mean = rng.normal(1.0, 1.0, n) if kind == "init" else rng.uniform(-1e3, 1e3, n)
    var = log_sd(n) ** 2
    reward = rng.normal(0.0, 10.0, n)
    done = rng.random(n) < 0.2
    return next_mean, next_var, mean, var, reward, done


def run(next_mean, next_var, mean, var, reward, done, **kw):
    t = torch.as_tensor
    m, v = adfq_posterior(t(next_mean), t(next_var), t(mean), t(var), t(reward), GAMMA, t(done), **kw)
    return m.numpy(), v.numpy()


def test_export():
    assert adfq_posterior is adfq_posterior_direct


@pytest.mark.parametrize("noise", [0.0, 1.0])
def test_single_next_action_is_gaussian_product(noise):
    rng = np.random.default_rng(1)
    nm, nv = rng.normal(0, 5, (50, 1)), rng.uniform(0.1, 10, (50, 1))
    mu, var, r = rng.normal(0, 5, 50), rng.uniform(0.1, 10, 50), rng.normal(0, 1, 50)
    m, v = run(nm, nv, mu, var, r, np.zeros(50, bool), noise=noise)
    em, ev = gaussian_product(mu, var, r + GAMMA * nm[:, 0], GAMMA**2 * nv[:, 0] + noise)
    np.testing.assert_allclose(m, em, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(v, ev, rtol=1e-12)


@pytest.mark.parametrize("noise", [0.0, 1.0])
def test_terminal_is_reward_update(noise):
    rng = np.random.default_rng(2)
    nm, nv = rng.normal(0, 5, (40, A)), rng.uniform(0.1, 10, (40, A))
    mu, var, r = rng.normal(0, 5, 40), rng.uniform(1e-3, 10, 40), rng.normal(0, 1, 40)
    m, v = run(nm, nv, mu, var, r, np.ones(40, bool), noise=noise, reward_var=1e-3)
    em, ev = gaussian_product(mu, var, r, 1e-3 + noise)
    np.testing.assert_allclose(m, em, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(v, ev, rtol=1e-12)
    # A hand-worked row: N(2, 1) x N(1, 1e-3) with noise 0.
    m, v = run(np.zeros((1, A)), np.ones((1, A)), [2.0], [1.0], [1.0], [True])
    assert v[0] == pytest.approx(1.0 / 1001.0, rel=1e-12)
    assert m[0] == pytest.approx((2.0 + 1000.0) / 1001.0, rel=1e-12)


@pytest.mark.parametrize("noise", [0.0, 1.0])
def test_dominant_next_action_is_td_update(noise):
    # Action 5 far above the others with a tiny variance: the posterior is the precision-weighted TD update.
    nm = np.full((3, A), -500.0)
    nm[:, 5] = [10.0, 20.0, -3.0]
    nv = np.full((3, A), 1.0)
    nv[:, 5] = 1e-8
    mu, var, r = np.array([12.0, 0.0, -1.0]), np.array([4.0, 0.5, 100.0]), np.array([0.5, 1.0, -2.0])
    m, v = run(nm, nv, mu, var, r, np.zeros(3, bool), noise=noise)
    em, ev = gaussian_product(mu, var, r + GAMMA * nm[:, 5], GAMMA**2 * 1e-8 + noise)
    np.testing.assert_allclose(m, em, rtol=1e-9)
    np.testing.assert_allclose(v, ev, rtol=1e-9)
    if noise == 0.0:  # the hand-worked first row: the target 10.4 with variance ~1e-8 wins
        assert m[0] == pytest.approx(10.4, abs=1e-7)
        assert v[0] == pytest.approx(GAMMA**2 * 1e-8, rel=1e-6)


def test_exact_ties_above_or_below_belief():
    # 12 identical next actions: the current mean above the target gives the plain product (no active
    # other action); below, all 11 others are active for every candidate.
    nm, nv = np.ones((2, A)), np.full((2, A), 100.0)
    mu, var, r = np.array([5.0, -5.0]), np.array([4.0, 4.0]), np.zeros(2)
    m, v = run(nm, nv, mu, var, r, np.zeros(2, bool))
    tm, tv = GAMMA, GAMMA**2 * 100.0
    em, ev = gaussian_product(5.0, 4.0, tm, tv)
    assert m[0] == pytest.approx(em, rel=1e-12) and v[0] == pytest.approx(ev, rel=1e-12)
    bm, bv = gaussian_product(-5.0, 4.0, tm, tv)
    ev = 1.0 / (1.0 / bv + (A - 1) / tv)
    assert m[1] == pytest.approx(ev * (bm / bv + (A - 1) * tm / tv), rel=1e-12)
    assert v[1] == pytest.approx(ev, rel=1e-12)


@pytest.mark.parametrize("kind", ["random", "tie", "near", "init"])
@pytest.mark.parametrize("noise", [0.0, 1.0])
def test_matches_slow_reference(kind, noise):
    rng = np.random.default_rng(["random", "tie", "near", "init"].index(kind) * 2 + int(noise) + 10)
    batch = make_batch(rng, 200, kind)
    m, v = run(*batch, noise=noise)
    em, ev = slow_posterior(*batch[:5], GAMMA, batch[5], noise=noise)
    assert np.isfinite(m).all() and np.isfinite(v).all() and (v > 0).all()
    mean_err = np.abs(m - em) / np.maximum(np.abs(em), 1e-12)
    var_err = np.abs(v - ev) / (1e-6 * ev + 1e-12 * (1.0 + em**2))
    assert mean_err.max() < 1e-6
    assert var_err.max() < 1.0
    # Same formulas and summation order: in fact agreement is at rounding level.
    assert mean_err.max() < 1e-12
    np.testing.assert_allclose(v, ev, rtol=1e-9)


def test_float32_in_float32_out():
    rng = np.random.default_rng(3)
    batch = make_batch(rng, 100, "random")
    t32 = [torch.as_tensor(a, dtype=torch.float32) for a in batch[:5]]
    m32, v32 = adfq_posterior(*t32, GAMMA, torch.as_tensor(batch[5]))
    assert m32.dtype == torch.float32 and v32.dtype == torch.float32
    # The float32-rounded inputs, computed in float64: the float32 output is that result rounded.
    m64, v64 = adfq_posterior(*[a.double() for a in t32], GAMMA, torch.as_tensor(batch[5]))
    assert torch.equal(m32, m64.float()) and torch.equal(v32, v64.float())


def test_extreme_ranges_finite_with_finite_gradients():
    gen = torch.Generator().manual_seed(4)
    n = 2000
    next_mean = (torch.rand(n, A, generator=gen, dtype=torch.float64) * 2e3 - 1e3).requires_grad_()
    next_var = (10 ** (torch.rand(n, A, generator=gen, dtype=torch.float64) * 10 - 5)) ** 2
    next_var.requires_grad_()
    mean = (torch.rand(n, generator=gen, dtype=torch.float64) * 2e3 - 1e3).requires_grad_()
    var = ((10 ** (torch.rand(n, generator=gen, dtype=torch.float64) * 10 - 5)) ** 2).requires_grad_()
    reward = torch.randn(n, generator=gen, dtype=torch.float64)
    done = torch.rand(n, generator=gen) < 0.2
    for noise in (0.0, 1.0):
        m, v = adfq_posterior(next_mean, next_var, mean, var, reward, GAMMA, done, noise=noise)
        assert torch.isfinite(m).all() and torch.isfinite(v).all() and (v > 0).all()
        grads = torch.autograd.grad(m.sum() + v.sum(), (next_mean, next_var, mean, var))
        assert all(torch.isfinite(g).all() for g in grads)
    for dtype in (torch.float32,):
        m, v = adfq_posterior(*(x.detach().to(dtype) for x in (next_mean, next_var, mean, var, reward)), GAMMA, done)
        assert torch.isfinite(m).all() and torch.isfinite(v).all() and (v > 0).all()


def test_var_floor():
    m, v = run(np.zeros((2, A)), np.full((2, A), 1e-30), [0.0, 0.0], [1e-30, 1e-30], [0.0, 0.0], [False, True])
    assert (v == 1e-20).all()
    m, v = run(np.zeros((1, A)), np.ones((1, A)), [0.0], [1e-12], [0.0], [False], var_min=1e-10)
    assert v[0] == 1e-10


def test_two_leading_batch_dims():
    rng = np.random.default_rng(5)
    nm, nv, mu, var, r, done = make_batch(rng, 24, "random")
    t = torch.as_tensor
    m, v = adfq_posterior(t(nm), t(nv), t(mu), t(var), t(r), GAMMA, t(done), noise=1.0)
    m2, v2 = adfq_posterior(
        t(nm).reshape(4, 6, A),
        t(nv).reshape(4, 6, A),
        t(mu).reshape(4, 6),
        t(var).reshape(4, 6),
        t(r).reshape(4, 6),
        GAMMA,
        t(done).reshape(4, 6),
        noise=1.0,
    )
    assert m2.shape == (4, 6) and v2.shape == (4, 6)
    torch.testing.assert_close(m2.reshape(-1), m, rtol=0, atol=0)
    torch.testing.assert_close(v2.reshape(-1), v, rtol=0, atol=0)
