"""Record the ARVI planner's plans on fixed seeded states of the four settings (``arvi_plans.pt``).

The file was written by the planner of commit 54a9a5a (before issue 16's rewrite); ``test_plans.py`` checks
that the planner still returns exactly these actions. Rerun only to extend the cases, with that commit's
planner (``git show 54a9a5a:aia/planners/arvi.py``):

    python tests/planners/data/record_arvi_plans.py
"""

from __future__ import annotations

from pathlib import Path

import torch

from aia.envs import make_env
from aia.planners import ARVIConfig, ARVIPlanner
from aia.policies import RandomPolicy

SETTINGS = ("empty1", "obstacles1", "small2", "small3")
WORLDS = 6  # planned together in one call
RANDOM_STEPS = 9  # random steps from the seeded reset, so that beliefs and poses vary
# Deterministic budgets: a node budget (the protocol's kind), and a pass budget with finite eps and min_range.
CASES = {
    "nodes": {"time_budget": None, "max_nodes": 2500},
    "passes_eps": {"time_budget": None, "max_passes": 30, "eps": 0.5, "min_range": 2.0},
}
PATH = Path(__file__).with_name("arvi_plans.pt")


def states(setting: str) -> dict[str, torch.Tensor]:
    """``WORLDS`` seeded states of ``setting``: robot pose and belief after ``RANDOM_STEPS`` random steps."""
    env = make_env(setting, batch_size=WORLDS, seed=16, transforms=False)
    random = RandomPolicy(env.action_spec.n, seed=16)
    td = env.reset()
    for _ in range(RANDOM_STEPS):
        td = env.step(random(td))["next"]
    return {"pose": td["robot_pose"].clone(), "mean": td["belief_mean"].clone(), "cov": td["belief_cov"].clone()}


def record() -> dict:
    """Per setting: the states and, per budget case, the planner's actions, nodes, passes and cost."""
    torch.set_num_threads(1)
    out = {}
    for setting in SETTINGS:
        state = states(setting)
        env = make_env(setting, transforms=False)
        plans = {}
        for case, budget in CASES.items():
            result = ARVIPlanner(env, ARVIConfig(**budget)).plan(state["pose"], state["mean"], state["cov"])
            plans[case] = {"actions": result.actions, "nodes": result.nodes, "passes": result.passes,
                           "cost": result.cost}
        out[setting] = {"state": state, "plans": plans}
    return {"cases": CASES, "settings": out}


if __name__ == "__main__":
    torch.save(record(), PATH)
    print(f"wrote {PATH} ({PATH.stat().st_size} bytes)")
