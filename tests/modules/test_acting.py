"""ExploringQPolicy: the same actions as the composed TorchRL policy (actor, then exploration)."""

from __future__ import annotations

import pytest
import torch
from tensordict import TensorDict
from tensordict.nn import TensorDictSequential
from torchrl.data import Categorical
from torchrl.envs.utils import ExplorationType, set_exploration_type

from aia.modules import ADFQNetwork, EpsilonGreedy, ExploringQPolicy, ThompsonSampling, make_q_network
from aia.modules.q_networks import make_qvalue_actor


def _networks_and_explorations():
    torch.manual_seed(0)
    adfq = ADFQNetwork(8, 12, (16,))
    with torch.no_grad():
        adfq.mlp[-1].weight.normal_()
    return [
        (make_q_network(8, 12, (16,)), False, lambda: EpsilonGreedy(12, 0.4, 0.4, 1, seed=3)),
        (adfq, True, lambda: EpsilonGreedy(12, 0.4, 0.4, 1, seed=3)),
        (adfq, True, lambda: ThompsonSampling(seed=3)),
    ]


@pytest.mark.parametrize("case", range(3), ids=["dqn-egreedy", "adfq-egreedy", "adfq-thompson"])
@pytest.mark.parametrize("mode", [None, ExplorationType.DETERMINISTIC])
def test_same_actions_as_the_composed_policy(case, mode):
    network, adfq, exploration = _networks_and_explorations()[case]
    composed = TensorDictSequential(make_qvalue_actor(network, Categorical(12), adfq=adfq), exploration())
    lean = ExploringQPolicy(network, exploration())
    differs_from_greedy = 0
    with set_exploration_type(mode):
        for step in range(30):
            obs = torch.randn(5, 8, generator=torch.Generator().manual_seed(step))
            expected = composed(TensorDict(observation=obs, batch_size=[5]))["action"]
            action = lean(TensorDict(observation=obs, batch_size=[5]))["action"]
            assert action.dtype == torch.int64 and torch.equal(action, expected)
            greedy = (network(obs)[0] if adfq else network(obs)).argmax(-1)
            differs_from_greedy += int((action != greedy).sum())
    assert (differs_from_greedy > 0) == (mode is None)  # exploring only when the type is unset


def test_thompson_sampling_needs_the_adfq_network():
    with pytest.raises(TypeError, match="ADFQ network"):
        ExploringQPolicy(make_q_network(8, 12, (4,)), ThompsonSampling())(
            TensorDict(observation=torch.zeros(1, 8), batch_size=[1]))
    with pytest.raises(TypeError, match="EpsilonGreedy or ThompsonSampling"):
        ExploringQPolicy(make_q_network(8, 12, (4,)), torch.nn.Identity())
