"""One writer per run folder: a second run on a folder in use is refused in one line naming the holder, the first
run's log stays intact; a stale lock of a dead process on this host is taken over; a lock held elsewhere is
waited for up to lock_wait_s; the lock goes with the run on every exit."""

from __future__ import annotations

import errno
import json
import os
import socket
import subprocess
import sys
import threading
import time

import pytest
from hydra import compose, initialize_config_module

from aia.config.errors import ConfigError, FolderLocked, WriteFailed
from aia.config.validation import validate_train_config
from aia.logging import read_run
from aia.runtime.stopping import StopOnSignals
from aia.training import train
from aia.training.folder_lock import LOCK_NAME, folder_locks

SMALL = ("env.max_steps=40", "warmup_frames=100", "eval.episodes=2", "batch_size=16", "hidden=[32,32]",
         "logger.record_every_evaluations=0", "seed=2")


def _config(*overrides: str):
    with initialize_config_module(config_module="aia.conf", version_base="1.3"):
        return compose(config_name="train", overrides=[*SMALL, *overrides])


def _holder(folder) -> dict:
    return json.loads((folder / LOCK_NAME).read_text())


class SecondRunAt(StopOnSignals):
    """Starts a second run on the same folder at the first run's ``step``-th step (the loop reads ``signal``
    once a step) and keeps what it raised; never signals."""

    def __init__(self, step: int, start) -> None:
        super().__init__()
        self.reads, self.start, self.refusal = step, start, None

    @property
    def signal(self) -> int | None:
        self.reads -= 1
        if self.reads == 0:
            try:
                self.start()
            except FolderLocked as err:
                self.refusal = err
        return None

    @signal.setter
    def signal(self, value: int | None) -> None:
        pass


def test_a_second_run_on_a_folder_in_use_is_refused_and_the_first_log_stays_intact(tmp_path):
    second = SecondRunAt(50, lambda: train(_config("frames=80"), tmp_path))
    state = train(_config("frames=120"), tmp_path, stop=second)
    refusal = str(second.refusal)
    assert refusal.count("\n") == 0 and refusal.startswith(f"{tmp_path} is in use by another run: pid {os.getpid()} "
                                                           f"on host {socket.gethostname()} since ")
    assert f"if that run is gone, delete {tmp_path / LOCK_NAME}" in refusal
    log = read_run(tmp_path / "run.mcap")
    assert log.complete and log.failure is None and not log.damage and log.segments == []
    assert log.scalars("eval/score").frames.tolist() == [40, 80, 120] and state.frames == 120
    assert sorted(p.name for p in tmp_path.iterdir()) == ["checkpoints", "run.mcap"]  # the lock went with the run


def test_a_stale_lock_of_a_dead_process_on_this_host_is_taken_over(tmp_path, capsys):
    dead = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True, text=True)
    stale = {"host": socket.gethostname(), "pid": int(dead.stdout), "since": "2026-12-06T00:00:00+00:00"}
    (tmp_path / LOCK_NAME).write_text(json.dumps(stale))
    with folder_locks([tmp_path], wait_s=0):
        assert _holder(tmp_path)["pid"] == os.getpid()
    assert f"taking over {tmp_path / LOCK_NAME}: its run (pid {stale['pid']} on this host) is gone" in (
        capsys.readouterr().out)
    assert not (tmp_path / LOCK_NAME).exists() and list(tmp_path.iterdir()) == []


def test_a_lock_held_on_another_host_is_waited_for_then_refused(tmp_path):
    held = {"host": "node-that-is-not-this-one", "pid": 1, "since": "2026-12-06T08:00:00+00:00"}
    (tmp_path / LOCK_NAME).write_text(json.dumps(held))
    start = time.monotonic()
    with pytest.raises(FolderLocked, match=r"pid 1 on host node-that-is-not-this-one since 2026-12-06T08:00:00"
                                           r"\+00:00 \(waited 0.3 s\)"), folder_locks([tmp_path], wait_s=0.3):
        pass
    assert time.monotonic() - start >= 0.3 and _holder(tmp_path) == held  # not taken over


def test_a_requeued_run_waits_for_its_earlier_copy_to_let_go(tmp_path):
    earlier = {"host": socket.gethostname(), "pid": os.getpid(), "since": "earlier"}  # alive: this process
    (tmp_path / LOCK_NAME).write_text(json.dumps(earlier))
    threading.Timer(0.3, (tmp_path / LOCK_NAME).unlink).start()
    with folder_locks([tmp_path], wait_s=10):
        assert _holder(tmp_path)["since"] != "earlier"


def test_every_folder_of_a_population_is_locked_and_released_on_an_error(tmp_path):
    folders = [tmp_path / "a", tmp_path / "b"]
    with pytest.raises(RuntimeError, match="the loop failed"), folder_locks(folders, wait_s=0):
        assert all(_holder(folder)["pid"] == os.getpid() for folder in folders)
        raise RuntimeError("the loop failed")
    assert not any((folder / LOCK_NAME).exists() for folder in folders)
    (folders[1] / LOCK_NAME).write_text(json.dumps({"host": "elsewhere", "pid": 7, "since": "then"}))
    with pytest.raises(FolderLocked), folder_locks(folders, wait_s=0):
        pass
    assert not (folders[0] / LOCK_NAME).exists()  # the lock taken before the refusal is released


def test_lock_wait_s_is_validated():
    with pytest.raises(ConfigError, match=r"^lock_wait_s=-1: expected a number >= 0$"):
        validate_train_config(_config("lock_wait_s=-1"))


def test_a_lock_that_cannot_be_written_is_a_write_failure_and_leaves_no_file(tmp_path, monkeypatch):
    def full(*args, **kwargs):
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    monkeypatch.setattr(json, "dump", full)
    with pytest.raises(WriteFailed, match=f"could not write {tmp_path / LOCK_NAME} \\(\\[Errno 28\\] No space"), \
            folder_locks([tmp_path], wait_s=0):
        pass
    assert not (tmp_path / LOCK_NAME).exists()
