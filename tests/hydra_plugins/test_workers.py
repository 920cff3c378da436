"""The population launcher's workers: forked from a fork server that preloads aia's training stack (spawned where
the platform has none), a stop signal while no training loop listens ends the call at once, and a worker whose
launcher is gone stops as on a SIGTERM instead of failing on the broken pipe."""

from __future__ import annotations

import multiprocessing
import os
import signal
from multiprocessing import forkserver

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


def test_workers_fork_from_a_server_preloading_the_training_stack_or_spawn_without_one(monkeypatch):
    context = workers._worker_context()
    assert context.get_start_method() == "forkserver"
    # the server's mark last: aia.runtime.fork_server marks the process that has imported the rest
    assert forkserver._forkserver._preload_modules == ["aia.training.sweeps", "aia.runtime.fork_server"]
    monkeypatch.setattr(multiprocessing, "get_all_start_methods", lambda: ["spawn"])
    assert workers._worker_context().get_start_method() == "spawn"
