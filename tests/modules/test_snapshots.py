"""SnapshotPolicy: each group of worlds acts like the single-snapshot epsilon-greedy policy on its own."""

from __future__ import annotations

import copy

import pytest
import torch
from tensordict import TensorDict
from tensordict.nn import TensorDictSequential
from torchrl.data import Categorical
from torchrl.envs.utils import ExplorationType, set_exploration_type

from aia.modules import (
    ADFQNetwork,
    EpsilonGreedy,
    SnapshotPolicy,
    make_q_network,
    make_qvalue_actor,
    parameter_snapshot,
)


def _perturbed(network: torch.nn.Module, seed: int) -> torch.nn.Module:
    other = copy.deepcopy(network)
    generator = torch.Generator().manual_seed(seed)
    with torch.no_grad():
        for param in other.parameters():
            param.add_(torch.randn(param.shape, generator=generator))
    return other


def test_each_group_acts_like_its_snapshot_with_epsilon_greedy_alone():
    torch.manual_seed(0)
    networks = [make_q_network(8, 12, (16, 16))]
    networks += [_perturbed(networks[0], seed) for seed in (1, 2)]
    policy = SnapshotPolicy(networks[0], 12, epsilon=0.3)
    policy.load([parameter_snapshot(n) for n in networks], seeds=[10, 11, 12])
    alone = [TensorDictSequential(make_qvalue_actor(n, Categorical(12)), EpsilonGreedy(12, 0.3, 0.3, 1, seed=s))
             for n, s in zip(networks, (10, 11, 12), strict=True)]
    explored = 0
    for step in range(20):
        obs = torch.randn(3, 4, 8, generator=torch.Generator().manual_seed(step))
        action = policy(TensorDict(observation=obs.reshape(12, 8), batch_size=[12]))["action"]
        assert action.dtype == torch.int64 and action.shape == (12,)
        for k in range(3):
            expected = alone[k](TensorDict(observation=obs[k], batch_size=[4]))["action"]
            assert torch.equal(action[4 * k:4 * (k + 1)], expected)
            explored += int((expected != networks[k](obs[k]).argmax(-1)).sum())
    assert explored > 0  # the random draws did replace greedy actions


def test_greedy_without_exploration_and_on_adfq_means():
    torch.manual_seed(1)
    network = ADFQNetwork(8, 12, (16,))
    with torch.no_grad():
        network.mlp[-1].weight.normal_()  # break the initial exact ties
    other = _perturbed(network, 3)
    policy = SnapshotPolicy(network, 12, epsilon=1.0)
    policy.load([parameter_snapshot(network), parameter_snapshot(other)], seeds=[0, 1])
    obs = torch.randn(6, 8)
    with set_exploration_type(ExplorationType.DETERMINISTIC):
        action = policy(TensorDict(observation=obs, batch_size=[6]))["action"]
    assert torch.equal(action[:3], network(obs[:3])[0].argmax(-1))
    assert torch.equal(action[3:], other(obs[3:])[0].argmax(-1))
    assert not torch.equal(network(obs)[0].argmax(-1), other(obs)[0].argmax(-1))  # the snapshots matter


def test_compiled_snapshot_policy_chooses_the_eager_actions():
    torch.manual_seed(2)
    network = make_q_network(8, 12, (16, 16))
    snapshots = [parameter_snapshot(network), parameter_snapshot(_perturbed(network, 5))]
    eager, compiled = SnapshotPolicy(network, 12, 0.3), SnapshotPolicy(network, 12, 0.3, compile=True)
    eager.load(snapshots, seeds=[1, 2])
    compiled.load(snapshots, seeds=[1, 2])
    for step in range(5):
        obs = torch.randn(8, 8, generator=torch.Generator().manual_seed(step))
        assert torch.equal(compiled(TensorDict(observation=obs, batch_size=[8]))["action"],
                           eager(TensorDict(observation=obs, batch_size=[8]))["action"])


def test_snapshots_are_copies():
    network = make_q_network(4, 3, (8,))
    snapshot = parameter_snapshot(network)
    with torch.no_grad():
        for param in network.parameters():
            param.add_(1.0)
    assert all(not torch.equal(snapshot[name], param) for name, param in network.named_parameters())


def test_bad_use_is_named():
    network = make_q_network(4, 3, (8,))
    with pytest.raises(ValueError, match=r"epsilon=1.5 must lie in \[0, 1\]"):
        SnapshotPolicy(network, 3, epsilon=1.5)
    policy = SnapshotPolicy(network, 3, epsilon=0.1)
    with pytest.raises(RuntimeError, match="call load"):
        policy(TensorDict(observation=torch.zeros(2, 4), batch_size=[2]))
    with pytest.raises(ValueError, match="one seed per snapshot"):
        policy.load([parameter_snapshot(network)], seeds=[1, 2])
    policy.load([parameter_snapshot(network)] * 2, seeds=[1, 2])
    with pytest.raises(ValueError, match="3 worlds does not split into 2 equal groups"):
        policy(TensorDict(observation=torch.zeros(3, 4), batch_size=[3]))
