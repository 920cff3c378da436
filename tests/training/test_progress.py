"""aia.training.progress: the loop's bar draws itself, or forwards its state (a population in a worker)."""

from __future__ import annotations

from tqdm import tqdm

from aia.training import progress


def test_a_bar_draws_itself_outside_forwarding_and_forwards_inside(capsys):
    bar = progress.progress_bar(100, 0, "dqn")
    assert isinstance(bar, tqdm)
    bar.close()
    sent = []
    with progress.forwarding(sent.append):
        bar = progress.progress_bar(100, 20, "dqn x2")
    assert isinstance(bar, progress.ForwardedBar)
    assert progress.progress_bar(100, 0, "after").__class__ is tqdm  # the sink ends with the block


def test_a_forwarded_bar_sends_at_most_every_interval_and_its_final_state_once(monkeypatch):
    clock = [0.0]
    monkeypatch.setattr(progress.time, "monotonic", lambda: clock[0])
    sent = []
    bar = progress.ForwardedBar(sent.append, total=300, initial=100, desc="adfq x4", interval_s=1.0)
    bar.update(1)  # the first update sends
    clock[0] = 0.5
    bar.set_postfix(score="1620", eps="0.10")
    bar.update(1)  # within the interval: kept
    clock[0] = 1.0
    bar.update(1)
    bar.close()
    bar.close()
    assert [(s["n"], s["postfix"], s["closed"]) for s in sent] == [
        (101, "", False), (103, "score=1620, eps=0.10", False), (103, "score=1620, eps=0.10", True)]
    assert all(s["total"] == 300 and s["desc"] == "adfq x4" for s in sent)
