"""Tests of aia/envs/dynamics.py: SE(2) unicycle step, motion primitives, double integrator, wrap_angle."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from aia.envs.dynamics import double_integrator, motion_primitives, se2_step, wrap_angle

SPEEDS = (3.0, 2.0, 1.0, 0.0)
TURNS = (math.pi / 2, 0.0, -math.pi / 2)


# ------------------------------------------------------------------ se2_step
def test_se2_step_straight_line():
    pose = torch.tensor([1.0, 2.0, 0.0], dtype=torch.float64)
    out = se2_step(pose, torch.tensor([3.0, 0.0], dtype=torch.float64), 0.5)
    torch.testing.assert_close(out, torch.tensor([2.5, 2.0, 0.0], dtype=torch.float64), rtol=0, atol=1e-12)


def test_se2_step_straight_line_with_heading():
    # v = 2, heading 3*pi/4 for 0.5 s: one metre along (-1, 1)/sqrt(2).
    pose = torch.tensor([0.0, 0.0, 0.75 * math.pi], dtype=torch.float64)
    out = se2_step(pose, torch.tensor([2.0, 0.0], dtype=torch.float64), 0.5)
    s = 1.0 / math.sqrt(2.0)
    expected = torch.tensor([-s, s, 0.75 * math.pi], dtype=torch.float64)
    torch.testing.assert_close(out, expected, rtol=0, atol=1e-12)


@pytest.mark.parametrize("theta", [0.0, 0.3, -1.2, 2.9, -3.0])
@pytest.mark.parametrize("w", [math.pi / 2, -math.pi / 2, 1.0])
def test_se2_step_arc_closed_form(theta, w):
    v, dt = 2.0, 0.5
    x, y = 4.0, -1.5
    pose = torch.tensor([x, y, theta], dtype=torch.float64)
    out = se2_step(pose, torch.tensor([v, w], dtype=torch.float64), dt)
    ex = x + v / w * (math.sin(theta + w * dt) - math.sin(theta))
    ey = y + v / w * (math.cos(theta) - math.cos(theta + w * dt))
    eth = math.remainder(theta + w * dt, 2 * math.pi)
    if eth >= math.pi:
        eth -= 2 * math.pi
    assert out[0].item() == pytest.approx(ex, abs=1e-12)
    assert out[1].item() == pytest.approx(ey, abs=1e-12)
    assert out[2].item() == pytest.approx(eth, abs=1e-12)


def test_se2_step_quarter_turn_arc_hand_value():
    # v = 2, w = pi/2 for 0.5 s from the origin heading 0: radius 4/pi, turned pi/4.
    out = se2_step(torch.tensor([0.0, 0.0, 0.0], dtype=torch.float64),
                   torch.tensor([2.0, math.pi / 2], dtype=torch.float64), 0.5)
    radius = 4.0 / math.pi
    expected = [radius * math.sin(math.pi / 4), radius * (1 - math.cos(math.pi / 4)), math.pi / 4]
    np.testing.assert_allclose(out.numpy(), expected, rtol=0, atol=1e-12)
    # Arc length 1 m is longer than the chord.
    chord = 2 * radius * math.sin(math.pi / 8)
    assert math.hypot(out[0].item(), out[1].item()) == pytest.approx(chord, abs=1e-12)


def test_se2_step_pure_rotation_keeps_position():
    pose = torch.tensor([7.0, -3.0, 1.0], dtype=torch.float64)
    out = se2_step(pose, torch.tensor([0.0, -math.pi / 2], dtype=torch.float64), 0.5)
    np.testing.assert_allclose(out.numpy(), [7.0, -3.0, 1.0 - math.pi / 4], rtol=0, atol=1e-12)


def test_se2_step_heading_wraps():
    # 3.0 + pi/4 = 3.785... > pi  -> 3.785 - 2 pi
    out = se2_step(torch.tensor([0.0, 0.0, 3.0], dtype=torch.float64),
                   torch.tensor([1.0, math.pi / 2], dtype=torch.float64), 0.5)
    assert out[2].item() == pytest.approx(3.0 + math.pi / 4 - 2 * math.pi, abs=1e-12)
    out = se2_step(torch.tensor([0.0, 0.0, -3.0], dtype=torch.float64),
                   torch.tensor([1.0, -math.pi / 2], dtype=torch.float64), 0.5)
    assert out[2].item() == pytest.approx(-3.0 - math.pi / 4 + 2 * math.pi, abs=1e-12)


def test_se2_step_batched_matches_single_calls():
    gen = torch.Generator().manual_seed(0)
    poses = torch.rand(5, 7, 3, generator=gen, dtype=torch.float64) * torch.tensor([10, 10, 2 * math.pi],
                                                                                     dtype=torch.float64)
    poses[..., 2] -= math.pi
    table = motion_primitives(SPEEDS, TURNS, dtype=torch.float64)
    actions = torch.randint(0, 12, (5, 7), generator=gen)
    out = se2_step(poses, table[actions], 0.5)
    assert out.shape == (5, 7, 3)
    for i in range(5):
        for j in range(7):
            torch.testing.assert_close(out[i, j], se2_step(poses[i, j], table[actions[i, j]], 0.5))
    assert ((out[..., 2] >= -math.pi) & (out[..., 2] < math.pi)).all()


def test_se2_step_float32_small_turn_no_nan():
    # sinc near w = 0 must be finite and close to the straight-line step.
    out = se2_step(torch.tensor([0.0, 0.0, 0.0]), torch.tensor([3.0, 1e-8]), 0.5)
    assert torch.isfinite(out).all()
    assert out[0].item() == pytest.approx(1.5, abs=1e-6)
    assert abs(out[1].item()) < 1e-6


# ----------------------------------------------------------- motion_primitives
def test_motion_primitives_order():
    table = motion_primitives(SPEEDS, TURNS, dtype=torch.float64)
    assert table.shape == (12, 2)
    for i_v, v in enumerate(SPEEDS):
        for i_w, w in enumerate(TURNS):
            a = 3 * i_v + i_w
            assert table[a, 0].item() == v
            assert table[a, 1].item() == w
    assert table[5].tolist() == [2.0, -math.pi / 2]
    assert table[10].tolist() == [0.0, 0.0]
    assert table[0].tolist() == [3.0, math.pi / 2]
    assert table[11].tolist() == [0.0, -math.pi / 2]


def test_motion_primitives_dtype_and_other_sizes():
    table = motion_primitives((1.0, 0.5), (0.1, 0.0, -0.1, 0.2))
    assert table.dtype == torch.float32
    assert table.shape == (8, 2)
    # a = len(w) * i_v + i_w
    assert table[6].tolist() == pytest.approx([0.5, -0.1])


# ----------------------------------------------------------- double integrator
@pytest.mark.parametrize("dt,q", [(0.5, 0.01), (0.5, 0.001), (0.1, 2.0)])
def test_double_integrator_matrices(dt, q):
    A, W = double_integrator(dt, q)
    assert A.dtype == torch.float64 and W.dtype == torch.float64
    eA = np.array([[1, 0, dt, 0], [0, 1, 0, dt], [0, 0, 1, 0], [0, 0, 0, 1]], dtype=np.float64)
    a, b, c = dt**3 / 3, dt**2 / 2, dt
    eW = q * np.array([[a, 0, b, 0], [0, a, 0, b], [b, 0, c, 0], [0, b, 0, c]], dtype=np.float64)
    np.testing.assert_allclose(A.numpy(), eA, rtol=0, atol=1e-15)
    np.testing.assert_allclose(W.numpy(), eW, rtol=1e-14, atol=0)
    # W is symmetric positive definite: det of each 2x2 block q^2 (dt^4/3 - dt^4/4) > 0.
    assert torch.linalg.eigvalsh(W).min().item() > 0


def test_double_integrator_values_default_setting():
    _, W = double_integrator(0.5, 0.01)
    assert W[0, 0].item() == pytest.approx(0.01 * 0.125 / 3, rel=1e-14)
    assert W[0, 2].item() == pytest.approx(0.01 * 0.125, rel=1e-14)
    assert W[3, 3].item() == pytest.approx(0.005, rel=1e-14)
    assert W[0, 1].item() == 0.0 and W[0, 3].item() == 0.0


def test_double_integrator_monte_carlo():
    dt, q, n = 0.5, 0.01, 200_000
    A, W = double_integrator(dt, q)
    gen = torch.Generator().manual_seed(1234)
    y = torch.tensor([3.0, -2.0, 0.7, -1.1], dtype=torch.float64)
    noise = torch.randn(n, 4, generator=gen, dtype=torch.float64)
    nxt = y @ A.mT + noise @ torch.linalg.cholesky(W).mT
    mean = nxt.mean(0)
    expected_mean = A @ y
    np.testing.assert_allclose(expected_mean.numpy(), [3.35, -2.55, 0.7, -1.1], atol=1e-12)
    std_mean = torch.sqrt(torch.diagonal(W) / n)
    assert ((mean - expected_mean).abs() < 5 * std_mean).all(), (mean - expected_mean) / std_mean

    centred = nxt - mean
    cov = centred.T @ centred / (n - 1)
    # Var of a sample covariance entry for Gaussians: (W_ii W_jj + W_ij^2) / n.
    d = torch.diagonal(W)
    std_cov = torch.sqrt((d[:, None] * d[None, :] + W * W) / n)
    assert ((cov - W).abs() < 5 * std_cov).all(), (cov - W) / std_cov
    # And the correlation between position and velocity of the same axis: (dt^2/2) / sqrt(dt^4/3) = sqrt(3)/2.
    corr = cov[0, 2] / torch.sqrt(cov[0, 0] * cov[2, 2])
    assert corr.item() == pytest.approx(math.sqrt(3) / 2, abs=5e-3)


# ----------------------------------------------------------------- wrap_angle
def test_wrap_angle_values():
    x = torch.tensor([0.0, math.pi, -math.pi, 3 * math.pi, -3 * math.pi, 2 * math.pi, 1.0, 7.0, -7.0, 100.0],
                     dtype=torch.float64)
    out = wrap_angle(x)
    expected = [0.0, -math.pi, -math.pi, -math.pi, -math.pi, 0.0, 1.0, 7.0 - 2 * math.pi, -7.0 + 2 * math.pi,
                100.0 - 32 * math.pi]
    np.testing.assert_allclose(out.numpy(), expected, rtol=0, atol=1e-12)


def test_wrap_angle_range_and_equivalence():
    gen = torch.Generator().manual_seed(3)
    x = (torch.rand(100_000, generator=gen, dtype=torch.float64) - 0.5) * 200
    out = wrap_angle(x)
    assert ((out >= -math.pi) & (out < math.pi)).all()
    k = (x - out) / (2 * math.pi)
    assert (k - k.round()).abs().max().item() < 1e-9
    # Idempotent.
    torch.testing.assert_close(wrap_angle(out), out, rtol=0, atol=1e-12)


def test_wrap_angle_float32_in_range():
    x = torch.linspace(-50, 50, 100_001, dtype=torch.float32)
    out = wrap_angle(x)
    assert ((out >= -math.pi) & (out <= math.pi)).all()
    assert torch.allclose(torch.sin(out), torch.sin(x), atol=1e-4)
    assert torch.allclose(torch.cos(out), torch.cos(x), atol=1e-4)
