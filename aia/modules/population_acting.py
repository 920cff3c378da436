"""``PopulationQPolicy``: the collector's policy of ``P`` learners, each acting in its own worlds.

The collector steps one env of ``P * W`` worlds, member-major (member ``k`` owns worlds ``k W .. k W + W - 1``).
One call runs the :class:`~aia.modules.StackedQNetwork` on every member's observations and then each member's
exploration: uniformly random actions during its warm-up frames, then epsilon-greedy on its own linear
schedule, or ADFQ's Thompson sampling (``argmax_a q_a``, ``q_a ~ N(mean_a, sd_a^2)``), each member its own.

All draws are counter-based (:mod:`aia.rng`): a pure function of the member's seed, the policy's step
count and the world's slot, computed a block of steps at a time (:class:`~aia.rng.CounterStream`). So a
member draws the same numbers whatever the other members are (member ``k`` of a population acts exactly as a
population of one with its seed would), nothing but the step count is state (a checkpoint stores it), and no
draw needs a host sync on CUDA (the step count lives on the host, epsilon is computed on the device).
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


class PopulationQPolicy(TensorDictModuleBase):
    """``action`` for ``P * W`` worlds from ``observation`` (and ``local_map`` for a conv network), member by
    member, without gradients.

    Args:
        network: the members' stacked Q-network (ADFQ: it returns ``(mean, log_sd)``), an MLP on ``in_key`` or a
            :class:`~aia.modules.StackedConvQNetwork` on its own ``in_keys``.
        num_actions: size of the discrete action space.
        worlds_per_member: ``W``.
        seeds: one seed per member (its exploration stream).
        thompson: per member, Thompson sampling (ADFQ) instead of epsilon-greedy (one bool: every member's).
        eps_init, eps_end, annealing_frames: each member's linear epsilon schedule over its frames (unused by a
            member that samples).
        warmup_frames: frames of uniformly random actions at the start of each member's run.

    Exploration acts only when the exploration type is ``RANDOM`` or unset (TorchRL's convention); otherwise
    the action is greedy (on the means for ADFQ). :attr:`steps` counts the exploring calls.
    """

    def __init__(self, network: StackedQNetwork | StackedConvQNetwork, num_actions: int, worlds_per_member: int,
                 seeds: Sequence[int], thompson: bool | Sequence[bool], eps_init: Sequence[float],
                 eps_end: Sequence[float], annealing_frames: Sequence[int], warmup_frames: int,
                 in_key: str = "observation", action_key: str = "action") -> None:
        super().__init__()
        members = len(seeds)
        if network.num_members != members:
            raise ValueError(f"{members} seeds for a network of {network.num_members} members")
        samples = [bool(thompson)] * members if isinstance(thompson, bool) else [bool(t) for t in thompson]
        if len(samples) != members:
            raise ValueError(f"{len(samples)} exploration kinds for {members} members")
        if any(samples) and network.log_sd_bounds is None:
            raise TypeError("Thompson sampling needs a network that returns (mean, log_sd): the ADFQ network")
        self.in_keys = network_in_keys(network, in_key)
        self.out_keys = [action_key]
        self.network = network
        self.num_actions = num_actions
        self.worlds = worlds_per_member
        self.samples = samples  # which members explore by Thompson sampling
        self.warmup_frames = warmup_frames
        first = next(network.parameters())  # the networks' parameters share one device and dtype
        device = first.device
        self.keys = rng.seed_keys(list(seeds), rng.Purpose.ACTING, device)
        self._sampling = torch.tensor(samples, device=device).unsqueeze(-1)  # [P, 1]
        as_tensor = lambda values: torch.tensor(list(values), dtype=torch.float64, device=device)  # noqa: E731
        self.eps_init, self.eps_end = as_tensor(eps_init), as_tensor(eps_end)
        self.annealing_frames = as_tensor(annealing_frames)
        W, A = worlds_per_member, num_actions
        self._draws = {"explore": rng.CounterStream(rng.uniform, self.keys, rng.ExplorationStream.EXPLORE, W),
                       "random": rng.CounterStream(rng.uniform, self.keys, rng.ExplorationStream.RANDOM, W)}
        if any(samples):
            self._draws["thompson"] = rng.CounterStream(rng.normal, self.keys, rng.ExplorationStream.THOMPSON, W * A,
                                                        first.dtype)

    @property
    def steps(self) -> int:
        """Exploring calls so far: the counter of every draw of the next call (the streams advance together)."""
        return self._draws["explore"].counter

    @steps.setter
    def steps(self, value: int) -> None:
        for stream in self._draws.values():
            stream.counter = value

    @property
    def frames(self) -> int:
        """Frames each member has collected under exploration so far."""
        return self.steps * self.worlds

    @property
    def egreedy_members(self) -> list[int]:
        """The members that explore epsilon-greedily (the others sample)."""
        return [k for k, sampling in enumerate(self.samples) if not sampling]

    def epsilon(self) -> Tensor:
        """``[P]`` each member's epsilon now (its schedule at :attr:`frames`; a sampling member's is unused)."""
        fraction = (self.frames / self.annealing_frames).clamp(0.0, 1.0)
        return self.eps_init + fraction * (self.eps_end - self.eps_init)

    def forward(self, tensordict: TensorDictBase) -> TensorDictBase:
        """Write the chosen action of every world (int64, shape = the batch shape)."""
        obs = tensordict.get(self.in_keys[0])
        members, batch_dims = self.keys.shape[0], obs.dim() - 1
        grouped = [value.reshape(members, self.worlds, *value.shape[batch_dims:])
                   for value in (tensordict.get(key) for key in self.in_keys)]
        with torch.no_grad():
            out = self.network(*grouped)
        if not exploring():
            action = (out[0] if isinstance(out, tuple) else out).argmax(-1)
            return tensordict.set(self.out_keys[0], action.reshape(obs.shape[:-1]))
        action = self._explore(out)  # its draws advance the streams: one step
        return tensordict.set(self.out_keys[0], action.reshape(obs.shape[:-1]))

    def _explore(self, out: Tensor | tuple[Tensor, Tensor]) -> Tensor:
        """``[P, W]`` exploring actions of this step (the draws of counter :attr:`steps`)."""
        warm = self.frames < self.warmup_frames  # read before the draws advance the step count
        every_member_samples = all(self.samples)
        epsilon = None if every_member_samples or warm else self.epsilon()
        greedy = None if every_member_samples else (out[0] if isinstance(out, tuple) else out).argmax(-1)
        if any(self.samples):
            mean, log_sd = out
            noise = self._draws["thompson"].next().reshape(mean.shape)
            sampled = (mean + log_sd.exp() * noise).argmax(-1)
            action = sampled if greedy is None else torch.where(self._sampling, sampled, greedy)
        else:
            action = greedy
        explore, random = self._draws["explore"].next(), self._draws["random"].next()
        if warm:  # every action uniformly random
            return (random * self.num_actions).long()
        if epsilon is None:  # Thompson sampling explores by itself
            return action
        # a sampling member never takes the epsilon branch
        epsilon_greedy = (explore < epsilon.unsqueeze(-1)) & ~self._sampling
        return torch.where(epsilon_greedy, (random * self.num_actions).long(), action)
