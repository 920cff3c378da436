"""aia.training.components: the loss's value estimator keeps its buffers on the run's device from the start."""

from __future__ import annotations

import pytest
from hydra import compose, initialize_config_module

from aia.envs import make_env
from aia.modules.q_networks import make_qvalue_actor
from aia.training.components import make_loss, make_stacked_network


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
