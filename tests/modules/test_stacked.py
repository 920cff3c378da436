"""StackedQNetwork: P networks as one module, member k computing exactly what network k computes."""

from __future__ import annotations

import copy

import pytest
import torch
from torch import nn

from aia.modules import ADFQNetwork, StackedQNetwork, make_q_network


def _mlps(count: int, hidden=(16, 16), activation: str = "relu", first_seed: int = 0) -> list[nn.Module]:
    networks = []
    for k in range(count):
        torch.manual_seed(first_seed + k)
        networks.append(make_q_network(8, 12, hidden, activation))
    return networks


def _adfqs(count: int, first_seed: int = 0) -> list[ADFQNetwork]:
    networks = []
    for k in range(count):
        torch.manual_seed(first_seed + k)
        network = ADFQNetwork(8, 5, hidden=(16,))
        with torch.no_grad():  # break the init's constant head, and push some log sds past both bounds
            network.mlp[-1].weight.normal_()
            network.mlp[-1].bias[5:] = torch.tensor([-100.0, 100.0, 0.5, -2.0, 3.0]) * (k + 1)
        networks.append(network)
    return networks


@pytest.mark.parametrize("batch", [(), (5,), (2, 3)])
def test_forward_is_each_members_own_forward(batch):
    networks = _mlps(3)
    stacked = StackedQNetwork.stack(networks)
    assert stacked.num_members == 3 and stacked.log_sd_bounds is None
    obs = torch.randn(3, *batch, 8, generator=torch.Generator().manual_seed(1))
    out = stacked(obs)
    assert out.shape == (3, *batch, 12)
    for k, network in enumerate(networks):
        torch.testing.assert_close(out[k], network(obs[k]))
    # the members are different networks (the test would pass trivially otherwise)
    assert not torch.allclose(out[0], out[1])


def test_adfq_forward_is_each_members_mean_and_clamped_log_sd():
    networks = _adfqs(2)
    stacked = StackedQNetwork.stack(networks)
    assert stacked.log_sd_bounds == (networks[0].log_sd_min, networks[0].log_sd_max)
    obs = torch.randn(2, 4, 8, generator=torch.Generator().manual_seed(2))
    mean, log_sd = stacked(obs)
    assert mean.shape == log_sd.shape == (2, 4, 5)
    for k, network in enumerate(networks):
        own_mean, own_log_sd = network(obs[k])
        torch.testing.assert_close(mean[k], own_mean)
        torch.testing.assert_close(log_sd[k], own_log_sd)
    # both bounds are met: action 0's log sd is clamped below, action 1's above
    assert torch.all(log_sd[..., 0] == networks[0].log_sd_min)
    assert torch.all(log_sd[..., 1] == networks[0].log_sd_max)
    assert (log_sd[..., 2:] > networks[0].log_sd_min).all() and (log_sd[..., 2:] < networks[0].log_sd_max).all()


def test_gradients_of_the_summed_outputs_are_each_members_own_gradients():
    networks = _mlps(2, hidden=(8,))
    stacked = StackedQNetwork.stack(networks)
    obs = torch.randn(2, 6, 8, generator=torch.Generator().manual_seed(3))
    (stacked(obs) ** 2).sum().backward()
    for k, network in enumerate(networks):
        (network(obs[k]) ** 2).sum().backward()
        torch.testing.assert_close(stacked.weight0.grad[k], network[0].weight.grad.t())
        torch.testing.assert_close(stacked.bias1.grad[k, 0], network[-1].bias.grad)


def test_bfloat16_inner_layers_round_only_the_matmuls_between_hidden_layers():
    networks = _mlps(2, hidden=(16, 16, 16))
    exact, rounded = StackedQNetwork.stack(networks), StackedQNetwork.stack(networks, torch.bfloat16)
    obs = torch.randn(2, 6, 8, generator=torch.Generator().manual_seed(4))
    out = rounded(obs)
    assert out.dtype == torch.float32 and not torch.equal(out, exact(obs))  # rounded, so not the same bits
    torch.testing.assert_close(out, exact(obs), rtol=0.05, atol=0.05)  # but about the same values
    # the first layer alone is exact: with one hidden layer there is no inner matmul to round
    one_hidden = _mlps(2, hidden=(16,))
    torch.testing.assert_close(StackedQNetwork.stack(one_hidden, torch.bfloat16)(obs),
                               StackedQNetwork.stack(one_hidden)(obs), rtol=0, atol=0)
    (out ** 2).sum().backward()  # parameters and their gradients stay float32
    assert all(p.dtype == p.grad.dtype == torch.float32 for p in rounded.parameters())
    assert rounded.weight1.grad.abs().sum() > 0


@pytest.mark.parametrize("adfq", [False, True])
def test_stack_then_unstack_into_is_exact(adfq):
    sources = _adfqs(3) if adfq else _mlps(3)
    stacked = StackedQNetwork.stack(sources)
    targets = _adfqs(3, first_seed=10) if adfq else _mlps(3, first_seed=10)
    for k, (source, target) in enumerate(zip(sources, targets, strict=True)):
        assert stacked.unstack_into(k, target) is target
        for (name, want), got in zip(source.named_parameters(), target.parameters(), strict=True):
            assert torch.equal(got, want), name
    # stack copies: changing a source afterwards leaves the stacked network as it was
    before = {name: param.clone() for name, param in stacked.named_parameters()}
    with torch.no_grad():
        for param in sources[0].parameters():
            param.add_(1.0)
    assert all(torch.equal(param, before[name]) for name, param in stacked.named_parameters())


def test_load_member_changes_only_that_member():
    stacked = StackedQNetwork.stack(_mlps(3))
    before = {name: param.detach().clone() for name, param in stacked.named_parameters()}
    (replacement,) = _mlps(1, first_seed=20)
    stacked.load_member(1, replacement)
    for name, param in stacked.named_parameters():
        assert torch.equal(param[0], before[name][0]) and torch.equal(param[2], before[name][2]), name
        assert not torch.equal(param[1], before[name][1]), name
    obs = torch.randn(3, 4, 8, generator=torch.Generator().manual_seed(4))
    torch.testing.assert_close(stacked(obs)[1], replacement(obs[1]))
    check = stacked.unstack_into(1, _mlps(1, first_seed=30)[0])
    assert all(torch.equal(a, b) for a, b in zip(check.parameters(), replacement.parameters(), strict=True))


def test_mismatched_architectures_are_refused_with_a_message():
    with pytest.raises(ValueError, match="differ in architecture"):
        StackedQNetwork.stack(_mlps(1) + _mlps(1, hidden=(16, 32)))
    with pytest.raises(ValueError, match="differ in architecture"):
        StackedQNetwork.stack(_mlps(1) + _mlps(1, activation="tanh"))
    with pytest.raises(ValueError, match="differ in architecture"):
        StackedQNetwork.stack(_mlps(1) + _adfqs(1))
    # same layer shapes, another kind (an MLP of 2A outputs beside ADFQ networks of A actions) or sd bounds
    adfq = _adfqs(1)[0]
    plain = nn.Sequential(*[copy.deepcopy(layer) for layer in adfq.mlp])
    with pytest.raises(ValueError, match="differ in kind or sd bounds"):
        StackedQNetwork.stack([adfq, plain])
    other_bounds = copy.deepcopy(adfq)
    other_bounds.log_sd_max = 1.0
    with pytest.raises(ValueError, match="differ in kind or sd bounds"):
        StackedQNetwork.stack([adfq, other_bounds])
    with pytest.raises(TypeError, match="alternating Linear layers"):
        StackedQNetwork.stack([nn.Sequential(nn.Linear(8, 4), nn.ReLU(), nn.Tanh(), nn.Linear(4, 2))])
    with pytest.raises(ValueError, match="one bias per weight"):
        StackedQNetwork([torch.zeros(1, 2, 2)], [], nn.ReLU)
