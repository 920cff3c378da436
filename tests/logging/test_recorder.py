"""SceneRecorder: records the armed episode of one world, exactly what the env produced."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from aia.envs import make_env
from aia.logging import MCAPLogger, SceneRecorder, read_run


def _recorded_env(tmp_path, world=1, batch_size=3):
    logger = MCAPLogger("exp", tmp_path)
    env = make_env("obstacles1", batch_size=batch_size, seed=3, overrides=["num_targets=2", "max_steps=12"])
    recorder = SceneRecorder(logger, world=world)
    env.append_transform(recorder)
    return logger, env, recorder


def test_records_every_step_of_the_armed_episode_of_its_world(tmp_path):
    logger, env, recorder = _recorded_env(tmp_path)
    torch.manual_seed(0)
    env.rollout(12, break_when_any_done=False)  # not armed: nothing is written
    recorder.record(episode=5, frame=640)
    rollout = env.rollout(12, break_when_any_done=False)
    assert not recorder.recording  # the episode ended and disarmed it
    logger.close()

    run = read_run(tmp_path / "run.mcap")
    assert run.episodes() == [5]
    info, frames = run.episode(5)
    assert info.grid_map.name == "obstacles4" and (info.num_targets, info.frame) == (2, 640)
    assert [f.step for f in frames] == list(range(13))
    assert all((f.episode, f.frame) == (5, 640) for f in frames)
    world = rollout[1]
    poses = torch.cat((world["robot_pose"][:1], world["next", "robot_pose"])).double().numpy()
    targets = torch.cat((world["target_state"][:1], world["next", "target_state"]))[..., :2].double().numpy()
    means = torch.cat((world["belief_mean"][:1], world["next", "belief_mean"]))[..., :2].double().numpy()
    covs = torch.cat((world["belief_cov"][:1], world["next", "belief_cov"]))[..., :2, :2].double().numpy()
    observed = torch.cat((world["observed"][:1], world["next", "observed"])).numpy()
    assert np.stack([f.robot_pose for f in frames]) == pytest.approx(poses, abs=1e-4)
    assert np.stack([f.targets for f in frames]) == pytest.approx(targets, abs=1e-3)
    assert np.stack([f.belief_mean for f in frames]) == pytest.approx(means, abs=1e-3)
    assert np.stack([f.belief_cov for f in frames]) == pytest.approx(covs, rel=1e-5, abs=1e-6)
    assert np.array_equal(np.stack([f.observed for f in frames]), observed)
    assert frames[4].time == pytest.approx(4 * env.base_env.config.dt)


def test_a_partial_reset_of_other_worlds_does_not_start_a_recording(tmp_path):
    logger, env, recorder = _recorded_env(tmp_path, world=0)
    state = env.reset()
    recorder.record(episode=1, frame=0)
    env.reset(state.set("_reset", torch.tensor([[False], [True], [False]])))
    assert not recorder.recording
    env.reset()
    assert recorder.recording
    logger.close()


def test_the_recorded_world_must_exist(tmp_path):
    logger, env, recorder = _recorded_env(tmp_path, world=3)
    recorder.record(episode=1, frame=0)
    with pytest.raises(ValueError, match="world=3 is out of range for an env of 3 worlds"):
        env.reset()
    logger.close()


def test_a_particle_filter_records_its_particles_every_step_and_render_draws_them(tmp_path):
    """With a particle filter each recorded step also writes ``/belief_particles`` (a ``foxglove.PointCloud``):
    the recorded world's particles and weights as float32, read back with the frame they belong to."""
    from aia.envs.render import PARTICLE_COLOUR, render_frame
    from aia.logging.scenes import PARTICLES_TOPIC, parse_particle_cloud

    logger = MCAPLogger("exp", tmp_path)
    env = make_env("ttenv_v2_particle", batch_size=2, seed=1,
                   overrides=["max_steps=4", "belief.particles=16", "num_targets=2"])
    env.append_transform(SceneRecorder(logger, world=1))
    env.transform[-1].record(episode=0, frame=0)
    rollout = env.rollout(4, break_when_any_done=False)
    logger.close()

    run = read_run(tmp_path / "run.mcap")
    assert run.topic_counts()[PARTICLES_TOPIC] == ("foxglove.PointCloud", 5)  # the reset and 4 steps
    world = rollout[1]
    particles = torch.cat((world["belief_particles"][:1], world["next", "belief_particles"]))[..., :2]
    weights = torch.cat((world["belief_weights"][:1], world["next", "belief_weights"]))
    clouds = [parse_particle_cloud(m.data) for m in run.messages if m.topic == PARTICLES_TOPIC]
    assert np.array_equal(np.stack([c[0] for c in clouds]), particles.double().numpy())
    assert np.array_equal(np.stack([c[1] for c in clouds]), weights.double().numpy())
    info, frames = run.episode("first")
    assert np.array_equal(frames[2].particles, clouds[2][0])
    image = render_frame(info.grid_map, frames[2].robot_pose, frames[2].targets, frames[2].belief_mean,
                         frames[2].belief_cov, info.sensor_range, info.fov_deg, particles=frames[2].particles)
    assert (image == np.array(PARTICLE_COLOUR, dtype=np.uint8)).all(-1).any()
