"""The population launcher's workers: a stop signal while no training loop listens ends the call at once, and a
worker whose launcher is gone stops as on a SIGTERM instead of failing on the broken pipe."""

from __future__ import annotations

import multiprocessing
import os
import signal

import pytest

from hydra_plugins.aia_population_launcher import workers


def test_a_signal_while_no_training_loop_listens_ends_the_call():
    before = signal.getsignal(signal.SIGUSR1)
    with pytest.raises(workers._Signalled) as raised, workers._interrupting():
        os.kill(os.getpid(), signal.SIGUSR1)
    assert raised.value.signum == signal.SIGUSR1
    assert signal.getsignal(signal.SIGUSR1) is before


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
