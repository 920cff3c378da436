"""SnapshotPolicy: world group (g, k) acts as snapshot g's member k would alone, with its own noise."""

from __future__ import annotations

import pytest
import torch
from tensordict import TensorDict
from torchrl.envs.utils import ExplorationType, set_exploration_type

from aia.modules import ADFQNetwork, SnapshotPolicy, StackedQNetwork, make_q_network, parameter_snapshot

A = 12


def _stacked(members: int, adfq: bool = False, seed: int = 0) -> StackedQNetwork:
    networks = []
    for k in range(members):
        torch.manual_seed(seed + k)
        network = ADFQNetwork(8, A, (16,)) if adfq else make_q_network(8, A, (16, 16))
        if adfq:
            with torch.no_grad():  # break the initial exact ties
                network.mlp[-1].weight.normal_()
        networks.append(network)
    return StackedQNetwork.stack(networks)


def _snapshots(network: StackedQNetwork, count: int) -> list[dict[str, torch.Tensor]]:
    """``count`` snapshots: the network's parameters, then perturbed copies."""
    base = parameter_snapshot(network)
    generator = torch.Generator().manual_seed(99)
    return [base] + [{name: p + torch.randn(p.shape, generator=generator) for name, p in base.items()}
                     for _ in range(count - 1)]


def _member(snapshot: dict[str, torch.Tensor], k: int) -> dict[str, torch.Tensor]:
    """Member ``k`` of a snapshot, as the snapshot of a one-member stacked network."""
    return {name: p[k:k + 1].clone() for name, p in snapshot.items()}


def _act(policy: SnapshotPolicy, obs: torch.Tensor) -> torch.Tensor:
    return policy(TensorDict(observation=obs, batch_size=obs.shape[:1]))["action"]


def test_each_group_acts_as_its_snapshot_and_member_alone():
    G, P, E = 3, 2, 4
    network = _stacked(P)
    snapshots = _snapshots(network, G)
    seeds = [[10, 11], [12, 13], [14, 15]]
    policy = SnapshotPolicy(network, A, epsilon=0.3)
    policy.load(snapshots, seeds)
    alone = {}
    for g in range(G):
        for k in range(P):
            alone[g, k] = SnapshotPolicy(_stacked(1, seed=50), A, epsilon=0.3)
            alone[g, k].load([_member(snapshots[g], k)], [[seeds[g][k]]])
    explored = 0
    for step in range(15):
        obs = torch.randn(G, P, E, 8, generator=torch.Generator().manual_seed(step))
        action = _act(policy, obs.reshape(G * P * E, 8)).reshape(G, P, E)
        for (g, k), solo in alone.items():
            expected = _act(solo, obs[g, k])
            assert torch.equal(action[g, k], expected), (step, g, k)
            greedy = torch.func.functional_call(network, snapshots[g], (obs[g],))[k].argmax(-1)
            explored += int((expected != greedy).sum())
    assert int(policy.steps) == 15
    assert 0 < explored < G * P * E * 15  # the random draws replaced some greedy actions, not all


def test_greedy_on_adfq_means_without_exploration():
    G, P, E = 2, 2, 3
    network = _stacked(P, adfq=True)
    snapshots = _snapshots(network, G)
    policy = SnapshotPolicy(network, A, epsilon=1.0)
    policy.load(snapshots, [[0, 1], [2, 3]])
    obs = torch.randn(G, P, E, 8, generator=torch.Generator().manual_seed(5))
    with set_exploration_type(ExplorationType.DETERMINISTIC):
        action = _act(policy, obs.reshape(-1, 8)).reshape(G, P, E)
    assert int(policy.steps) == 0
    means = [torch.func.functional_call(network, snapshot, (obs[g],))[0] for g, snapshot in enumerate(snapshots)]
    for g in range(G):
        assert torch.equal(action[g], means[g].argmax(-1))
    assert not torch.equal(means[0].argmax(-1), means[1].argmax(-1))  # the snapshots matter
    assert not torch.equal(_act(policy, obs.reshape(-1, 8)).reshape(G, P, E), action)  # epsilon 1 explores


def test_compiled_snapshot_policy_chooses_the_eager_actions():
    network = _stacked(2, seed=2)
    snapshots = _snapshots(network, 2)
    eager, compiled = SnapshotPolicy(network, A, 0.3), SnapshotPolicy(network, A, 0.3, compile=True)
    eager.load(snapshots, [[1, 2], [3, 4]])
    compiled.load(snapshots, [[1, 2], [3, 4]])
    for step in range(4):
        obs = torch.randn(8, 8, generator=torch.Generator().manual_seed(step))
        assert torch.equal(_act(compiled, obs), _act(eager, obs))


def test_a_bfloat16_network_s_snapshots_act_on_weights_cast_once_as_the_network_itself():
    networks = []
    for k in range(2):
        torch.manual_seed(k)
        networks.append(make_q_network(8, A, (16, 16, 16)))
    network = StackedQNetwork.stack(networks, inner_dtype=torch.bfloat16)
    policy = SnapshotPolicy(network, A, epsilon=0.0)
    policy.load([parameter_snapshot(network)], [[0, 1]])
    # loaded in the dtype each layer multiplies in: the inner layers' weights are cast once, not every step
    assert [policy._params[f"weight{i}"].dtype for i in range(4)] == [torch.float32, torch.bfloat16,
                                                                        torch.bfloat16, torch.float32]
    obs = torch.randn(2, 64, 8, generator=torch.Generator().manual_seed(3))
    with set_exploration_type(ExplorationType.DETERMINISTIC):
        action = _act(policy, obs.reshape(-1, 8)).reshape(2, 64)
    assert torch.equal(action, network(obs).argmax(-1))  # bit for bit: the same casts, made earlier


def test_load_restarts_the_noise_streams():
    network = _stacked(1)
    policy = SnapshotPolicy(network, A, epsilon=0.5)
    obs = torch.randn(200, 8, generator=torch.Generator().manual_seed(0))
    policy.load(_snapshots(network, 1), [[7]])
    first = [_act(policy, obs) for _ in range(3)]
    assert not torch.equal(first[0], first[1])
    policy.load(_snapshots(network, 1), [[7]])
    assert all(torch.equal(_act(policy, obs), action) for action in first)


def test_snapshots_are_copies():
    network = _stacked(2)
    snapshot = parameter_snapshot(network)
    with torch.no_grad():
        for param in network.parameters():
            param.add_(1.0)
    assert all(not torch.equal(snapshot[name], param) for name, param in network.named_parameters())


def test_bad_use_is_named():
    network = _stacked(2)
    with pytest.raises(ValueError, match=r"epsilon=1.5 must lie in \[0, 1\]"):
        SnapshotPolicy(network, A, epsilon=1.5)
    policy = SnapshotPolicy(network, A, epsilon=0.1)
    with pytest.raises(RuntimeError, match="call load"):
        _act(policy, torch.zeros(4, 8))
    snapshot = parameter_snapshot(network)
    with pytest.raises(ValueError, match=r"need 2 seeds per snapshot.*1 snapshots and seeds \[\[1, 2, 3\]\]"):
        policy.load([snapshot], [[1, 2, 3]])
    with pytest.raises(ValueError, match="2 snapshots and seeds"):
        policy.load([snapshot, snapshot], [[1, 2]])
    with pytest.raises(ValueError, match="at least one snapshot"):
        policy.load([], [])
    policy.load([snapshot] * 2, [[1, 2], [3, 4]])
    with pytest.raises(ValueError, match="6 worlds does not split into 4 equal groups"):
        _act(policy, torch.zeros(6, 8))
