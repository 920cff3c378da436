"""Tests of aia/envs/belief.py against a straightforward per-target numpy EKF (SPEC 5)."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from aia.envs import belief
from aia.envs.dynamics import double_integrator

DT = 0.5
V_NP = np.diag([0.2**2, 0.01**2])


def _wrap(a: float) -> float:
    return (a + math.pi) % (2 * math.pi) - math.pi


# ---------------------------------------------------------------- reference EKF
def ref_predict(mu, P, A, W):
    return A @ mu, A @ P @ A.T + W


def ref_h(p, pose):
    d = p - pose[:2]
    return np.array([math.hypot(d[0], d[1]), _wrap(math.atan2(d[1], d[0]) - pose[2])])


def ref_H(p, pose):
    d1, d2 = p - pose[:2]
    r = math.hypot(d1, d2)
    return (1.0 / r) * np.array([[d1, d2, 0.0, 0.0], [-d2 / r, d1 / r, 0.0, 0.0]])


def ref_update(mu, P, z, pose, V):
    H = ref_H(mu[:2], pose)
    S = H @ P @ H.T + V
    K = P @ H.T @ np.linalg.inv(S)
    innov = z - ref_h(mu[:2], pose)
    innov[1] = _wrap(innov[1])
    I_KH = np.eye(4) - K @ H
    return mu + K @ innov, I_KH @ P @ I_KH.T + K @ V @ K.T, K, H


# ------------------------------------------------------------------- helpers
def _random_scene(rng: np.random.Generator, B: int, N: int):
    """True targets, belief means a few metres off, covariances 30 I."""
    truth = np.zeros((B, N, 4))
    truth[..., :2] = rng.uniform(10, 40, size=(B, N, 2))
    truth[..., 2:] = rng.normal(0, 0.5, size=(B, N, 2))
    mean = truth.copy()
    mean[..., :2] += rng.uniform(-3, 3, size=(B, N, 2))
    mean[..., 2:] = 0.0
    cov = np.broadcast_to(30.0 * np.eye(4), (B, N, 4, 4)).copy()
    return truth, mean, cov


def _robot_poses(rng: np.random.Generator, centres: np.ndarray) -> np.ndarray:
    """One robot pose per (world): within 1..9 m of the first target's true position, random heading."""
    B = centres.shape[0]
    dist = rng.uniform(1.0, 9.0, size=B)
    ang = rng.uniform(-math.pi, math.pi, size=B)
    poses = np.empty((B, 3))
    poses[:, 0] = centres[:, 0] + dist * np.cos(ang)
    poses[:, 1] = centres[:, 1] + dist * np.sin(ang)
    poses[:, 2] = rng.uniform(-math.pi, math.pi, size=B)
    return poses


# ---------------------------------------------------------------- comparisons
def test_predict_update_matches_numpy_reference_over_50_steps():
    rng = np.random.default_rng(0)
    B, N, steps, q = 4, 3, 50, 0.01
    A_t, W_t = double_integrator(DT, q)
    A, W = A_t.numpy(), W_t.numpy()
    V_t = torch.tensor(V_NP)
    chol_w = np.linalg.cholesky(W)

    truth, mean0, cov0 = _random_scene(rng, B, N)
    ref_mean, ref_cov = mean0.copy(), cov0.copy()
    t_mean, t_cov = torch.tensor(mean0), torch.tensor(cov0)
    wrapped_residuals = 0
    for _ in range(steps):
        truth = truth @ A.T + rng.standard_normal((B, N, 4)) @ chol_w.T
        poses = _robot_poses(rng, truth[:, 0, :2])
        z = np.empty((B, N, 2))
        for b in range(B):
            for n in range(N):
                z[b, n] = ref_h(truth[b, n, :2], poses[b]) + rng.normal(0, [0.2, 0.01])
                z[b, n, 1] = _wrap(z[b, n, 1])
        # numpy reference, target by target
        for b in range(B):
            for n in range(N):
                mu, P = ref_predict(ref_mean[b, n], ref_cov[b, n], A, W)
                zhat = ref_h(mu[:2], poses[b])
                if abs(z[b, n, 1] - zhat[1]) > math.pi:
                    wrapped_residuals += 1
                ref_mean[b, n], ref_cov[b, n], _, _ = ref_update(mu, P, z[b, n], poses[b], V_NP)
        # torch, batched over [B, N]
        t_mean, t_cov = belief.predict(t_mean, t_cov, A_t, W_t)
        t_mean, t_cov = belief.update(t_mean, t_cov, torch.tensor(z), torch.tensor(poses)[:, None, :], V_t)
        assert t_mean.shape == (B, N, 4) and t_cov.shape == (B, N, 4, 4)
        np.testing.assert_allclose(t_mean.numpy(), ref_mean, rtol=1e-9, atol=1e-9)
        scale = np.abs(ref_cov).max(axis=(-1, -2), keepdims=True)
        np.testing.assert_allclose(t_cov.numpy(), ref_cov, rtol=1e-9, atol=1e-12 * scale.max())
    # The filter actually converged (the test is not comparing two diverging things).
    assert np.abs(ref_mean[..., :2] - truth[..., :2]).max() < 2.0
    assert np.linalg.det(ref_cov).max() < 1e-3


def test_update_wraps_bearing_residual():
    """Predicted bearing just below pi, measured just above -pi: the residual is +0.02, not 0.02 - 2 pi."""
    mu = np.array([-10.0, 0.1, 0.0, 0.0])  # bearing from origin heading 0: pi - 0.01
    P = 4.0 * np.eye(4)
    pose = np.array([0.0, 0.0, 0.0])
    zhat = ref_h(mu[:2], pose)
    assert zhat[1] == pytest.approx(math.pi - 0.01, abs=1e-5)
    z = np.array([zhat[0], _wrap(zhat[1] + 0.02)])
    assert z[1] < -math.pi + 0.02
    ref_mu, ref_P, _, _ = ref_update(mu, P, z, pose, V_NP)
    t_mu, t_P = belief.update(torch.tensor(mu), torch.tensor(P), torch.tensor(z), torch.tensor(pose),
                              torch.tensor(V_NP))
    np.testing.assert_allclose(t_mu.numpy(), ref_mu, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(t_P.numpy(), ref_P, rtol=1e-9, atol=1e-12)
    # A 0.02 rad bearing correction at 10 m moves the mean by at most ~0.2 m (unwrapped it would be ~60 m).
    assert np.abs(t_mu.numpy()[:2] - mu[:2]).max() < 0.25


def test_joseph_form_matches_standard_form_float64():
    rng = np.random.default_rng(1)
    B = 64
    M = rng.normal(size=(B, 4, 4))
    cov = M @ np.swapaxes(M, -1, -2) + 0.5 * np.eye(4)
    pos = rng.uniform(-10, 10, size=(B, 2))
    pose = np.concatenate([rng.uniform(-10, 10, size=(B, 2)), rng.uniform(-math.pi, math.pi, size=(B, 1))],
                          -1)
    cov_t = torch.tensor(cov)
    H = belief.measurement_jacobian(torch.tensor(pos), torch.tensor(pose))
    joseph, K = belief.update_cov(cov_t, H, torch.tensor(V_NP))
    standard = (torch.eye(4, dtype=torch.float64) - K @ H) @ cov_t
    rel = (joseph - standard).abs().amax((-1, -2)) / cov_t.abs().amax((-1, -2))
    assert rel.max().item() < 1e-9
    # And the gain is the textbook one.
    for b in range(B):
        Hb = ref_H(pos[b], pose[b])
        Kb = cov[b] @ Hb.T @ np.linalg.inv(Hb @ cov[b] @ Hb.T + V_NP)
        np.testing.assert_allclose(K[b].numpy(), Kb, rtol=1e-9, atol=1e-13)
    # The update reduces uncertainty.
    assert (torch.linalg.det(joseph) < torch.linalg.det(cov_t)).all()


def test_predict_matches_formula():
    rng = np.random.default_rng(2)
    A_t, W_t = double_integrator(DT, 0.001)
    mean = rng.normal(size=(3, 2, 4))
    M = rng.normal(size=(3, 2, 4, 4))
    cov = M @ np.swapaxes(M, -1, -2)
    m, c = belief.predict(torch.tensor(mean), torch.tensor(cov), A_t, W_t)
    A, W = A_t.numpy(), W_t.numpy()
    np.testing.assert_allclose(m.numpy(), mean @ A.T, rtol=1e-12, atol=1e-14)
    np.testing.assert_allclose(c.numpy(), A @ cov @ A.T + W, rtol=1e-12, atol=1e-14)
    # Hand value: position advances by dt * velocity.
    m1, _ = belief.predict(torch.tensor([1.0, 2.0, 3.0, -4.0], dtype=torch.float64),
                           torch.eye(4, dtype=torch.float64), A_t, W_t)
    np.testing.assert_allclose(m1.numpy(), [2.5, 0.0, 3.0, -4.0], atol=1e-15)


# ------------------------------------------------------------- measurement model
def test_range_bearing_hand_values():
    p = torch.tensor([3.0, 4.0], dtype=torch.float64)
    out = belief.range_bearing(p, torch.tensor([0.0, 0.0, 0.0], dtype=torch.float64))
    np.testing.assert_allclose(out.numpy(), [5.0, math.atan2(4, 3)], atol=1e-15)
    out = belief.range_bearing(p, torch.tensor([0.0, 0.0, math.pi / 2], dtype=torch.float64))
    np.testing.assert_allclose(out.numpy(), [5.0, math.atan2(4, 3) - math.pi / 2], atol=1e-15)
    assert out[1].item() == pytest.approx(-math.atan2(3, 4), abs=1e-15)
    # Robot offset and a bearing that needs wrapping: 3 pi / 4 - (-pi / 2) = 5 pi / 4 -> -3 pi / 4.
    out = belief.range_bearing(torch.tensor([0.0, 3.0], dtype=torch.float64),
                               torch.tensor([1.0, 2.0, -math.pi / 2], dtype=torch.float64))
    np.testing.assert_allclose(out.numpy(), [math.sqrt(2), -0.75 * math.pi], atol=1e-14)


def test_range_bearing_broadcasts_points_per_pose():
    poses = torch.tensor([[0.0, 0.0, 0.0], [1.0, 1.0, math.pi]], dtype=torch.float64)
    points = torch.tensor([[[1.0, 0.0], [0.0, 2.0]], [[1.0, 3.0], [4.0, 1.0]]], dtype=torch.float64)
    out = belief.range_bearing(points, poses[:, None, :])
    expected = [[[1.0, 0.0], [2.0, math.pi / 2]], [[2.0, -math.pi / 2], [3.0, -math.pi]]]
    np.testing.assert_allclose(out.numpy(), expected, atol=1e-14)


def test_measurement_jacobian_finite_difference():
    rng = np.random.default_rng(3)
    B = 50
    state = torch.tensor(np.concatenate([rng.uniform(-20, 20, size=(B, 2)), rng.normal(size=(B, 2))], -1))
    pose = torch.tensor(np.concatenate([rng.uniform(-20, 20, size=(B, 2)), rng.uniform(-3, 3, size=(B, 1))],
                                       -1))
    H = belief.measurement_jacobian(state[:, :2], pose)
    assert H.shape == (B, 2, 4)
    eps = 1e-6
    fd = torch.zeros(B, 2, 4, dtype=torch.float64)
    for j in range(4):
        step = torch.zeros(4, dtype=torch.float64)
        step[j] = eps
        hp = belief.range_bearing((state + step)[:, :2], pose)
        hm = belief.range_bearing((state - step)[:, :2], pose)
        diff = hp - hm
        diff[:, 1] = torch.remainder(diff[:, 1] + math.pi, 2 * math.pi) - math.pi
        fd[:, :, j] = diff / (2 * eps)
    np.testing.assert_allclose(H.numpy(), fd.numpy(), rtol=1e-6, atol=1e-8)
    assert (H[..., 2:] == 0).all()
    # Hand value: target (3, 4) from the origin: H = [[0.6, 0.8, 0, 0], [-4/25, 3/25, 0, 0]].
    H1 = belief.measurement_jacobian(torch.tensor([3.0, 4.0], dtype=torch.float64),
                                     torch.tensor([0.0, 0.0, 1.0], dtype=torch.float64))
    np.testing.assert_allclose(H1.numpy(), [[0.6, 0.8, 0, 0], [-0.16, 0.12, 0, 0]], atol=1e-15)


def test_logdet_matches_slogdet():
    rng = np.random.default_rng(4)
    M = rng.normal(size=(5, 3, 4, 4))
    cov = M @ np.swapaxes(M, -1, -2) + 1e-3 * np.eye(4)
    sign, ref = np.linalg.slogdet(cov)
    assert (sign > 0).all()
    np.testing.assert_allclose(belief.logdet(torch.tensor(cov)).numpy(), ref, rtol=1e-10, atol=1e-10)
    got = belief.logdet(30.0 * torch.eye(4, dtype=torch.float64)).item()
    assert got == pytest.approx(4 * math.log(30.0), abs=1e-12)
    # float32 path
    got32 = belief.logdet(torch.tensor(cov, dtype=torch.float32)).numpy()
    np.testing.assert_allclose(got32, ref, rtol=0, atol=5e-3)


# --------------------------------------------------------------- long rollout
@pytest.fixture
def single_thread():
    """Tiny batched matmuls are dominated by thread start-up on a busy machine: run them on one thread."""
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(threads)


def test_covariance_stays_spd_over_long_float32_rollout(single_thread):
    """2000 steps of float32 predict/update from random poses: Sigma stays symmetric positive definite."""
    torch.manual_seed(5)
    gen = torch.Generator().manual_seed(5)
    B, N, steps = 32, 3, 2000
    dtype = torch.float32
    A, W = (m.to(dtype) for m in double_integrator(DT, 0.001))
    V = torch.tensor(V_NP, dtype=dtype)
    chol_w = torch.linalg.cholesky(W.double()).to(dtype)
    truth = torch.zeros(B, N, 4, dtype=dtype)
    truth[..., :2] = torch.rand(B, N, 2, generator=gen) * 30 + 10
    mean = truth.clone()
    mean[..., :2] += torch.rand(B, N, 2, generator=gen) * 6 - 3
    mean[..., 2:] = 0
    cov = (30.0 * torch.eye(4, dtype=dtype)).expand(B, N, 4, 4).clone()
    min_eig = math.inf
    max_asym = 0.0
    updates = 0
    for t in range(steps):
        truth = truth @ A.mT + torch.randn(B, N, 4, generator=gen) @ chol_w.mT
        truth[..., 2:] = truth[..., 2:].clamp(-2, 2)
        # Robot 0.5 .. 10 m from a random target, random heading.
        which = torch.randint(0, N, (B,), generator=gen)
        centre = truth[torch.arange(B), which, :2]
        dist = 0.5 + 9.5 * torch.rand(B, generator=gen)
        ang = (torch.rand(B, generator=gen) * 2 - 1) * math.pi
        pose = torch.stack((centre[:, 0] + dist * torch.cos(ang), centre[:, 1] + dist * torch.sin(ang),
                            (torch.rand(B, generator=gen) * 2 - 1) * math.pi), -1)
        mean, cov = belief.predict(mean, cov, A, W)
        z = belief.range_bearing(truth[..., :2], pose[:, None, :])
        z = z + torch.randn(B, N, 2, generator=gen) * torch.tensor([0.2, 0.01])
        observed = torch.rand(B, N, generator=gen) < 0.7
        m_post, c_post = belief.update(mean, cov, z, pose[:, None, :], V)
        mean = torch.where(observed[..., None], m_post, mean)
        cov = torch.where(observed[..., None, None], c_post, cov)
        updates += int(observed.sum())
        if t % 50 == 49 or t == steps - 1:
            c64 = cov.double()
            min_eig = min(min_eig, torch.linalg.eigvalsh(c64).min().item())
            asym = ((c64 - c64.mT).abs().amax((-1, -2)) / c64.abs().amax((-1, -2))).max().item()
            max_asym = max(max_asym, asym)
            assert torch.isfinite(cov).all() and torch.isfinite(mean).all()
    assert min_eig > 0, min_eig
    assert max_asym < 1e-6, max_asym
    assert torch.isfinite(belief.logdet(cov)).all()
    assert updates > 0.6 * B * N * steps
    # The filter tracks: beliefs are within a few metres of the truth and log det is small.
    assert (mean[..., :2] - truth[..., :2]).abs().max().item() < 3.0
    assert belief.logdet(cov).max().item() < 0.0


def test_cap_det_keeps_the_prior_where_the_prediction_reaches_the_cap():
    prior = torch.stack((torch.eye(4), 10 * torch.eye(4))).double()
    predicted = 2 * prior  # log det: 4 log 2 = 2.77 and 4 log 20 = 11.98
    capped = belief.cap_det(prior, predicted, log_det_cap=math.log(1e5))  # 11.51
    assert torch.equal(capped[0], predicted[0]) and torch.equal(capped[1], prior[1])
    assert torch.equal(belief.cap_det(prior, predicted, math.inf), predicted)
