"""aia.runtime.timing: phase totals with a fake clock, in place in the dict given, the summary line, and the machine's
matmul rate."""

from __future__ import annotations

import subprocess
import sys

import pytest

from aia.runtime import timing
from aia.runtime.timing import PhaseTimer


@pytest.fixture
def clock(monkeypatch):
    now = [0.0]
    monkeypatch.setattr(timing.time, "perf_counter", lambda: now[0])
    return now


def test_phases_accumulate_into_the_given_dict(clock):
    seconds = {"update": 1.0}
    timer = PhaseTimer(seconds)
    with timer("update"):
        clock[0] += 2.5
    with timer("collect"):
        clock[0] += 0.5
    timer.add("other", 1.0)
    assert seconds == {"update": 3.5, "collect": 0.5, "other": 1.0}
    assert timer.seconds is seconds


def test_a_phase_that_raises_is_still_counted(clock):
    timer = PhaseTimer()
    with pytest.raises(KeyError), timer("evaluate"):
        clock[0] += 4.0
        raise KeyError("boom")
    assert timer.seconds == {"evaluate": 4.0}


def test_summary_ranks_phases_by_time():
    assert PhaseTimer({"collect": 1.0, "update": 3.0}).summary() == "update 75% (3.0 s), collect 25% (1.0 s)"
    assert PhaseTimer().summary() == "no time measured"


def test_sgemm_rate_counts_two_flops_per_multiply_add(monkeypatch):
    # 30 products of 64 x 64 matrices (2 * 64**3 FLOPs each) between clock readings 10 s and 12 s
    readings = iter([10.0, 12.0])
    monkeypatch.setattr(timing.time, "perf_counter", lambda: next(readings))
    assert timing.sgemm_gflops(size=64, calls=30) == pytest.approx(2 * 64**3 * 30 / 2.0 / 1e9)


def test_python_m_aia_timing_prints_a_positive_rate():
    result = subprocess.run([sys.executable, "-m", "aia.runtime.timing"], capture_output=True, text=True, timeout=120)
    assert result.returncode == 0, result.stderr
    assert float(result.stdout) > 0
