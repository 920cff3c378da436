"""Tests of the Gymnasium wrapper ``aia.envs.gym.TargetTrackingGymEnv`` and its registration."""

from __future__ import annotations

import importlib
import subprocess
import sys
import warnings

import gymnasium
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

import aia
from aia.envs.gym import TargetTrackingGymEnv, resolve_setting


@pytest.fixture(scope="module")
def env() -> TargetTrackingGymEnv:
    return TargetTrackingGymEnv(map="empty", num_targets=1, render_mode="rgb_array", render_size=160)


def rollout(env: TargetTrackingGymEnv, seed: int, actions: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    obs, _ = env.reset(seed=seed)
    observations, rewards = [obs], []
    for action in actions:
        obs, reward, *_ = env.step(action)
        observations.append(obs)
        rewards.append(reward)
    return np.stack(observations), np.array(rewards)


def test_check_env_passes(env):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # the Box bounds are infinite for the rates and log det
        check_env(env)


def test_spaces(env):
    assert env.action_space == gymnasium.spaces.Discrete(12)
    assert env.observation_space.shape == (8,)
    assert env.observation_space.dtype == np.float32
    assert env.observation_space.high[6] == pytest.approx(10.0)  # obstacle distance <= sensor range
    assert env.metadata["render_modes"] == ["rgb_array"] and env.metadata["render_fps"] == 2
    obs, info = env.reset(seed=0)
    assert obs.dtype == np.float32 and env.observation_space.contains(obs)


def test_same_seed_same_episode_and_different_seeds_differ(env):
    actions = np.random.default_rng(0).integers(0, 12, size=20)
    obs_a, rew_a = rollout(env, 7, actions)
    obs_b, rew_b = rollout(env, 7, actions)
    obs_c, _ = rollout(env, 8, actions)
    assert obs_a.shape == (21, 8)
    np.testing.assert_array_equal(obs_a, obs_b)
    np.testing.assert_array_equal(rew_a, rew_b)
    assert not np.array_equal(obs_a[0], obs_c[0])
    assert np.abs(obs_a - obs_c).max() > 0.1
    # A fresh instance with the same seed replays the same episode too.
    other = TargetTrackingGymEnv(map="empty", num_targets=1)
    obs_d, rew_d = rollout(other, 7, actions)
    np.testing.assert_array_equal(obs_a, obs_d)
    np.testing.assert_array_equal(rew_a, rew_d)


def test_step_outputs_and_info(env):
    obs, info = env.reset(seed=1)
    assert set(info) == {"logdet_cov", "observed", "collision", "score_increment"}
    obs, reward, terminated, truncated, info = env.step(np.int64(4))
    assert isinstance(reward, float) and np.isfinite(reward)
    assert terminated is False and truncated is False
    assert info["logdet_cov"].shape == (1,)
    assert info["observed"].shape == (1,) and info["observed"].dtype == bool
    assert isinstance(info["collision"], bool)
    assert info["score_increment"] == pytest.approx(-info["logdet_cov"].mean())
    # The observation carries the same log det and observed flag (features 4 and 5 of the target).
    assert obs[4] == pytest.approx(info["logdet_cov"][0])
    assert obs[5] == float(info["observed"][0])
    # The reward is the shaped one, not the raw score increment.
    assert reward != pytest.approx(info["score_increment"])


def test_invalid_action_raises_value_error_naming_it(env):
    env.reset(seed=0)
    with pytest.raises(ValueError, match=r"action 12 .*0\.\.11"):
        env.step(12)
    with pytest.raises(ValueError, match=r"action -3 "):
        env.step(np.int64(-3))
    with pytest.raises(ValueError, match=r"action 1\.5 "):
        env.step(1.5)
    env.step(np.int32(11))  # numpy ints are fine
    env.step(np.array(0))


def test_render_returns_an_rgb_frame(env):
    env.reset(seed=2)
    env.step(0)
    frame = env.render()
    assert frame.shape == (160, 160, 3) and frame.dtype == np.uint8
    assert (frame == np.array([30, 60, 220], dtype=np.uint8)).all(-1).any()  # the robot is drawn


def test_truncation_after_max_steps():
    env = TargetTrackingGymEnv(map="empty_small", num_targets=2, overrides=["max_steps=5"])
    assert env.setting == "small2" and env.config.max_steps == 5
    env.reset(seed=0)
    flags = [env.step(7)[2:4] for _ in range(5)]
    assert flags == [(False, False)] * 4 + [(False, True)]
    obs, _ = env.reset()
    assert env.step(7)[3] is False  # a new episode starts the count again
    assert obs.shape == (6 * 2 + 2,)


def test_observation_size_for_three_targets():
    env = TargetTrackingGymEnv(map="empty_small", num_targets=3)
    assert env.setting == "small3"
    obs, info = env.reset(seed=0)
    assert env.observation_space.shape == (20,) and obs.shape == (20,)
    obs, *_, info = env.step(3)
    assert obs.shape == (20,) and info["logdet_cov"].shape == (3,) and info["observed"].shape == (3,)


def test_collision_is_reported():
    env = TargetTrackingGymEnv(map="empty_small", num_targets=2)
    env.reset(seed=0)
    # Full speed straight ahead from the centre of a 27 m map reaches a wall within 10 steps.
    collisions = [env.step(1)[4]["collision"] for _ in range(15)]
    assert any(collisions)


@pytest.mark.parametrize(
    ("args", "expected"),
    [
        ((None, None, None), ("empty1", [])),
        ((None, "empty", 1), ("empty1", [])),
        ((None, "obstacles4", None), ("obstacles1", [])),
        ((None, "empty_small", 2), ("small2", [])),
        ((None, "empty_small", 3), ("small3", [])),
        ((None, "empty", 3), ("empty1", ["map=empty", "num_targets=3", "max_steps=150"])),
        ((None, "empty_small", 1), ("empty1", ["map=empty_small", "num_targets=1"])),
        (("obstacles1_2019", None, 2), ("obstacles1_2019", ["num_targets=2"])),
    ],
)
def test_resolve_setting(args, expected):
    assert resolve_setting(*args, overrides=()) == expected


def test_user_overrides_come_last():
    assert resolve_setting(None, "empty", 2, ["max_steps=20"]) == (
        "empty1", ["map=empty", "num_targets=2", "max_steps=150", "max_steps=20"]
    )
    env = TargetTrackingGymEnv(map="empty", num_targets=2, overrides=["max_steps=20", "sensor.range=12"])
    assert env.config.max_steps == 20 and env.config.num_targets == 2 and env.config.sensor.range == 12
    assert env.observation_space.high[-2] == pytest.approx(12.0)


def test_bad_arguments_raise():
    with pytest.raises(ValueError, match="render_mode"):
        TargetTrackingGymEnv(render_mode="human")
    with pytest.raises(ValueError, match="nowhere"):
        TargetTrackingGymEnv(map="nowhere")


def test_registered_id_makes_the_env():
    env = gymnasium.make("aia/TargetTracking-v0", map="empty", num_targets=1, render_mode="rgb_array",
                         render_size=64)
    assert isinstance(env.unwrapped, TargetTrackingGymEnv)
    obs, _ = env.reset(seed=3)
    assert obs.shape == (8,)
    env.step(2)
    assert env.render().shape == (64, 64, 3)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # importing aia again is a no-op, not an "overriding" warning
        importlib.reload(aia)


def test_fresh_process_can_make_the_env_by_module_prefix():
    code = ("import gymnasium; e = gymnasium.make('aia:aia/TargetTracking-v0', map='empty_small', num_targets=3); "
            "print(e.reset(seed=0)[0].shape)")
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert result.returncode == 0, result.stderr
    assert result.stdout.strip() == "(20,)"


def test_a_map_observation_gives_a_dict_space_and_random_maps_render_their_own_map():
    """ttenv_v4 (features and the local map image) behind the Gymnasium API: a Dict observation space whose
    observations it contains, gymnasium's checker passes; on random maps the frame draws the world's own map."""
    env = TargetTrackingGymEnv("ttenv_v4", render_mode="rgb_array", render_size=64,
                               overrides=["features.im_size=6", "map=random_obstacles", "target.collision_rule=reflect",
                                          "max_steps=5"])
    assert env.observation_space == gymnasium.spaces.Dict({
        "observation": env.observation_space["observation"],
        "local_map": gymnasium.spaces.Box(-1.0, 1.0, (1, 6, 6), np.float32)})
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # the features' Box bounds are infinite for the rates and log det
        check_env(env)
    obs, _ = env.reset(seed=2)
    assert env.observation_space.contains(obs) and set(np.unique(obs["local_map"])) <= {-1.0, 1.0}
    world = env.base_env.world_map(0)
    assert world.has_obstacles and world.name == "world 0"
    assert env.render().shape == (64, 64, 3)
