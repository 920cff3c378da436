"""``SnapshotPolicy``: saved parameter sets of a population's stacked Q-network, each on its own worlds.

The training loop evaluates the policy after every few training episodes. Instead of one small rollout per
evaluation it keeps a copy of the members' stacked parameters at each evaluation point and later plays
several of them in one batched rollout. The batch ``[G * P * E]`` holds ``G`` snapshots of ``P`` members with
``E`` worlds each: world group ``(g, k)`` acts with member ``k`` of snapshot ``g`` (``torch.func.vmap`` over
the snapshots of the stacked network: one call for all groups) and draws its epsilon-greedy noise from its
own counter-based stream (:mod:`aia.rng`, keyed by the group's seed and the step), so what a group does
never depends on the other groups, the snapshots or the members played beside it.
"""

from __future__ import annotations

from collections.abc import Sequence

import torch
from tensordict import TensorDictBase
from tensordict.nn import TensorDictModuleBase
from torch import Tensor

from aia import rng
from aia.modules.exploration import exploring
from aia.modules.q_networks import network_in_keys
from aia.modules.stacked import StackedConvQNetwork, StackedQNetwork
from aia.runtime.compiling import compiled


def parameter_snapshot(network: torch.nn.Module) -> dict[str, Tensor]:
    """A detached copy of ``network``'s parameters, by name."""
    return {name: param.detach().clone() for name, param in network.named_parameters()}


class SnapshotPolicy(TensorDictModuleBase):
    """Epsilon-greedy actions of ``G`` parameter snapshots of ``P`` stacked members, one per group of worlds.

    :meth:`load` sets the snapshots and one noise seed per (snapshot, member) group. Group ``(g, k)`` takes
    the argmax of member ``k`` of snapshot ``g`` (for ADFQ, of its means) and, while exploring (exploration
    type ``RANDOM`` or unset), replaces it by a uniform random action with probability ``epsilon``.
    ``compile=True`` runs the batched network and argmax through ``torch.compile`` (a few seconds once).
    """

    def __init__(self, network: StackedQNetwork | StackedConvQNetwork, num_actions: int, epsilon: float,
                 in_key: str = "observation", action_key: str = "action", compile: bool = False) -> None:
        super().__init__()
        if not 0.0 <= epsilon <= 1.0:
            raise ValueError(f"epsilon={epsilon} must lie in [0, 1]")
        self.in_keys = network_in_keys(network, in_key)
        self.out_keys = [action_key]
        self.network = network
        self.num_actions = num_actions
        self.epsilon = epsilon
        self._params: dict[str, Tensor] = {}
        self.keys: Tensor | None = None
        self.steps = torch.zeros((), dtype=torch.int64)
        self._greedy = compiled(self._greedy_actions) if compile else self._greedy_actions

    def load(self, snapshots: Sequence[dict[str, Tensor]], seeds: Sequence[Sequence[int]]) -> None:
        """Act with ``snapshots`` (from :func:`parameter_snapshot` of the stacked network), group ``(g, k)``
        drawing from ``seeds[g][k]``; the noise streams start afresh."""
        members = self.network.num_members
        if not snapshots or len(snapshots) != len(seeds) or any(len(s) != members for s in seeds):
            raise ValueError(f"need {members} seeds per snapshot and at least one snapshot, got {len(snapshots)} "
                             f"snapshots and seeds {[list(s) for s in seeds]}")
        stacked = {name: torch.stack([s[name] for s in snapshots]) for name in snapshots[0]}
        self._params = self.network.in_layer_dtypes(stacked)
        device = next(iter(self._params.values())).device
        self.keys = rng.seed_keys([int(s) for group in seeds for s in group], rng.Purpose.EVALUATION, device)
        self.steps = torch.zeros((), dtype=torch.int64, device=device)

    def _values(self, params: dict[str, Tensor], *inputs: Tensor) -> Tensor:
        out = torch.func.functional_call(self.network, params, inputs)
        return out[0] if isinstance(out, tuple) else out  # the ADFQ network returns (mean, log_sd)

    def _greedy_actions(self, params: dict[str, Tensor], *grouped: Tensor) -> Tensor:
        """``[G, P, E]`` argmax actions of snapshot ``g`` on its members' groups (``grouped``: ``[G, P, E, ...]``
        per in_key).

        ``torch.vmap`` over the snapshots rather than one forward of ``G * P`` members, which was 7 % faster in
        a training run's evaluations (bfloat16 inner layers) but rounds differently (5e-8 in
        float32), so that a near tie could flip an action: evaluation scores are results, and float32 runs
        reproduce earlier commits' to the digit."""
        return torch.func.vmap(self._values)(params, *grouped).argmax(-1)

    def forward(self, tensordict: TensorDictBase) -> TensorDictBase:
        """Write each group's action (int64, shape = batch shape) under ``action_key``."""
        if self.keys is None:
            raise RuntimeError("SnapshotPolicy has no snapshots: call load() first")
        obs = tensordict.get(self.in_keys[0])
        groups = self.keys.shape[0]
        if obs.shape[0] % groups:
            raise ValueError(f"a batch of {obs.shape[0]} worlds does not split into {groups} equal groups")
        members = self.network.num_members
        grouped = [value.reshape(groups // members, members, -1, *value.shape[1:])
                   for value in (tensordict.get(key) for key in self.in_keys)]
        with torch.no_grad():
            action = self._greedy(self._params, *grouped).reshape(groups, -1)
        if exploring():
            worlds = action.shape[-1]
            counter = self.steps.expand(groups)
            draws = rng.ExplorationStream
            explore = rng.uniform(self.keys, counter, draws.EXPLORE, worlds, torch.float64) < self.epsilon
            random = (rng.uniform(self.keys, counter, draws.RANDOM, worlds, torch.float64) * self.num_actions)
            action = torch.where(explore, random.long(), action)
            self.steps += 1
        return tensordict.set(self.out_keys[0], action.reshape(obs.shape[0]))
