"""Budget groups: several groups planned in one batch each get exactly the plans of the group planned alone."""

from __future__ import annotations

from pathlib import Path

import pytest
import torch

from aia.envs import make_env
from aia.planners import ARVIConfig, ARVIPlanner

STATES = torch.load(Path(__file__).parent / "data" / "arvi_plans.pt", weights_only=True)["settings"]
GROUPS = torch.tensor([0, 1, 0, 2, 2, 1])  # interleaved: groups of 2, 2 and 2 worlds
BUDGETS = {"nodes": {"time_budget": None, "max_nodes": 1500},
           "passes_eps": {"time_budget": None, "max_passes": 20, "eps": 0.5, "min_range": 2.0},
           "nodes_and_passes": {"time_budget": None, "max_nodes": 1500, "max_passes": 26}}


@pytest.mark.parametrize(("setting", "case"), [("small2", "nodes"), ("obstacles1", "passes_eps"),
                                               ("small2", "nodes_and_passes")])
def test_each_group_plans_as_if_alone(setting, case):
    state = STATES[setting]["state"]
    planner = ARVIPlanner(make_env(setting, transforms=False), ARVIConfig(**BUDGETS[case]))
    together = planner.plan_groups(state["pose"], state["mean"], state["cov"], GROUPS)
    assert len(together) == 3
    passes = set()
    for group, result in enumerate(together):
        worlds = GROUPS.eq(group).nonzero().squeeze(-1)
        alone = planner.plan(state["pose"][worlds], state["mean"][worlds], state["cov"][worlds])
        assert torch.equal(result.actions, alone.actions) and torch.equal(result.nodes, alone.nodes)
        assert torch.equal(result.cost, alone.cost)
        assert (result.passes, result.delta) == (alone.passes, alone.delta)
        passes.add(alone.passes)
    if case != "passes_eps":  # the groups stop at different passes, and a shared budget would plan otherwise
        assert len(passes) > 1
        shared = planner.plan(state["pose"], state["mean"], state["cov"])
        assert not all(torch.equal(shared.nodes[GROUPS.eq(g)], r.nodes) for g, r in enumerate(together))


def test_bad_groups_are_named():
    state = STATES["empty1"]["state"]
    planner = ARVIPlanner(make_env("empty1", transforms=False), ARVIConfig(time_budget=None, max_passes=1))
    with pytest.raises(ValueError, match="groups must label the 6 worlds 0 .. G - 1"):
        planner.plan_groups(state["pose"], state["mean"], state["cov"], torch.tensor([0, 0, 2, 2, 2, 2]))
