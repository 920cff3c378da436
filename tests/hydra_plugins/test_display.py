"""The population launcher's display: a bar of its own line per running population on a terminal, throttled
progress lines elsewhere, and lines printed above the bars."""

from __future__ import annotations

from hydra_plugins.aia_population_launcher.display import PopulationDisplay


def _state(n: int, closed: bool = False, postfix: str = "score=12") -> dict:
    return {"n": n, "total": 400, "desc": "dqn x2", "postfix": postfix, "closed": closed}


def test_elsewhere_a_population_gets_a_line_per_interval_and_one_at_its_end(capsys, monkeypatch):
    clock = [100.0]
    monkeypatch.setattr("hydra_plugins.aia_population_launcher.display.time.monotonic", lambda: clock[0])
    display = PopulationDisplay(["jobs 0-1", "jobs 2-4"], slots=2, terminal=False, every_s=30.0)
    display.progress(0, _state(0))
    clock[0] = 110.0
    display.progress(0, _state(100))  # within 30 s: no line
    clock[0] = 130.0
    display.progress(0, _state(300))
    display.progress(0, _state(400, closed=True))
    display.write("population launcher: 1/2 done after 0:30: jobs 0-1")
    assert capsys.readouterr().out.splitlines() == [
        "population launcher: jobs 0-1: dqn x2 0/400 frames (0%), score=12",
        "population launcher: jobs 0-1: dqn x2 300/400 frames (75%), 10 frames/s, score=12",
        "population launcher: jobs 0-1: dqn x2 400/400 frames (100%), 13 frames/s, score=12",
        "population launcher: 1/2 done after 0:30: jobs 0-1",
    ]


def test_on_a_terminal_each_running_population_has_a_bar_of_its_own_line(capsys):
    display = PopulationDisplay(["jobs 0-1", "jobs 2-4", "job 5"], slots=2, terminal=True)
    display.progress(0, _state(10))
    display.progress(1, _state(20))
    lines = {index: line for index, (_, line) in display._bars.items()}
    assert lines == {0: 0, 1: 1}
    display.write("training dqn (egreedy) on empty1 for 400 frames as a population of 2")
    display.finish(0)
    display.progress(2, _state(30))  # takes the line population 0 left
    assert {index: line for index, (_, line) in display._bars.items()} == {1: 1, 2: 0}
    bar, _ = display._bars[2]
    assert (bar.n, bar.total, bar.desc) == (30, 400, "job 5: dqn x2")
    display.close()
    assert display._bars == {}
    captured = capsys.readouterr()
    assert "training dqn (egreedy) on empty1 for 400 frames as a population of 2\n" in captured.out
    assert "jobs 2-4: dqn x2" in captured.err
