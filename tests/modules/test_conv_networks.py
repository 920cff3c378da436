"""ConvQNetwork (a conv torso over the map image, the MLP or ADFQ head over its features and the belief
features) and StackedConvQNetwork: member k computes what the solo network with its seed computes."""

from __future__ import annotations

import pytest
import torch

from aia.config.errors import ConfigError
from aia.modules import ADFQNetwork, ConvQNetwork, ConvTorso, StackedConvQNetwork, make_q_network
from aia.modules.q_networks import same_padding

OBS, ACTIONS = 8, 5


def _network(seed: int, adfq: bool = False, channels: int = 1, im_size: int = 12,
             layers=((2, 4, 2), (3, 3, 2))) -> ConvQNetwork:
    """The solo network under ``torch.manual_seed(seed)``, torso first (as the training's make_network)."""
    torch.manual_seed(seed)
    torso = ConvTorso(channels, im_size, layers)
    width = torso.out_features + OBS
    head = ADFQNetwork(width, ACTIONS, hidden=(16,)) if adfq else make_q_network(width, ACTIONS, (16, 16))
    return ConvQNetwork(torso, head)


def _inputs(members: int, batch: tuple[int, ...], channels: int = 1, im_size: int = 12, seed: int = 0):
    generator = torch.Generator().manual_seed(seed)
    return (torch.randn(members, *batch, OBS, generator=generator),
            torch.randn(members, *batch, channels, im_size, im_size, generator=generator))


def test_the_authors_torso_and_tensorflows_same_padding():
    torso = ConvTorso(1, 28)  # ttenv v4: 28 x 28 -> 4 x 7 x 7 -> 8 x 4 x 4
    assert [(c.in_channels, c.out_channels, c.kernel_size, c.stride, pad) for c, pad in torso.convolutions()] == [
        (1, 4, (8, 8), (4, 4), (2, 2, 2, 2)), (4, 8, (4, 4), (2, 2), (1, 2, 1, 2))]
    assert torso.out_features == 128
    assert torso(torch.zeros(2, 1, 28, 28)).shape == (2, 8, 4, 4)
    assert ConvTorso(5, 28).out_features == 128  # ttenv v5: 5 channels, the same image size
    # TensorFlow's SAME: output ceil(size / stride), the odd cell of padding after
    assert same_padding(28, 8, 4) == (2, 2, 7) and same_padding(7, 4, 2) == (1, 2, 4)
    assert same_padding(5, 1, 3) == (0, 0, 2)


@pytest.mark.parametrize("adfq", [False, True])
@pytest.mark.parametrize("batch", [(), (3,), (2, 3)])
def test_solo_shapes(adfq, batch):
    network = _network(0, adfq, channels=2)
    observation, local_map = (x[0] for x in _inputs(1, batch, channels=2))
    out = network(observation, local_map)
    for value in out if adfq else (out,):
        assert value.shape == (*batch, ACTIONS)


@pytest.mark.parametrize("adfq", [False, True])
@pytest.mark.parametrize("channels", [1, 5])
def test_member_k_is_the_solo_network_with_its_seed(adfq, channels):
    networks = [_network(seed, adfq, channels) for seed in (3, 7, 11)]
    stacked = StackedConvQNetwork.stack(networks)
    assert stacked.num_members == 3 and stacked.in_keys == ("observation", "local_map")
    observation, local_map = _inputs(3, (2, 4), channels)
    out = stacked(observation, local_map)
    for k, network in enumerate(networks):
        # the same parameters to the bit as the seed's own network
        solo = _network((3, 7, 11)[k], adfq, channels)
        assert all(torch.equal(a, b) for a, b in zip(network.parameters(), solo.parameters(), strict=True))
        own = network(observation[k], local_map[k])
        if adfq:  # at initialisation the head is constant: exactly the solo outputs
            assert torch.equal(out[0][k], own[0]) and torch.equal(out[1][k], own[1])
        else:
            assert out[k].shape == (2, 4, ACTIONS)
            torch.testing.assert_close(out[k], own, rtol=1e-6, atol=1e-6)
    if not adfq:
        assert not torch.allclose(out[0], out[1])  # different members (else the test would pass trivially)


@pytest.mark.parametrize("adfq", [False, True])
def test_adam_steps_on_per_member_losses_are_each_members_own(adfq):
    seeds = (0, 1)
    networks = [_network(seed, adfq) for seed in seeds]
    stacked = StackedConvQNetwork.stack(networks)
    optimizer = torch.optim.Adam(stacked.parameters(), lr=1e-2)  # elementwise: member k's step uses its grads
    solos = [(network, torch.optim.Adam(network.parameters(), lr=1e-2)) for network in networks]

    def loss(out):  # a per-member loss that reaches both ADFQ heads
        return sum(value.square().mean(-1) for value in out) if adfq else out.square().mean(-1)

    for step in range(4):
        observation, local_map = _inputs(2, (6,), seed=step)
        optimizer.zero_grad()
        loss(stacked(observation, local_map)).mean(-1).sum().backward()
        optimizer.step()
        for k, (network, solo_optimizer) in enumerate(solos):
            solo_optimizer.zero_grad()
            loss(network(observation[k], local_map[k])).mean().backward()
            solo_optimizer.step()
    for k, (network, _) in enumerate(solos):
        check = stacked.unstack_into(k, _network(50, adfq))
        for (name, want), got in zip(network.named_parameters(), check.parameters(), strict=True):
            torch.testing.assert_close(got, want, rtol=1e-5, atol=1e-5, msg=name)
        assert not torch.equal(check.torso[1].weight, _network(seeds[k], adfq).torso[1].weight)  # it learned


def test_unstack_into_and_load_member_are_exact_and_touch_only_that_member():
    networks = [_network(seed, adfq=True) for seed in range(3)]
    stacked = StackedConvQNetwork.stack(networks)
    for k, network in enumerate(networks):
        copy = stacked.unstack_into(k, _network(20, adfq=True))
        assert all(torch.equal(a, b) for a, b in zip(copy.parameters(), network.parameters(), strict=True))
    before = {name: param.detach().clone() for name, param in stacked.named_parameters()}
    replacement = _network(30, adfq=True)
    with torch.no_grad():
        replacement.head.mlp[-1].weight.normal_()
    stacked.load_member(1, replacement)
    for name, param in stacked.named_parameters():
        assert torch.equal(param[0], before[name][0]) and torch.equal(param[2], before[name][2]), name
    observation, local_map = _inputs(3, (4,))
    torch.testing.assert_close(stacked(observation, local_map)[0][1], replacement(observation[1], local_map[1])[0])


def test_in_layer_dtypes_casts_only_the_heads_inner_layers():
    stacked = StackedConvQNetwork.stack([_network(0)], inner_dtype=torch.bfloat16)
    params = dict(stacked.named_parameters())
    cast = stacked.in_layer_dtypes(params)
    assert set(cast) == set(params)
    assert cast["conv_weight0"] is params["conv_weight0"] and cast["head.weight0"].dtype == torch.float32
    assert cast["head.weight1"].dtype == torch.bfloat16


def test_bad_input_is_one_config_error_line():
    for kwargs, text in (({"channels": 0, "im_size": 28}, "local_map.channels=0: expected an integer >= 1"),
                         ({"channels": 1, "im_size": 0}, "local_map.im_size=0: expected an integer >= 1"),
                         ({"channels": 1, "im_size": 28, "layers": [[4, 0, 4]]}, "conv_layers=[[4, 0, 4]]")):
        with pytest.raises(ConfigError) as error:
            ConvTorso(**kwargs)
        assert str(error.value).startswith(text) and "\n" not in str(error.value)


def test_mismatched_members_are_refused():
    with pytest.raises(ValueError, match="conv torsos differ"):
        StackedConvQNetwork.stack([_network(0), _network(1, channels=2)])
    with pytest.raises(ValueError, match="differ in architecture"):  # the heads (StackedQNetwork's check)
        StackedConvQNetwork.stack([_network(0), _network(1, im_size=13, layers=((2, 4, 2), (3, 3, 3)))])
    with pytest.raises(ValueError, match="a bias, a padding and a stride per convolution"):
        StackedConvQNetwork([torch.zeros(1, 2, 1, 3, 3)], [], [(0, 0, 0, 0)], [1], torch.nn.ReLU,
                            StackedConvQNetwork.stack([_network(0)]).head)
