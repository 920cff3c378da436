"""BeliefFeatures: hand-computed features, both relative-velocity forms, specs, composition."""

from __future__ import annotations

import math

import pytest
import torch
from torchrl.envs import ObservationNorm, RewardSum, StepCounter

from aia.envs import make_env
from aia.transforms import BeliefFeatures, belief_features


def _features(pose, velocity, mean, form, logdet=(7.5,), observed=(True,), obstacle=(2.0, -0.3)):
    mean = torch.tensor([mean], dtype=torch.float64)
    return belief_features(
        torch.tensor([pose], dtype=torch.float64),
        torch.tensor([velocity], dtype=torch.float64),
        mean[..., :2],
        mean[..., 2:],
        torch.tensor([logdet], dtype=torch.float64),
        torch.tensor([observed]),
        torch.tensor([obstacle], dtype=torch.float64),
        form,
    )[0]


def test_exact_features_hand_computed():
    # robot at the origin moving along x with (v, w) = (1, 0.5); belief at (3, 4) moving like the robot
    f = _features((0.0, 0.0, 0.0), (1.0, 0.5), [(3.0, 4.0, 1.0, 0.0)], "exact")
    expected = [5.0, math.atan2(4, 3), 0.0, -0.5, 7.5, 1.0, 2.0, -0.3]
    assert torch.allclose(f, torch.tensor(expected, dtype=torch.float64))
    # robot at (1, 1) facing +y at 2 m/s; belief straight ahead at 3 m moving (0.5, -1)
    f = _features((1.0, 1.0, math.pi / 2), (2.0, 0.0), [(1.0, 4.0, 0.5, -1.0)], "exact")
    # relative velocity (0.5, -3): rdot = (0, 3).(0.5, -3) / 3 = -3; alphadot = (0 * -3 - 3 * 0.5) / 9
    assert torch.allclose(f[:4], torch.tensor([3.0, 0.0, -3.0, -1.5 / 9], dtype=torch.float64), atol=1e-12)


def test_2019_features_hand_computed():
    # |p| w term: robot velocity (v cos th - |p| w sin th, v sin th + |p| w cos th) = (1, 1)
    f = _features((2.0, 0.0, 0.0), (1.0, 0.5), [(5.0, 4.0, 1.0, 0.0)], "2019")
    # rdot = (3, 4).(0, -1) / 5; alphadot about the map origin: (5 * 0 - 1 * 4) / 41 - 0.5
    expected = [5.0, math.atan2(4, 3), -0.8, -4 / 41 - 0.5]
    assert torch.allclose(f[:4], torch.tensor(expected, dtype=torch.float64), atol=1e-12)
    f = _features((1.0, 1.0, math.pi / 2), (2.0, 0.0), [(1.0, 4.0, 0.5, -1.0)], "2019")
    assert torch.allclose(f[2:4], torch.tensor([-3.0, -3 / 17], dtype=torch.float64), atol=1e-12)


def test_several_targets_layout_and_zero_distance():
    mean = [(3.0, 4.0, 0.0, 0.0), (0.0, 0.0, 1.0, 1.0)]  # the second sits on the robot
    f = _features((0.0, 0.0, 0.0), (0.0, 0.3), mean, "exact", logdet=(1.0, 2.0), observed=(False, True))
    assert f.shape == (14,)
    assert f[[4, 5, 10, 11]].tolist() == [1.0, 0.0, 2.0, 1.0]
    assert f[6].item() == 0.0 and f[8].item() == 0.0 and f[9].item() == pytest.approx(-0.3)
    assert f[-2:].tolist() == pytest.approx([2.0, -0.3])
    f2019 = _features((0.0, 0.0, 0.0), (0.0, 0.3), mean, "2019", logdet=(1.0, 2.0), observed=(False, True))
    assert f2019[8].item() == 0.0 and f2019[9].item() == 0.0  # the 2019 code returns (0, 0) at r = 0


def test_bad_relative_velocity_form():
    with pytest.raises(ValueError, match="relative_velocity='polar'.*exact"):
        BeliefFeatures("polar")


@pytest.mark.parametrize("setting", ["obstacles1", "small3_2019"])
def test_features_inside_spec_and_match_raw_keys(setting):
    env = make_env(setting, batch_size=8, seed=1)
    spec = env.observation_spec["observation"]
    n = env.base_env.num_targets
    assert spec.shape == (8, 6 * n + 2)
    assert spec.space.high[0, -2].item() == 10.0
    td = env.rollout(60, break_when_any_done=False)
    for t in range(60):
        assert spec.is_in(td[:, t]["next", "observation"])
    obs = td["next", "observation"]
    assert torch.equal(obs[..., 4:6 * n:6], td["next", "logdet_cov"])
    assert torch.equal(obs[..., -2:], td["next", "obstacle_polar"])
    # reset features: zero rates (the robot and the beliefs are at rest)
    assert (td["observation"][:, 0, 2:6 * n:6] == 0).all()


def test_composes_with_torchrl_transforms():
    env = make_env("small2", batch_size=4, seed=0)
    for transform in (StepCounter(), RewardSum(), ObservationNorm(in_keys=["observation"], standard_normal=True)):
        env.append_transform(transform)
    env.transform[-1].init_stats(num_iter=150, reduce_dim=(0, 1), cat_dim=1)
    td = env.rollout(150, break_when_any_done=False)
    assert td["next", "step_count"][:, -1].squeeze(-1).tolist() == [150] * 4
    assert torch.allclose(td["next", "episode_reward"][:, -1], td["next", "reward"].sum(1), rtol=1e-4, atol=1e-3)
    normed = td["next", "observation"]
    assert normed.mean().abs().item() < 0.5
