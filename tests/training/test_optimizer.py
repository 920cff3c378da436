"""aia.training.optimizer: one member's step is torch's backward, clip_grad_norm_ and Adam bit for bit;
members never mix (own clipping norm, own learning rate); compiled equals eager."""

from __future__ import annotations

import pytest
import torch
from hydra import compose, initialize_config_module
from torchrl.objectives import HardUpdate

import aia.training.optimizer as optimizer_module
from aia.envs import make_env
from aia.modules.q_networks import make_qvalue_actor
from aia.training.components import make_loss, make_stacked_network
from aia.training.optimizer import StackedAdam, Updater, update_step


def _config(*overrides: str):
    with initialize_config_module(config_module="aia.conf", version_base="1.3"):
        return compose(config_name="train", overrides=list(overrides))


def _setup(algo: str, seeds: tuple[int, ...], lrs: tuple[float, ...] | None = None, clip: float = 10.0):
    """A stacked loss of ``len(seeds)`` members, its Updater, and 3 batches ``[P, 16]`` of seeded transitions
    (member k's batch is the same whatever the other members are)."""
    cfgs = [_config(f"algo={algo}", "hidden=[32,32]", f"seed={s}") for s in seeds]
    torch.manual_seed(0)  # the rollout's random actions
    env = make_env("empty1", batch_size=16, seed=0)
    rollout = env.rollout(3)  # random actions
    network = make_stacked_network(cfgs, env.observation_spec["observation"].shape[-1], env.action_spec.n)
    loss = make_loss(cfgs, make_qvalue_actor(network, env.action_spec, adfq=algo == "adfq"))
    params = list(loss.value_network_params.values(True, True))
    optimizer = StackedAdam(params, list(lrs or [cfgs[0].lr] * len(seeds)))
    target_updater = HardUpdate(loss, value_network_update_interval=2)
    batches = [rollout[:, i].unsqueeze(0).expand(len(seeds), 16).clone() for i in range(3)]
    return loss, optimizer, target_updater, batches, clip


def _run(setup, compile: bool, updates: int = 6, falls_back: bool = False) -> tuple[torch.Tensor, list[torch.Tensor]]:
    loss, optimizer, target_updater, batches, clip = setup
    update = Updater(loss, optimizer, target_updater, clip, compile)
    losses = torch.stack([update(batches[i % 3].clone()) for i in range(updates)])
    assert (update._step is update_step) == (not compile or falls_back)  # compiled unless it fell back to eager
    return losses, [p.detach().clone() for p in optimizer.params]


@pytest.mark.parametrize("algo", ["dqn", "ddqn", "adfq"])
def test_one_member_is_backward_clip_grad_norm_and_torch_adam_bit_for_bit(algo):
    loss, optimizer, target_updater, batches, clip = setup = _setup(algo, (0,))
    reference = [p.detach().clone().requires_grad_(True) for p in optimizer.params]
    losses, params = _run(setup, compile=False)

    # the same steps by torch's own pieces, on copies of the initial parameters
    loss2, optimizer2, target2, _, _ = _setup(algo, (0,))
    adam = torch.optim.Adam(optimizer2.params, lr=optimizer2.lrs[0].item())
    reference_losses = []
    for i in range(6):
        out = loss2(batches[i % 3].clone())["loss"].mean()
        adam.zero_grad()
        out.backward()
        torch.nn.utils.clip_grad_norm_(optimizer2.params, clip)
        adam.step()
        target2.step()
        reference_losses.append(out.detach())
    assert torch.equal(losses[:, 0], torch.stack(reference_losses))
    assert all(torch.equal(p, q) for p, q in zip(params, optimizer2.params, strict=True))
    assert not torch.equal(params[0], reference[0])  # the updates changed the network


@pytest.mark.parametrize("algo", ["dqn", "adfq"])
def test_a_member_updates_as_it_would_alone_and_its_neighbours_rate_changes_nothing(algo):
    # tiny clip: every member's step is clipped, by its own norm
    alone_losses, alone_params = _run(_setup(algo, (1,), lrs=(1e-3,), clip=0.5), compile=False)
    for lrs in ((1e-3, 1e-3, 1e-3), (3e-2, 1e-3, 1e-4)):
        losses, params = _run(_setup(algo, (0, 1, 2), lrs=lrs, clip=0.5), compile=False)
        torch.testing.assert_close(losses[:, 1], alone_losses[:, 0], rtol=1e-6, atol=0)
        for p, q in zip(params, alone_params, strict=True):
            torch.testing.assert_close(p[1], q[0], rtol=1e-6, atol=1e-9)
    _, fast = _run(_setup(algo, (0, 1, 2), lrs=(3e-2, 1e-3, 1e-4)), compile=False)
    _, slow = _run(_setup(algo, (0, 1, 2), lrs=(1e-4, 1e-3, 1e-4)), compile=False)
    assert all(torch.equal(p[1:], q[1:]) for p, q in zip(fast, slow, strict=True))  # bit for bit
    assert not torch.equal(fast[0][0], slow[0][0])


@pytest.mark.parametrize("algo", ["dqn", "adfq"])
def test_compiled_update_gives_the_eager_losses_and_parameters(algo):
    eager_losses, eager_params = _run(_setup(algo, (0, 1), lrs=(1e-3, 5e-4)), compile=False)
    torch._dynamo.utils.counters.clear()
    losses, params = _run(_setup(algo, (0, 1), lrs=(1e-3, 5e-4)), compile=True)
    # two graphs (the gradients; Adam), no graph break: the backward is traced into the first, not left to the
    # autograd engine (25 % of a 3 x 256 ADFQ step), and no graph is traced twice to place a break
    assert not torch._dynamo.utils.counters["graph_break"], dict(torch._dynamo.utils.counters["graph_break"])
    assert torch._dynamo.utils.counters["stats"]["unique_graphs"] == 2
    torch.testing.assert_close(losses, eager_losses, rtol=1e-5, atol=1e-5)
    for p, q in zip(params, eager_params, strict=True):
        torch.testing.assert_close(p, q, rtol=1e-5, atol=1e-5)


def test_an_update_step_inductor_cannot_compile_runs_eager_and_says_so(monkeypatch, capsys):
    # torch 2.13's CPU inductor fails on the step of 2+ members of the paper's networks (pytorch#196570)
    from torch._inductor.exc import InductorError

    def failing_compile(fn):
        def compiled(*args):
            raise InductorError(KeyError("buf54"), None)
        return compiled

    eager_losses, eager_params = _run(_setup("dqn", (0, 1)), compile=False)
    monkeypatch.setattr(optimizer_module, "compiled_update", failing_compile)
    losses, params = _run(_setup("dqn", (0, 1)), compile=True, falls_back=True)
    assert torch.equal(losses, eager_losses) and all(map(torch.equal, params, eager_params))
    lines = capsys.readouterr().err.strip().splitlines()
    assert lines == ["compile.update: torch.compile could not compile the update step (KeyError: 'buf54'); it runs "
                     "eager"]


def test_on_target_copy_is_called_after_each_hard_target_copy():
    loss, optimizer, target_updater, batches, clip = _setup("adfq", (0, 1))  # a copy every 3rd update
    copied = []
    update = Updater(loss, optimizer, target_updater, clip, on_target_copy=lambda: copied.append(True))
    for i in range(9):
        before = list(loss.target_value_network_params.clone().values(True, True))
        update(batches[i % 3].clone())
        after = loss.target_value_network_params.values(True, True)
        changed = not all(torch.equal(a, b) for a, b in zip(before, after, strict=True))
        assert (len(copied) == i // 3 + (i % 3 == 2)) and changed == (i % 3 == 2)


def test_stacked_adam_needs_one_positive_rate_per_member():
    params = [torch.zeros(2, 3)]
    with pytest.raises(ValueError, match="one learning rate per member"):
        StackedAdam(params, [1e-3])
    with pytest.raises(ValueError, match=r"must be > 0, got \[0.001, -1.0\]"):
        StackedAdam(params, [1e-3, -1.0])
