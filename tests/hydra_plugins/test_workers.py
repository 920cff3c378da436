"""The population launcher's workers: a stop signal while no training loop listens ends the call at once, and a
worker whose launcher is gone stops as on a SIGTERM instead of failing on the broken pipe."""

from __future__ import annotations

import multiprocessing
import os
import signal

from hydra_plugins.aia_population_launcher import workers


def test_a_signal_while_no_training_loop_listens_ends_the_call(monkeypatch):
    monkeypatch.setattr(workers, "run_group", lambda *call: os.kill(os.getpid(), signal.SIGUSR1))
    assert workers.run_stoppable(("task", [], [], None)) == ("stopped", 128 + signal.SIGUSR1)


def test_a_worker_whose_launcher_is_gone_stops_as_on_a_sigterm(monkeypatch, capsys):
    launcher_end, worker_end = multiprocessing.Pipe()
    pipe = workers._LauncherPipe(worker_end)
    pipe.send(("print", "a line"))
    assert launcher_end.recv() == ("print", "a line")
    launcher_end.close()  # the launcher is gone
    sent = []
    monkeypatch.setattr(workers.os, "kill", lambda pid, signum: sent.append((pid, signum)))
    for _ in range(3):
        pipe.send(("progress", {}))
    assert pipe.gone and sent == [(os.getpid(), signal.SIGTERM)]  # once; the rest is dropped
    assert "the launcher is gone: this population stops as on a SIGTERM" in capsys.readouterr().err
