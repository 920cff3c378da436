"""Compile aia's numba kernels into numba's cache (files beside their modules), while the test session's workers start.

numba compiles a kernel on its first use in a process and caches it; a process that needs it before one has
written it compiles its own. In a fresh clone the two workers and the processes the tests start did so again and
again: the suite took 376 s there against 267 s with the caches made (one run each, back to back). Compiling
every kernel once takes 24 s on one core, in two parts run side by side (tests/conftest.py starts them, and each
worker's first test waits for them):

    python -m tests.kernel_cache envs      # the map queries, the map generator, the visit maps (about 18 s)
    python -m tests.kernel_cache planner   # ARVI's expansion and pruning (about 11 s)
"""

from __future__ import annotations

import sys

import torch
from torchrl.envs import StepCounter, TransformedEnv

from aia.envs import make_env
from aia.planners import ARVIConfig, ARVIPolicy

PARTS = ("envs", "planner")


def compile_envs() -> None:
    """A step of per-world random maps (generator, block fields, walk, collisions, sight) and of ttenv v5's
    visit maps."""
    for name in ("random_obstacles", "ttenv_v5"):
        env = make_env(name, batch_size=2, device="cpu", seed=0)
        state = env.reset()
        state.set("action", torch.zeros(2, dtype=torch.long))
        env.step(state)


def compile_planner() -> None:
    """One ARVI plan on a map with obstacles."""
    env = TransformedEnv(make_env("obstacles1", batch_size=2, device="cpu", seed=0), StepCounter())
    config = ARVIConfig(time_budget=None, max_passes=0, max_nodes=50, horizon=2, replan_every=1)
    ARVIPolicy(env, config)(env.reset())


if __name__ == "__main__":
    part = sys.argv[1] if len(sys.argv) > 1 else ""
    if part not in PARTS:
        sys.exit(f"kernel_cache: expected one of {', '.join(PARTS)}, got {part!r}")
    {"envs": compile_envs, "planner": compile_planner}[part]()
