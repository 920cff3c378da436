"""MemberReplay: each member replays only its own transitions, from its own seeded stream."""

from __future__ import annotations

import pytest
import torch
from tensordict import TensorDict

from aia.training.replay import MemberReplay


def _transitions(start: int, count: int, members: list[int]) -> TensorDict:
    """``[count, P]`` transitions; transition ``t`` of member ``k`` carries ``id = 1000 k + t``."""
    t = torch.arange(start, start + count).unsqueeze(-1)
    ids = 1000 * torch.tensor(members) + t
    return TensorDict(id=ids, observation=ids.unsqueeze(-1).float().expand(-1, -1, 3),
                      batch_size=[count, len(members)])


def _samples(replay: MemberReplay, count: int) -> torch.Tensor:
    return torch.stack([replay.sample()["id"].clone() for _ in range(count)])  # [count, P, batch]


def test_a_members_samples_depend_only_on_its_seed_and_its_own_rows():
    population = MemberReplay(capacity=50, batch_size=16, seeds=[1, 2, 3])
    others = MemberReplay(capacity=50, batch_size=16, seeds=[9, 2, 8])
    solo = MemberReplay(capacity=50, batch_size=16, seeds=[2])
    for replay, members in ((population, [0, 1, 2]), (others, [5, 1, 7]), (solo, [1])):
        replay.extend(_transitions(0, 30, members))
        replay.extend(_transitions(30, 10, members))
    assert len(population) == len(solo) == 40
    a, b, c = _samples(population, 5), _samples(others, 5), _samples(solo, 5)
    assert a.shape == (5, 3, 16)
    assert torch.equal(a[:, 1], c[:, 0]) and torch.equal(b[:, 1], c[:, 0])
    for k in range(3):  # every row a member draws is its own
        assert (a[:, k] // 1000 == k).all() and (a[:, k] % 1000 < 40).all()
    assert not torch.equal(a[:, 0] % 1000, a[:, 2] % 1000)  # the members' streams differ
    assert not torch.equal(a[0], a[1])  # and each batch is a fresh draw
    sample = population.sample()
    assert torch.equal(sample["observation"], sample["id"].unsqueeze(-1).float().expand(-1, -1, 3))


def test_draws_cover_the_rows_uniformly():
    replay = MemberReplay(capacity=10, batch_size=1000, seeds=[4])
    replay.extend(_transitions(0, 10, [0]))
    counts = torch.bincount(_samples(replay, 10).flatten(), minlength=10)
    assert counts.sum() == 10_000 and (counts > 900).all() and (counts < 1100).all()  # sd ~ 30


def test_fifo_overwrite_once_full():
    replay = MemberReplay(capacity=5, batch_size=200, seeds=[1, 2])
    replay.extend(_transitions(0, 3, [0, 1]))
    assert len(replay) == 3
    assert set(_samples(replay, 1)[:, 0].flatten().tolist()) == {0, 1, 2}
    replay.extend(_transitions(3, 4, [0, 1]))  # 7 transitions in 5 rows: 0 and 1 are overwritten
    assert len(replay) == 5
    drawn = _samples(replay, 2)
    assert set(drawn[:, 0].flatten().tolist()) == {2, 3, 4, 5, 6}
    assert set(drawn[:, 1].flatten().tolist()) == {1002, 1003, 1004, 1005, 1006}
    # the rows in storage order: 5 and 6 overwrote rows 0 and 1, the cursor is at row 2 (the oldest, 2)
    assert replay.member_state(1)["transitions"]["id"].tolist() == [1005, 1006, 1002, 1003, 1004]
    assert replay.member_state(1)["cursor"] == 2
    replay.extend(_transitions(7, 1, [0, 1]))
    assert replay.member_state(0)["transitions"]["id"].tolist() == [5, 6, 7, 3, 4]


@pytest.mark.parametrize("collected", [12, 27])  # 27 > 20: the buffer has wrapped around
def test_member_state_round_trip_gives_the_same_next_samples(collected):
    replay = MemberReplay(capacity=20, batch_size=8, seeds=[3, 4])
    replay.extend(_transitions(0, collected, [0, 1]))
    _samples(replay, 3)  # the sampler's count is part of the state
    states = [replay.member_state(k) for k in range(2)]
    assert [state["draws"] for state in states] == [3, 3]
    restored = MemberReplay(capacity=20, batch_size=8, seeds=[3, 4])
    for k, state in enumerate(states):
        restored.load_member_state(k, state)
    assert len(restored) == min(collected, 20)
    assert torch.equal(_samples(restored, 4), _samples(replay, 4))
    # and both go on alike after more transitions
    for buffer in (replay, restored):
        buffer.extend(_transitions(collected, 3, [0, 1]))
    assert torch.equal(_samples(restored, 2), _samples(replay, 2))
    assert torch.equal(restored.member_state(1)["transitions"]["id"], replay.member_state(1)["transitions"]["id"])


def test_empty_member_state_round_trip():
    state = MemberReplay(capacity=4, batch_size=2, seeds=[1]).member_state(0)
    assert state == {"transitions": None, "cursor": 0, "draws": 0}
    restored = MemberReplay(capacity=4, batch_size=2, seeds=[1])
    restored.load_member_state(0, state)
    assert len(restored) == 0


def test_keys_a_loss_writes_into_a_batch_do_not_reach_the_next_batch():
    # a changed key set makes a compiled update step recompile (a guard on the TensorDict's keys)
    replay = MemberReplay(capacity=4, batch_size=2, seeds=[1])
    replay.extend(_transitions(0, 4, [0]))
    batch = replay.sample()
    batch["td_error"] = torch.zeros(1, 2)
    assert set(replay.sample().keys()) == {"id", "observation"}


def test_attached_columns_are_sampled_with_their_rows_and_kept_out_of_checkpoints():
    replay = MemberReplay(capacity=6, batch_size=32, seeds=[1, 2])
    with pytest.raises(ValueError, match="columns shaped"):
        replay.attach(TensorDict(double=torch.zeros(6, 2), batch_size=[6, 2]))  # nothing stored yet
    rows = replay.extend(_transitions(0, 4, [0, 1]))
    assert rows.tolist() == [0, 1, 2, 3]
    with pytest.raises(ValueError, match=r"columns shaped \(5, 2\)"):
        replay.attach(TensorDict(double=torch.zeros(5, 2), batch_size=[5, 2]))
    columns = TensorDict(double=torch.zeros(6, 2, dtype=torch.int64), batch_size=[6, 2])
    replay.attach(columns)
    assert replay.extend(_transitions(4, 3, [0, 1])).tolist() == [4, 5, 0]  # wraps around
    columns["double"].copy_(2 * replay.rows["id"])  # the owner writes its columns (after the rows changed)
    sample = replay.sample()
    assert torch.equal(sample["double"], 2 * sample["id"])
    assert "double" not in replay.member_state(0)["transitions"].keys()  # noqa: SIM118
