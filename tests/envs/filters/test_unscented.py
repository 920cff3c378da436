"""The batched UKF against filterpy's UnscentedKalmanFilter with the same (Julier) sigma points."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from filterpy.kalman import JulierSigmaPoints
from filterpy.kalman import UnscentedKalmanFilter as ReferenceUKF

from aia.envs.belief_models import belief_model
from aia.envs.filters import UnscentedKalmanFilter
from aia.envs.filters.unscented import sigma_points, sigma_weights

DT, KAPPA = 0.5, 1.0
MEAS_NOISE = np.diag([0.2**2, 0.01**2])


def _wrap(a):
    return (a + math.pi) % (2 * math.pi) - math.pi


def _unicycle(x, dt, v, w):
    """Exact unicycle integration (our own reference, numpy)."""
    half = 0.5 * dt * w
    chord = v * dt * np.sinc(half / math.pi)
    return np.array([x[0] + chord * math.cos(x[2] + half), x[1] + chord * math.sin(x[2] + half), _wrap(x[2] + dt * w)])


def _reference(dim: int, q_noise: np.ndarray) -> ReferenceUKF:
    def fx(x, dt):
        if dim == 3:
            return x.copy()  # the se2 model with the zero control
        return np.concatenate((_unicycle(x[:3], dt, x[3], x[4]), x[3:]))

    def hx(x, pose):
        delta = x[:2] - pose[:2]
        return np.array([math.hypot(*delta), _wrap(math.atan2(delta[1], delta[0]) - pose[2])])

    def circular_mean(index):
        def mean(points, weights):
            out = weights @ points
            out[index] = math.atan2(weights @ np.sin(points[:, index]), weights @ np.cos(points[:, index]))
            return out
        return mean

    def residual(index):
        def diff(a, b):
            out = a - b
            out[index] = _wrap(out[index])
            return out
        return diff

    ukf = ReferenceUKF(dim, 2, DT, hx=hx, fx=fx, points=JulierSigmaPoints(dim, kappa=KAPPA),
                       x_mean_fn=circular_mean(2), z_mean_fn=circular_mean(1), residual_x=residual(2),
                       residual_z=residual(1))
    ukf.Q = q_noise
    return ukf


def test_sigma_points_and_weights_are_julier_s():
    mean = torch.tensor([1.0, -2.0, 0.3], dtype=torch.float64)
    cov = torch.tensor([[2.0, 0.3, 0.1], [0.3, 1.0, -0.2], [0.1, -0.2, 0.5]], dtype=torch.float64)
    reference = JulierSigmaPoints(3, kappa=KAPPA)
    assert np.allclose(sigma_points(mean, cov, KAPPA).numpy(), reference.sigma_points(mean.numpy(), cov.numpy()),
                       rtol=1e-12, atol=1e-12)
    assert np.allclose(sigma_weights(3, KAPPA).numpy(), reference.Wm, rtol=1e-15)


@pytest.mark.parametrize("model_name", ["se2", "se2_velocity"])
def test_ukf_matches_filterpy_on_random_se2_tracks(model_name):
    generator = np.random.default_rng(7)
    model = belief_model(model_name, DT, q=0.5, dtype=torch.float64)
    ours = UnscentedKalmanFilter(model, torch.tensor(MEAS_NOISE), kappa=KAPPA)
    dim, tracks, steps = model.dim, 6, 25
    checked = 0
    for _ in range(tracks):
        truth = np.array([0.0, 0.0, generator.uniform(-math.pi, math.pi), 1.2, generator.uniform(-0.4, 0.4)])
        pose = np.array([-4.0, 1.0, 0.0])
        mean = np.concatenate((truth[:2] + generator.normal(0, 0.5, 2), [truth[2] + 0.2], truth[3:dim]))[:dim]
        cov = np.diag(generator.uniform(0.2, 1.0, dim))
        reference = _reference(dim, model.noise.numpy())
        reference.x, reference.P = mean.copy(), cov.copy()
        m, c = torch.tensor(mean)[None, None], torch.tensor(cov)[None, None]
        for _ in range(steps):
            truth = np.concatenate((_unicycle(truth[:3], DT, truth[3], truth[4]), truth[3:]))
            pose = np.concatenate((truth[:2] - 5.0 * np.array([math.cos(truth[2]), math.sin(truth[2])]), [truth[2]]))
            m, c = ours.predict(m, c, None, None)
            reference.predict()
            _assert_close(m, c, reference)
            z = reference.hx(truth, pose) + generator.normal(0.0, [0.2, 0.01])
            m, c = ours.update(m, c, torch.tensor(z)[None, None], torch.tensor(pose)[None])
            reference.update(z, R=MEAS_NOISE, pose=pose)
            _assert_close(m, c, reference)
            checked += 1
    assert checked == tracks * steps


def _assert_close(mean, cov, reference):
    ours_mean, ours_cov = mean[0, 0].numpy(), cov[0, 0].numpy()
    difference = ours_mean - reference.x
    difference[2] = _wrap(difference[2])
    assert np.all(np.abs(difference) <= 1e-6 * np.maximum(1.0, np.abs(reference.x)))
    assert np.allclose(ours_cov, reference.P, rtol=1e-6, atol=1e-9)
