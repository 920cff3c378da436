"""TD(0) targets for a population whose members are each DQN or Double DQN (one flag per member).

TorchRL's ``DQNLoss`` takes ``double_dqn`` for the whole module. Both algorithms share the network and the
loss and differ only in the next action of the target: the target network's own argmax (DQN) or the online
network's (Double DQN). :class:`MemberwiseDoubleTD0` is a ``TD0Estimator`` whose next-state value picks, member
by member, one of the two; given to a ``DQNLoss(double_dqn=False)`` it makes that loss train a mixed population
(one program for ``method=dqn,ddqn``). A member's target is the one its own algorithm's ``DQNLoss`` computes.
"""

from __future__ import annotations

from collections.abc import Sequence

import torch
from tensordict import TensorDictBase
from torch import Tensor
from torchrl.envs.utils import step_mdp
from torchrl.objectives import DQNLoss
from torchrl.objectives.value import TD0Estimator


class MemberwiseDoubleTD0(TD0Estimator):
    """TD(0) targets of a ``[P, B]`` batch for ``loss`` (a ``DQNLoss`` with ``double_dqn=False`` on stacked
    networks) where member ``k`` uses Double DQN's next action if ``double[k]``, DQN's otherwise.

    Costs one more forward of the online network on the Double DQN members' next observations (what Double DQN
    costs anyway); the DQN members skip it. Use :func:`use_memberwise_double` to install it.
    """

    def __init__(self, loss: DQNLoss, double: Sequence[bool], gamma: float,
                 device: torch.device | str | None = None) -> None:
        super().__init__(gamma=gamma, value_network=loss.value_network, device=device)
        # a tuple: the online parameters are the loss's, not a submodule of this estimator
        self._online = (loss.value_network_params,)
        # the Double DQN members' indices: only their slices of the online network see the next observations
        self.register_buffer("double_members", torch.tensor([k for k, d in enumerate(double) if d], dtype=torch.long,
                                                            device=device))
        self._action_key = loss.tensor_keys.action
        self._action_value_key = loss.tensor_keys.action_value

    def _next_value(self, tensordict: TensorDictBase, target_params, kwargs) -> Tensor:
        """``[P, B, 1]``: the target network's value of each member's next action."""
        step_td = step_mdp(tensordict, keep_other=False)
        members = self.double_members
        online_td = step_td[members]  # a copy, taken before the target network writes into step_td
        with target_params.to_module(self.value_network, preserve_module_state=False):
            self.value_network(step_td)
        online_params = self._online[0].data.apply(lambda p: p.index_select(0, members))
        with online_params.to_module(self.value_network, preserve_module_state=False):
            self.value_network(online_td)
        target_values = step_td.get(self._action_value_key)
        own = step_td.get(self.tensor_keys.value)  # DQN: the target network's chosen (greedy) action's value
        online_action = online_td.get(self._action_key)
        if online_action.ndim != target_values.ndim:
            online_action = online_action.unsqueeze(-1)
        # Double DQN: the target network's value of the online network's action
        double = torch.gather(target_values.index_select(0, members), -1, online_action)
        return own.index_copy(0, members, double)


def use_memberwise_double(loss: DQNLoss, double: Sequence[bool], gamma: float,
                          device: torch.device | str | None = None) -> DQNLoss:
    """``loss`` (``double_dqn=False``, ``delay_value=True``) with :class:`MemberwiseDoubleTD0` as its value
    estimator (its buffers on ``device``), its keys set as ``DQNLoss.make_value_estimator`` sets them."""
    if loss.double_dqn or not loss.delay_value:
        raise ValueError("a memberwise Double DQN target needs DQNLoss(double_dqn=False, delay_value=True)")
    loss.make_value_estimator(MemberwiseDoubleTD0(loss, double, gamma, device))
    keys = loss.tensor_keys
    loss.value_estimator.set_keys(value=keys.value, reward=keys.reward, done=keys.done, terminated=keys.terminated,
                                  advantage=keys.advantage, value_target=keys.value_target)
    return loss
