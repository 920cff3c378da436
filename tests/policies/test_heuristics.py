"""Scripted policies: reproducibility, belief-only inputs, and the pursuit heuristic's margin over random."""

from __future__ import annotations

import math

import torch

from aia.envs import make_env
from aia.evaluation import episode_scores, run_episodes
from aia.policies import BeliefPursuitPolicy, RandomPolicy


def test_random_policy_is_seeded_and_in_range():
    env = make_env("empty1", batch_size=64, seed=0)
    td = env.reset()
    a = RandomPolicy(12, seed=3)(td.clone())["action"]
    b = RandomPolicy(12, seed=3)(td.clone())["action"]
    assert torch.equal(a, b) and a.min() >= 0 and a.max() <= 11 and len(a.unique()) > 6


def test_pursuit_turns_toward_the_belief_and_ignores_the_truth():
    env = make_env("empty1", batch_size=2, seed=0)
    policy = BeliefPursuitPolicy(env.base_env)
    pose = torch.tensor([[50.0, 50.0, 0.0], [50.0, 50.0, 0.0]])
    mean = torch.tensor([[[50.0, 60.0, 0.0, 0.0]], [[55.0, 50.0, 0.0, 0.0]]])  # to the left; straight ahead
    action = policy.choose(pose, mean[..., :2], mean[..., 2:], torch.zeros(2, 1))
    assert action[0].item() in (0, 3, 6, 9)  # a left turn (w = +pi/2)
    assert action[1].item() in (1, 4, 7, 10)  # straight on, already at the standoff distance
    td = env.reset().exclude("target_state")
    assert policy(td)["action"].shape == (2,)


def test_pursuit_beats_random_by_a_clear_margin():
    env = make_env("empty1", batch_size=32, seed=7)
    random_scores = episode_scores(run_episodes(env, RandomPolicy(12, seed=7), seed=7))
    pursuit_scores = episode_scores(run_episodes(env, BeliefPursuitPolicy(env.base_env), seed=7))
    margin = pursuit_scores.mean() - random_scores.mean()
    spread = math.hypot(random_scores.std().item(), pursuit_scores.std().item()) / math.sqrt(32)
    assert margin.item() > 500 and margin.item() > 4 * spread
