"""``SnapshotPolicy``: saved parameter sets of one Q-network, each acting on its own group of worlds.

The training loop evaluates the policy after every few training episodes. Instead of one small rollout per
evaluation it keeps a copy of the network's parameters at each evaluation point and later plays several of
them in one batched rollout: world group ``k`` of the batch acts with snapshot ``k`` (``torch.func.vmap``
over the stacked parameters, one network call for all groups) and draws its epsilon-greedy noise from its
own ``torch.Generator``, so what a group does never depends on the other groups.
"""

from __future__ import annotations

from collections.abc import Sequence

import torch
from tensordict import TensorDictBase
from tensordict.nn import TensorDictModuleBase
from torch import Tensor, nn

from aia.compiling import compiled
from aia.modules.exploration import exploring


def parameter_snapshot(network: nn.Module) -> dict[str, Tensor]:
    """A detached copy of ``network``'s parameters, by name."""
    return {name: param.detach().clone() for name, param in network.named_parameters()}


class SnapshotPolicy(TensorDictModuleBase):
    """Epsilon-greedy actions of ``G`` parameter snapshots of ``network``, one per group of worlds.

    :meth:`load` sets the snapshots and one generator seed per snapshot. The batch ``[G * E]`` is read as
    ``G`` consecutive groups of ``E`` worlds; group ``k`` takes the argmax of ``network`` under snapshot
    ``k`` (for an ADFQ network, of its means) and, while exploring (as :class:`~aia.modules.EpsilonGreedy`:
    exploration type ``RANDOM`` or unset), replaces it by a uniform random action with probability
    ``epsilon``, drawing first ``E`` uniforms and then ``E`` random actions from generator ``k`` at every
    step, exactly as an :class:`~aia.modules.EpsilonGreedy` seeded alike would on those ``E`` worlds alone.
    ``compile=True`` runs the batched network and argmax through ``torch.compile`` (a few seconds once).
    """

    def __init__(self, network: nn.Module, num_actions: int, epsilon: float, in_key: str = "observation",
                 action_key: str = "action", compile: bool = False) -> None:
        super().__init__()
        if not 0.0 <= epsilon <= 1.0:
            raise ValueError(f"epsilon={epsilon} must lie in [0, 1]")
        self.in_keys = [in_key]
        self.out_keys = [action_key]
        self.network = network
        self.num_actions = num_actions
        self.epsilon = epsilon
        self._params: dict[str, Tensor] = {}
        self.generators: list[torch.Generator] = []
        self._greedy = compiled(self._greedy_actions) if compile else self._greedy_actions

    def load(self, snapshots: Sequence[dict[str, Tensor]], seeds: Sequence[int]) -> None:
        """Act with ``snapshots`` (from :func:`parameter_snapshot`), group ``k`` drawing from ``seeds[k]``."""
        if not snapshots or len(snapshots) != len(seeds):
            raise ValueError(f"need one seed per snapshot and at least one snapshot, got {len(snapshots)} "
                             f"snapshots and {len(seeds)} seeds")
        self._params = {name: torch.stack([s[name] for s in snapshots]) for name in snapshots[0]}
        device = next(iter(self._params.values())).device
        self.generators = [torch.Generator(device=device).manual_seed(int(seed)) for seed in seeds]

    def _values(self, params: dict[str, Tensor], obs: Tensor) -> Tensor:
        out = torch.func.functional_call(self.network, params, (obs,))
        return out[0] if isinstance(out, tuple) else out  # the ADFQ network returns (mean, log_sd)

    def _greedy_actions(self, params: dict[str, Tensor], grouped: Tensor) -> Tensor:
        """``[G, E]`` argmax actions of snapshot ``k`` on group ``k`` (``grouped``: ``[G, E, ...]``)."""
        return torch.func.vmap(self._values)(params, grouped).argmax(-1)

    def forward(self, tensordict: TensorDictBase) -> TensorDictBase:
        """Write each group's action (int64, shape = batch shape) under ``action_key``."""
        if not self.generators:
            raise RuntimeError("SnapshotPolicy has no snapshots: call load() first")
        obs = tensordict.get(self.in_keys[0])
        groups = len(self.generators)
        if obs.shape[0] % groups:
            raise ValueError(f"a batch of {obs.shape[0]} worlds does not split into {groups} equal groups")
        grouped = obs.reshape(groups, obs.shape[0] // groups, *obs.shape[1:])
        with torch.no_grad():
            action = self._greedy(self._params, grouped)
        if exploring():
            shape = action.shape[1:]
            explore, random = [], []
            for gen in self.generators:
                explore.append(torch.rand(shape, generator=gen, device=gen.device) < self.epsilon)
                random.append(torch.randint(0, self.num_actions, shape, generator=gen, device=gen.device))
            action = torch.where(torch.stack(explore).to(action.device), torch.stack(random).to(action), action)
        return tensordict.set(self.out_keys[0], action.reshape(obs.shape[0]))
