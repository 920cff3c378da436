"""aia.evaluation.rollouts: one episode in every world."""

from __future__ import annotations

import torch

from aia.envs import make_env
from aia.evaluation import episode_scores, run_episodes
from aia.policies import RandomPolicy


def test_run_episodes_covers_one_episode_per_world_and_is_seeded():
    env = make_env("empty1", batch_size=3, seed=0, overrides=["max_steps=25"])
    first = run_episodes(env, RandomPolicy(12, seed=1), seed=5)
    again = run_episodes(env, RandomPolicy(12, seed=1), seed=5)
    assert first.shape == (3, 25)
    assert first["next", "truncated"][:, -1].all() and not first["next", "truncated"][:, :-1].any()
    assert torch.equal(episode_scores(first), episode_scores(again))
