"""``ExploringQPolicy``: the training-time policy of a Q-network in one module call.

``TensorDictSequential(make_qvalue_actor(network, ...), exploration)`` is the TorchRL way to write an
exploring Q-value policy, and the losses need that actor. Acting with it costs three modules' worth of
TensorDict bookkeeping per step, several times the network itself at the paper's one world per step. This
module runs the same computation directly on tensors: the network on ``observation``, the greedy argmax (or
Thompson sampling's argmax of a sampled value per action), then epsilon-greedy, with the exploration
module's own generator, so it draws exactly what the composed policy draws and chooses the same actions.
"""

from __future__ import annotations

import torch
from tensordict import TensorDictBase
from tensordict.nn import TensorDictModuleBase
from torch import nn

from aia.modules.exploration import EpsilonGreedy, ThompsonSampling, exploring


class ExploringQPolicy(TensorDictModuleBase):
    """``action`` (int64 index) from ``observation`` by ``network`` and ``exploration``, without gradients.

    ``network`` returns the Q-values, or for ADFQ ``(mean, log_sd)``; ``exploration`` is an
    :class:`~aia.modules.EpsilonGreedy` (any network) or a :class:`~aia.modules.ThompsonSampling` (ADFQ).
    Exploration acts only when the exploration type is ``RANDOM`` or unset, as in the composed policy;
    otherwise the action is greedy (on the means for ADFQ).
    """

    def __init__(self, network: nn.Module, exploration: EpsilonGreedy | ThompsonSampling,
                 in_key: str = "observation", action_key: str = "action") -> None:
        super().__init__()
        if not isinstance(exploration, EpsilonGreedy | ThompsonSampling):
            raise TypeError(f"exploration must be EpsilonGreedy or ThompsonSampling, got {type(exploration).__name__}")
        self.in_keys = [in_key]
        self.out_keys = [action_key]
        self.network = network
        self.exploration = exploration

    def forward(self, tensordict: TensorDictBase) -> TensorDictBase:
        """Write the chosen action of every world."""
        with torch.no_grad():
            out = self.network(tensordict.get(self.in_keys[0]))
        if isinstance(self.exploration, ThompsonSampling):
            if not isinstance(out, tuple):
                raise TypeError("Thompson sampling needs a network that returns (mean, log_sd): the ADFQ network")
            action = self.exploration.sample(*out).argmax(-1) if exploring() else out[0].argmax(-1)
        else:
            action = (out[0] if isinstance(out, tuple) else out).argmax(-1)
            if exploring():
                action = self.exploration.explore(action)
        return tensordict.set(self.out_keys[0], action)
