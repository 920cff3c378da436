"""TargetCache: the ADFQ targets it keeps per replay row are the loss's own, to the bit, through target copies;
a run with the cache trains exactly as one that computes every sampled transition's target."""

from __future__ import annotations

import pytest
import torch
from hydra import compose, initialize_config_module
from torchrl.objectives import HardUpdate

import aia.training.population as population
import aia.training.target_cache as target_cache
from aia.envs import make_env
from aia.modules.q_networks import make_qvalue_actor
from aia.training import train_population
from aia.training.components import make_loss, make_stacked_network
from aia.training.optimizer import StackedAdam, Updater
from aia.training.replay import MemberReplay
from aia.training.target_cache import TargetCache, _chunks


def _config(*overrides: str):
    with initialize_config_module(config_module="aia.conf", version_base="1.3"):
        return compose(config_name="train", overrides=list(overrides))


def _targets_of(loss, batch) -> tuple[torch.Tensor, torch.Tensor]:
    """The loss's own targets of a sampled batch (the cached entries left out)."""
    return loss.target_posterior(batch.exclude(loss.tensor_keys.target_mean, loss.tensor_keys.target_var))


@pytest.mark.parametrize("rows, members, expected", [
    (1000, 10, [(0, 125), (125, 250), (250, 375), (375, 500), (500, 625), (625, 750), (750, 875), (875, 1000)]),
    (1000, 1, [(0, 1000)]),
    (1000, 3, [(0, 416), (416, 832), (584, 1000)]),  # the last overlaps its predecessor: one size
    (24, 2, [(0, 24)]),
    (6, 1000, [(0, 4), (2, 6)]),  # at least 4 rows (_MIN_WRITTEN)
])
def test_refresh_chunks_have_one_size_and_cover_the_rows(rows, members, expected):
    assert [(chunk.start, chunk.stop) for chunk in _chunks(rows, members)] == expected


def test_the_network_takes_larger_chunks_than_the_posterior():
    network = [(chunk.start, chunk.stop) for chunk in _chunks(1000, 40, target_cache._NETWORK_CHUNK_TRANSITIONS)]
    assert network == [(0, 250), (250, 500), (500, 750), (750, 1000)] and len(_chunks(1000, 40)) == 33


@pytest.mark.parametrize("inner_dtype, chunk_transitions, written", [("float32", None, 1), ("bfloat16", 20, 1),
                                                                    ("float32", None, 5)])
def test_sampled_targets_are_the_losss_own_through_writes_and_target_copies(monkeypatch, inner_dtype,
                                                                          chunk_transitions, written):
    if chunk_transitions:  # the refresh in chunks of 10 rows (0-10, 10-20, 14-24)
        monkeypatch.setattr(target_cache, "_CHUNK_TRANSITIONS", chunk_transitions)
    cfgs = [_config("algo=adfq", "hidden=[32,32]", f"inner_dtype={inner_dtype}", f"seed={s}") for s in (0, 1)]
    torch.manual_seed(0)  # the rollout's random actions
    env = make_env("empty1", batch_size=2, seed=0)
    rollout = env.rollout(40).transpose(0, 1)  # [T, P] transitions, random actions
    network = make_stacked_network(cfgs, env.observation_spec["observation"].shape[-1], env.action_spec.n)
    loss = make_loss(cfgs, make_qvalue_actor(network, env.action_spec, adfq=True))
    replay = MemberReplay(capacity=24, batch_size=16, seeds=[0, 1])
    cache = TargetCache(loss, network, replay)  # compiled: test_training_with_the_cache_is_training_without_it
    target_updater = HardUpdate(loss, value_network_update_interval=3)
    optimizer = StackedAdam(list(loss.value_network_params.values(True, True)), [1e-2, 1e-2])
    update = Updater(loss, optimizer, target_updater, 10.0, on_target_copy=cache.invalidate)
    own_rows = []  # per refresh, the rows whose s the network ran on (every other row's s is another row's s')
    network_rows = cache._network_rows

    def counted_network_rows(observations, rows, slot):
        if slot == 0:
            own_rows.append(len(observations[0]))
        network_rows(observations, rows, slot)

    monkeypatch.setattr(cache, "_network_rows", counted_network_rows)
    transitions = rollout.select(*loss.in_keys)
    replay.extend(transitions[:10])
    copies = updates = 0
    for t in range(10, 40, written):  # written transitions per step (the buffer wraps at 24), then an update
        rows = replay.extend(transitions[t:t + written])
        cache.record(transitions[t:t + written], rows)
        copies += not cache.fresh
        if not cache.fresh:
            cache.refresh()
        batch = replay.sample()
        mean, var = _targets_of(loss, batch)
        assert torch.equal(batch["target_mean"], mean) and torch.equal(batch["target_var"], var)
        update(batch)
        updates += 1
    assert copies == 1 + (updates - 1) // 4  # the first refresh, then after every copy (every 4th update)
    # one world per member, no episode's start in the buffer: only the oldest row's s is no other row's s'
    assert own_rows == [1] * copies


def test_a_stale_cache_records_nothing_and_an_empty_buffer_cannot_refresh():
    cfgs = [_config("algo=adfq", "hidden=[16]", "seed=0")]
    env = make_env("empty1", batch_size=1, seed=0)
    network = make_stacked_network(cfgs, env.observation_spec["observation"].shape[-1], env.action_spec.n)
    loss = make_loss(cfgs, make_qvalue_actor(network, env.action_spec, adfq=True))
    replay = MemberReplay(capacity=8, batch_size=4, seeds=[0])
    cache = TargetCache(loss, network, replay)
    with pytest.raises(RuntimeError, match="empty"):
        cache.refresh()
    transitions = env.rollout(3).select(*loss.in_keys).transpose(0, 1)  # [T, P = 1]
    cache.record(transitions, replay.extend(transitions))  # stale: computes nothing
    assert not cache.fresh and "target_mean" not in replay.sample().keys()  # noqa: SIM118
    cache.refresh()
    assert cache.fresh and "target_mean" in replay.sample().keys()  # noqa: SIM118
    cache.invalidate()
    assert not cache.fresh


@pytest.mark.parametrize("method, compile, setting", [
    ("adfq_egreedy", False, ("frames=260",)), ("adfq_ts", True, ("frames=260",)),
    ("adfq_ts", False, ("frames=160", "env=ttenv_v4", "env.features.im_size=8", "conv_layers=[[2,3,2]]")),
], ids=["egreedy", "thompson-compiled-update", "conv-map-observation"])
def test_training_with_the_cache_is_training_without_it_bit_for_bit(tmp_path, monkeypatch, method, compile, setting):
    # compile: the update and the cache's refresh and writes compiled (compile.update, which the cache follows); a
    # compiled env and acting policy would collect the same transitions for both runs. Compiling them too, the test
    # took 105 s in a suite run from a cold compile cache (a fresh venv: the CI's) against 15 s warm; without them,
    # 61 s cold on its own
    switches = [f"compile.update={str(compile).lower()}", "compile.env=false", "compile.policy=false"]
    overrides = ("env.max_steps=40", "warmup_frames=100", "eval.episodes=2", "batch_size=16",
                 "hidden=[32,32]", "buffer_size=64", "target_update_interval=20", "logger=none", *switches, *setting)
    cfgs = [_config(*overrides, f"method={method}", f"seed={s}") for s in (3, 4)]
    monkeypatch.setattr(target_cache, "_CHUNK_TRANSITIONS", 50)  # the refresh in chunks of 25 rows, overlapping
    monkeypatch.setattr(target_cache, "_NETWORK_CHUNK_TRANSITIONS", 50)  # its network's too


    def final_parameters(name: str) -> list[dict[str, torch.Tensor]]:
        dirs = [tmp_path / name / str(k) for k in range(2)]
        train_population(cfgs, dirs)
        return [torch.load(d / "checkpoints" / "last.pt", weights_only=False)["online"] for d in dirs]

    cached = final_parameters("cached")
    monkeypatch.setattr(population, "TargetCache", lambda *args, **kwargs: None)  # every sampled target computed
    computed = final_parameters("computed")
    for a, b in zip(cached, computed, strict=True):
        assert a.keys() == b.keys() and all(torch.equal(a[name], b[name]) for name in a)
