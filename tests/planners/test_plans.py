"""ARVI returns the plans recorded from the planner before issue 16's rewrite (``data/arvi_plans.pt``), with the
CPU's compiled kernels and with the tensor ops that run elsewhere."""

from __future__ import annotations

from pathlib import Path

import pytest
import torch

from aia.envs import make_env
from aia.planners import ARVIConfig, ARVIPlanner, search
from aia.planners.pruning import prune_tensors
from aia.planners.tree import Expansion

RECORDED = torch.load(Path(__file__).parent / "data" / "arvi_plans.pt", weights_only=True)


def _extend_by_tensor_ops(self, below, level, parents, positions, maps):
    """:meth:`Expansion.extend` as it runs off the CPU: the children in tensor ops, appended."""
    children = self.children_tensors(level, parents, positions, maps)
    below.append(children)
    return children


@pytest.mark.parametrize("implementation", ["cpu kernels", "tensor ops"])  # tensor ops: what a GPU runs
@pytest.mark.parametrize("case", sorted(RECORDED["cases"]))
@pytest.mark.parametrize("setting", sorted(RECORDED["settings"]))
def test_plans_equal_the_recorded_ones(setting, case, implementation, monkeypatch):
    if implementation == "tensor ops":
        monkeypatch.setattr(Expansion, "extend", _extend_by_tensor_ops)
        monkeypatch.setattr(search, "prune", prune_tensors)
    recorded = RECORDED["settings"][setting]
    state, expected = recorded["state"], recorded["plans"][case]
    planner = ARVIPlanner(make_env(setting, transforms=False), ARVIConfig(**RECORDED["cases"][case]))
    result = planner.plan(state["pose"], state["mean"], state["cov"])
    assert torch.equal(result.actions, expected["actions"])
    assert torch.equal(result.nodes, expected["nodes"]) and result.passes == expected["passes"]
    torch.testing.assert_close(result.cost, expected["cost"], rtol=1e-12, atol=1e-9)
