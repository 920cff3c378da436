"""Q-networks: shapes, parameter count, ADFQ initialisation and sd clipping, and the TorchRL actor chain."""

from __future__ import annotations

import math

import pytest
import torch
from tensordict.nn import TensorDictSequential

from aia.envs import make_env
from aia.modules import (
    ADFQNetwork,
    EpsilonGreedy,
    PopulationQPolicy,
    StackedQNetwork,
    make_q_network,
    make_qvalue_actor,
)


@pytest.mark.parametrize("obs_dim", [8, 20])
def test_network_output_shapes(obs_dim):
    torch.manual_seed(0)
    q = make_q_network(obs_dim, 12)
    adfq = ADFQNetwork(obs_dim, 12, hidden=(256, 256, 256))
    for batch in [(5,), (2, 3)]:
        obs = torch.randn(*batch, obs_dim)
        assert q(obs).shape == (*batch, 12)
        mean, log_sd = adfq(obs)
        assert mean.shape == log_sd.shape == (*batch, 12)


def test_parameter_count_3x128():
    q = make_q_network(8, 12, hidden=(128, 128, 128))
    expected = (8 * 128 + 128) + 2 * (128 * 128 + 128) + (128 * 12 + 12)  # = 35724
    assert sum(p.numel() for p in q.parameters()) == expected == 35724
    assert sum(isinstance(m, torch.nn.ReLU) for m in q.modules()) == 3


def test_unknown_activation_is_rejected():
    with pytest.raises(ValueError, match="activation"):
        make_q_network(8, 12, activation="gelu")


def test_adfq_init_gives_means_one_and_sds_ten():
    torch.manual_seed(0)
    net = ADFQNetwork(20, 12)
    mean, log_sd = net(10 * torch.randn(64, 20))
    torch.testing.assert_close(mean, torch.ones(64, 12))
    torch.testing.assert_close(log_sd.exp(), torch.full((64, 12), 10.0))


def test_adfq_log_sd_is_clipped_to_the_reference_bounds():
    net = ADFQNetwork(8, 12)
    head = net.mlp[-1]
    obs = torch.randn(3, 8)
    with torch.no_grad():
        head.bias[12:] = 100.0
    assert torch.allclose(net(obs)[1].exp(), torch.full((3, 12), 1e5), rtol=1e-5)
    with torch.no_grad():
        head.bias[12:] = -100.0
    assert torch.allclose(net(obs)[1].exp(), torch.full((3, 12), 1e-5), rtol=1e-5)
    # Inside the bounds the log sd passes through unchanged.
    with torch.no_grad():
        head.bias[12:] = torch.linspace(-5, 5, 12)
    torch.testing.assert_close(net(obs)[1], torch.linspace(-5, 5, 12).expand(3, 12))
    assert math.isclose(net.log_sd_min, math.log(1e-5)) and math.isclose(net.log_sd_max, math.log(1e5))


def _env_and_obs_dim():
    env = make_env("small2", batch_size=4, seed=0)
    return env, env.observation_spec["observation"].shape[-1]


def test_actor_writes_greedy_actions_and_chosen_values():
    torch.manual_seed(0)
    env, obs_dim = _env_and_obs_dim()
    actor = make_qvalue_actor(make_q_network(obs_dim, 12), env.action_spec)
    reset = env.reset()
    td = actor(reset.clone())
    action, values = td["action"], td["action_value"]
    assert action.shape == (4,) and action.dtype == torch.int64
    assert ((action >= 0) & (action < 12)).all()
    assert torch.equal(action, values.argmax(-1))
    torch.testing.assert_close(td["chosen_action_value"], values.gather(-1, action[:, None]))
    # An unbatched spec and the full composite spec give the same actor, and any batch shape works.
    for spec in (env.action_spec_unbatched, env.full_action_spec):
        other = make_qvalue_actor(actor[0].module, spec)
        assert torch.equal(other(reset.clone())["action"], action)
    stacked = torch.stack([td, td], dim=1)
    assert actor(stacked.exclude("action"))["action"].shape == (4, 2)


def test_adfq_actor_writes_mean_and_log_sd():
    env, obs_dim = _env_and_obs_dim()
    actor = make_qvalue_actor(ADFQNetwork(obs_dim, 12), env.action_spec, adfq=True)
    td = actor(env.reset())
    torch.testing.assert_close(td["action_value"], torch.ones(4, 12))
    torch.testing.assert_close(td["action_log_sd"], torch.full((4, 12), math.log(10.0)))
    assert torch.equal(td["action"], torch.zeros(4, dtype=torch.int64))  # exact ties at init


@pytest.mark.parametrize("kind", ["dqn", "adfq", "dqn+egreedy", "adfq+thompson"])
def test_rollout_with_actor(kind):
    torch.manual_seed(0)
    env, obs_dim = _env_and_obs_dim()
    if kind.startswith("adfq"):
        actor = make_qvalue_actor(ADFQNetwork(obs_dim, 12), env.action_spec, adfq=True)
    else:
        actor = make_qvalue_actor(make_q_network(obs_dim, 12), env.action_spec)
    if kind.endswith("egreedy"):
        actor = TensorDictSequential(actor, EpsilonGreedy(12, seed=0))
    elif kind.endswith("thompson"):  # a population of one ADFQ learner, Thompson sampling on its 4 worlds
        actor = PopulationQPolicy(StackedQNetwork.stack([ADFQNetwork(obs_dim, 12)]), 12, worlds_per_member=4,
                                  seeds=[0], thompson=True, eps_init=[0.0], eps_end=[0.0], annealing_frames=[1],
                                  warmup_frames=0)
    with torch.no_grad():
        traj = env.rollout(20, policy=actor, break_when_any_done=False)
    assert traj.batch_size == (4, 20)
    action = traj["action"]
    assert ((action >= 0) & (action < 12)).all()
    assert torch.isfinite(traj["next", "reward"]).all()
    if "+" in kind:  # exploration actually changes actions away from the greedy ones
        assert len(action.unique()) > 3


@pytest.mark.parametrize("adfq", [False, True])
def test_actor_writes_what_a_plain_tensordict_module_writes_without_a_module_search(monkeypatch, adfq):
    """The actor's value module skips tensordict's per-call ``find_spec("pandas")`` and writes the same."""
    import importlib.util

    from tensordict.nn import TensorDictModule

    torch.manual_seed(0)
    env = make_env("empty1", batch_size=4, seed=0)
    network = ADFQNetwork(8, 12, hidden=(16,)) if adfq else make_q_network(8, 12, hidden=(16,))
    actor = make_qvalue_actor(network, env.action_spec, adfq=adfq)
    value = actor[0]
    plain = TensorDictSequential(TensorDictModule(network, in_keys=value.in_keys, out_keys=value.out_keys), actor[1])
    td = env.reset()
    expected = plain(td.clone())

    def no_search(name, package=None):
        raise AssertionError(f"find_spec({name!r}) called")

    monkeypatch.setattr(importlib.util, "find_spec", no_search)
    out = actor(td.clone())
    assert set(out.keys(True, True)) == set(expected.keys(True, True))
    assert all(torch.equal(out[key], expected[key]) for key in expected.keys(True, True))
