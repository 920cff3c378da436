"""aia.training.components: the loss's value estimator keeps its buffers on the run's device from the start; a
map observation gets the conv networks."""

from __future__ import annotations

import pytest
import torch
from hydra import compose, initialize_config_module
from torchrl.data import Categorical, Unbounded
from torchrl.envs import Transform
from torchrl.objectives import HardUpdate

from aia.envs import make_env
from aia.modules import ConvQNetwork, StackedConvQNetwork
from aia.modules.q_networks import make_qvalue_actor
from aia.training.components import make_actor, make_loss, make_stacked_network, map_shape
from aia.training.optimizer import StackedAdam, Updater


@pytest.mark.parametrize("methods", [("dqn",), ("ddqn",), ("dqn", "ddqn")])
def test_value_estimator_buffers_on_the_run_device(methods: tuple[str, ...]) -> None:
    """TorchRL would make ``gamma`` on the CPU and move it at the first call (a compiled update then compiles
    twice on a GPU): every buffer of the estimator is on ``cfg.device`` when the loss is made. The network is
    made on the CPU and the device named ``meta``, so that a buffer left on the CPU shows on a CPU machine."""
    with initialize_config_module(config_module="aia.conf", version_base="1.3"):
        cfgs = [compose(config_name="train", overrides=[f"algo={m}", "hidden=[8]", f"seed={k}"])
                for k, m in enumerate(methods)]
    env = make_env("empty1", batch_size=1, seed=0)
    network = make_stacked_network(cfgs, env.observation_spec["observation"].shape[-1], env.action_spec.n)
    for cfg in cfgs:
        cfg.device = "meta"
    loss = make_loss(cfgs, make_qvalue_actor(network, env.action_spec))
    buffers = dict(loss.value_estimator.named_buffers(recurse=False))
    assert buffers.keys() == ({"gamma", "double_members"} if len(methods) > 1 else {"gamma"})
    assert {b.device.type for b in buffers.values()} == {"meta"}


class _FakeLocalMap(Transform):
    """A stand-in for the map observation (not yet emitted by the env): a ``local_map`` image ``[C, S, S]`` made
    from the observation's first feature."""

    CHANNELS, SIZE = 2, 6

    def __init__(self) -> None:
        super().__init__(in_keys=["observation"], out_keys=["local_map"])

    def _apply_transform(self, observation: torch.Tensor) -> torch.Tensor:
        shape = (*observation.shape[:-1], self.CHANNELS, self.SIZE, self.SIZE)
        return torch.tanh(observation[..., :1, None, None]).expand(shape).contiguous()

    def _reset(self, tensordict, tensordict_reset):
        return self._call(tensordict_reset)

    def transform_observation_spec(self, observation_spec):
        observation_spec["local_map"] = Unbounded((*observation_spec.shape, self.CHANNELS, self.SIZE, self.SIZE),
                                                  device=observation_spec.device)
        return observation_spec


def _map_configs(algo: str, seeds: tuple[int, ...]) -> list:
    with initialize_config_module(config_module="aia.conf", version_base="1.3"):
        return [compose(config_name="train", overrides=[f"algo={algo}", "hidden=[8]", "conv_layers=[[2,3,2],[3,2,1]]",
                                                        f"seed={seed}"]) for seed in seeds]


@pytest.mark.parametrize("algo", ["dqn", "adfq"])
def test_a_map_observation_gets_the_conv_network_and_member_k_is_the_solo_run(algo: str) -> None:
    """With a ``local_map`` key in the observation the actor and the population are conv networks; member k acts
    as the population of one with its seed (greedy actions before any update exact) and learns as it does
    (100 updates of DQN on the same batches: member 1's parameters to 1e-4)."""
    env = make_env("empty1", batch_size=3, seed=0)
    env.append_transform(_FakeLocalMap())
    cfgs = _map_configs(algo, (4, 9))
    actor = make_actor(cfgs[0], env)
    assert isinstance(actor[0].module, ConvQNetwork) and "local_map" in actor.in_keys
    rollout = env.rollout(4, actor)
    assert rollout["local_map"].shape == (3, 4, 2, 6, 6)

    obs_dim, shape = env.observation_spec["observation"].shape[-1], map_shape(env.observation_spec)
    assert shape == (2, 6, 6)
    population = make_stacked_network(cfgs, obs_dim, env.action_spec.n, shape)
    solos = [make_stacked_network([cfg], obs_dim, env.action_spec.n, shape) for cfg in cfgs]
    assert isinstance(population, StackedConvQNetwork) and population.num_members == 2
    frames = torch.stack([rollout, rollout.flip(0)])  # [P, worlds, steps]
    values = population(frames["observation"], frames["local_map"])
    values = values[0] if algo == "adfq" else values
    for k, solo in enumerate(solos):
        own = solo(frames["observation"][k:k + 1], frames["local_map"][k:k + 1])
        own = own[0] if algo == "adfq" else own
        assert torch.equal(values[k].argmax(-1), own[0].argmax(-1))
    if algo == "adfq":
        return  # ADFQ's loss is the MLP's on the network's outputs (tests/losses); its targets come from the loop
    update, update_solo = _updater(cfgs, population), _updater(cfgs[1:], solos[1])
    transitions = rollout[:, :-1].reshape(-1)  # 9 transitions with next states
    generator = torch.Generator().manual_seed(0)
    initial = population.conv_weight0[1].detach().clone()
    for _ in range(100):
        rows = torch.randint(len(transitions), (2, 5), generator=generator)
        batch = torch.stack([transitions[rows[0]], transitions[rows[1]]])
        batch["next", "reward"] = torch.randn(2, 5, 1, generator=generator)
        update(batch.clone())
        update_solo(batch[1:].clone())
    for name, param in solos[1].named_parameters():
        torch.testing.assert_close(param[0], population.get_parameter(name)[1], rtol=1e-4, atol=1e-4)
    assert not torch.equal(population.conv_weight0[1], initial)  # it learned


def _updater(cfgs: list, network) -> Updater:
    loss = make_loss(cfgs, make_qvalue_actor(network, Categorical(5)))
    optimizer = StackedAdam(list(loss.value_network_params.values(True, True)), [c.lr for c in cfgs])
    return Updater(loss, optimizer, HardUpdate(loss, value_network_update_interval=cfgs[0].target_update_interval),
                   cfgs[0].grad_clip)
