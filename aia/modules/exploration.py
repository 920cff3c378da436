"""Exploration for the Q-value policies: a linear epsilon schedule, batched epsilon-greedy and the config check.

:class:`EpsilonGreedy` follows TorchRL's ``EGreedyModule`` convention: it comes after the greedy actor in a
``TensorDictSequential``, overwrites ``action``, and acts only when the exploration type is ``RANDOM`` or unset
(``None``, the default, e.g. inside ``env.rollout``). Under ``set_exploration_type(DETERMINISTIC)`` it
leaves the greedy action untouched. It owns a ``torch.Generator`` seeded at construction, so its
exploration noise is reproducible and independent of the global torch RNG. ``chosen_action_value`` written
by ``QValueModule`` still refers to the greedy action afterwards (as with TorchRL's ``EGreedyModule``).
ADFQ's Thompson sampling is done by :class:`~aia.modules.PopulationQPolicy`.
"""

from __future__ import annotations

import torch
from tensordict import TensorDictBase
from tensordict.nn import TensorDictModuleBase
from torch import Tensor
from torchrl.envs.utils import ExplorationType, exploration_type

ALGORITHMS = ("dqn", "ddqn", "adfq")
EXPLORATIONS = ("egreedy", "thompson")


def exploring() -> bool:
    """Whether exploration acts now: exploration type ``RANDOM`` or unset (TorchRL's convention)."""
    return exploration_type() in (ExplorationType.RANDOM, None)


class LinearEpsilon:
    """Epsilon annealed linearly from ``eps_init`` to ``eps_end`` over ``annealing_frames``, then constant."""

    def __init__(self, eps_init: float = 1.0, eps_end: float = 0.01, annealing_frames: int = 10_000) -> None:
        if annealing_frames <= 0:
            raise ValueError(f"annealing_frames must be positive, got {annealing_frames}")
        self.eps_init = eps_init
        self.eps_end = eps_end
        self.annealing_frames = annealing_frames

    def value(self, frames: int) -> float:
        """Epsilon after ``frames`` environment frames."""
        fraction = min(max(frames, 0) / self.annealing_frames, 1.0)
        return self.eps_init + fraction * (self.eps_end - self.eps_init)


class EpsilonGreedy(TensorDictModuleBase):
    """Replaces each world's ``action`` by a uniform random one with probability ``epsilon``.

    One batched draw per call (no per-world loop), for any leading batch shape. ``step(frames)`` advances
    the :class:`LinearEpsilon` schedule like TorchRL's ``EGreedyModule.step``; ``epsilon`` is a plain
    attribute that may also be set directly, e.g. to 0.05 for evaluation (a later ``step`` overwrites it).
    """

    def __init__(
        self,
        num_actions: int,
        eps_init: float = 1.0,
        eps_end: float = 0.01,
        annealing_frames: int = 10_000,
        seed: int = 0,
        action_key: str = "action",
        device: torch.device | str = "cpu",
    ) -> None:
        super().__init__()
        self.in_keys = [action_key]
        self.out_keys = [action_key]
        self.num_actions = num_actions
        self.schedule = LinearEpsilon(eps_init, eps_end, annealing_frames)
        self.frames = 0
        self.epsilon = self.schedule.value(0)
        self.generator = torch.Generator(device=device).manual_seed(seed)

    def step(self, frames: int = 1) -> None:
        """Advance the schedule by ``frames`` environment frames and update ``epsilon``."""
        self.frames += frames
        self.epsilon = self.schedule.value(self.frames)

    def forward(self, tensordict: TensorDictBase) -> TensorDictBase:
        """Overwrite ``action`` where a uniform draw falls below ``epsilon`` (only when exploring)."""
        if not exploring():
            return tensordict
        key = self.in_keys[0]
        return tensordict.set(key, self.explore(tensordict.get(key)))

    def explore(self, action: Tensor) -> Tensor:
        """``action`` with each entry replaced by a uniform random one with probability ``epsilon``."""
        gen = self.generator
        explore = torch.rand(action.shape, generator=gen, device=gen.device) < self.epsilon
        random = torch.randint(0, self.num_actions, action.shape, generator=gen, device=gen.device)
        return torch.where(explore.to(action.device), random.to(action), action)


def check_exploration(algo: str, exploration: str) -> None:
    """Raise ``ValueError`` for an unknown algorithm or exploration, or Thompson sampling without ADFQ."""
    if algo not in ALGORITHMS:
        raise ValueError(f"algo must be one of {ALGORITHMS}, got {algo!r}")
    if exploration not in EXPLORATIONS:
        raise ValueError(f"exploration must be one of {EXPLORATIONS}, got {exploration!r}")
    if exploration == "thompson" and algo != "adfq":
        raise ValueError(
            f"exploration={exploration!r} needs the per-action sds of algo='adfq', got algo={algo!r}; "
            "use exploration='egreedy' with dqn/ddqn"
        )
