"""The CPU expansion kernel makes the children the tensor ops make: the same children, poses bit for bit."""

from __future__ import annotations

import pytest
import torch

from aia.envs import make_env
from aia.planners import ARVIConfig, ARVIPlanner
from aia.planners.tree import Expansion
from aia.policies import RandomPolicy


def _states(setting: str, worlds: int, seed: int) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """A seeded reset and a few random steps; the first world's first target made so uncertain that
    the prediction meets the det cap in the tree."""
    env = make_env(setting, batch_size=worlds, seed=seed, transforms=False)
    random = RandomPolicy(env.action_spec.n, seed=seed)
    td = env.reset()
    for _ in range(4):
        td = env.step(random(td))["next"]
    cov = td["belief_cov"].double().clone()
    cov[0, 0] = 32.0 * torch.eye(4, dtype=torch.float64)  # det 1.05e6, over the cap 1e6
    return td["robot_pose"], td["belief_mean"], cov


@pytest.mark.parametrize(("setting", "overrides"), [
    ("empty1", {"min_range": 2.0}),  # the minimum range hides close targets
    ("obstacles1", {}),  # collisions with obstacles and lines of sight
    ("small3", {"eps": 0.5}),  # three targets
    ("random_obstacles", {}),  # a map per world: the margin test instead of the collision grid
])
def test_the_kernel_makes_the_children_of_the_tensor_ops(setting, overrides, monkeypatch):
    kernel = Expansion.extend
    seen = {"calls": 0, "children": 0, "dropped": 0, "updated": 0, "capped": 0}

    def both(self, below, level, parents, positions, maps):
        before = below.size
        made = kernel(self, below, level, parents, positions, maps)
        expected = self.children_tensors(level, parents, positions, maps)
        for name in ("pose", "world", "parent", "action"):
            assert torch.equal(made[name], expected[name]), name
            assert torch.equal(getattr(below, name)[before:], expected[name]), name  # appended to the level
        for name in ("cov", "logdet", "cost"):
            torch.testing.assert_close(made[name], expected[name], rtol=1e-12, atol=1e-12)
        assert not below.expanded[before:].any()
        prior = level.cov.index_select(0, made["parent"])
        seen["calls"] += 1
        seen["children"] += made["cost"].numel()
        seen["dropped"] += parents.numel() * self.model.primitives.shape[0] - made["cost"].numel()
        seen["updated"] += int((made["logdet"] < level.logdet.index_select(0, made["parent"]) - 1e-9).sum())
        seen["capped"] += int((made["cov"] == prior).flatten(2).all(-1).sum())
        return made

    monkeypatch.setattr(Expansion, "extend", both)
    states = _states(setting, worlds=3, seed=5)
    env = make_env(setting, batch_size=3, seed=5, transforms=False)
    env.reset()  # the maps of _states' env, where each world has its own
    planner = ARVIPlanner(env, ARVIConfig(time_budget=None, max_nodes=1500, **overrides))
    planner.plan(*states)
    assert seen["calls"] > 10 and seen["children"] > 3 * 1500 * 0.9
    # every branch of the kernel was taken: collisions, Kalman updates, the det cap
    assert seen["updated"] > 0 and seen["capped"] > 0
    assert seen["dropped"] > 0 or setting not in ("obstacles1", "random_obstacles")


def test_a_planner_reusing_its_buffers_plans_as_a_fresh_one():
    """The levels' buffers kept from an earlier (larger) call change nothing of a later call's plans."""
    env = make_env("small3", transforms=False)
    config = ARVIConfig(time_budget=None, max_nodes=800)
    reused = ARVIPlanner(env, config)
    reused.plan(*_states("small3", worlds=4, seed=1))
    grown = [level["cost"].shape[0] for level in reused.storage]
    for seed in (2, 3):
        states = _states("small3", worlds=2, seed=seed)
        again, fresh = reused.plan(*states), ARVIPlanner(env, config).plan(*states)
        for name in ("actions", "cost", "nodes"):
            assert torch.equal(getattr(again, name), getattr(fresh, name)), name
    assert [level["cost"].shape[0] for level in reused.storage] == grown  # the first call's buffers, reused
    assert max(grown) >= 1024


def test_planning_leaves_plain_tensors():
    """The search runs in inference mode; its results can be written to in place like any tensor."""
    planner = ARVIPlanner(make_env("empty1", transforms=False), ARVIConfig(time_budget=None, max_nodes=300))
    result = planner.plan(*_states("empty1", worlds=2, seed=0))
    assert not any(t.is_inference() for t in (result.actions, result.cost, result.nodes))
    result.actions.add_(1)  # an inference tensor would refuse this outside inference mode
