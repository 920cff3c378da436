"""The aia-train app: parallel local sweeps (joblib), the SLURM launcher config, killed runs keep their log, a
full disk ends a run in one line."""

from __future__ import annotations

import signal
import subprocess
import sys
import time

import pytest
import torch
from hydra import compose, initialize_config_module

import aia.training.checkpoint_files as checkpoint_files
from aia.apps import train as train_app
from aia.logging import read_run
from aia.training import TrainingState


def test_local_sweep_runs_every_job(tmp_path):
    result = subprocess.run(
        [sys.executable, "-m", "aia.apps.train", "-m", "algo=dqn,adfq", "frames=120", "logger=none",
         "env.max_steps=40", "warmup_frames=100", "eval.episodes=2", "threads=1", "hydra.launcher.n_jobs=1",
         f"hydra.sweep.dir={tmp_path}"],
        capture_output=True, text=True, timeout=300,
    )
    assert result.returncode == 0, result.stderr
    for job in ("0", "1"):
        assert (tmp_path / job / "checkpoints" / "last.pt").is_file()
    assert "JoblibLauncher" in (tmp_path / "multirun.yaml").read_text()


def test_slurm_launcher_config_composes():
    with initialize_config_module(config_module="aia.conf", version_base="1.3"):
        cfg = compose(config_name="train", overrides=["hydra/launcher=slurm", "hydra.launcher.partition=cpu"],
                      return_hydra_config=True)
    launcher = cfg.hydra.launcher
    assert launcher._target_.endswith("SlurmLauncher")
    assert launcher.partition == "cpu" and launcher.cpus_per_task == 2 and launcher.timeout_min == 720


def test_sigterm_ends_the_run_with_a_complete_log(tmp_path):
    """SIGTERM: exit status 143 and a log closed cleanly with every evaluation (after SIGKILL the log keeps
    every evaluation too: tests/training/test_resuming.py kills a run with flushing by time switched off)."""
    process = subprocess.Popen(
        [sys.executable, "-m", "aia.apps.train", "frames=1000000", "env.max_steps=40", "warmup_frames=100",
         "eval.episodes=2", "threads=1", "logger.flush_interval_s=3600", f"hydra.run.dir={tmp_path}"],
        stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True,
    )
    log = tmp_path / "run.mcap"
    deadline = time.monotonic() + 240
    scores = 0
    while scores < 2 and time.monotonic() < deadline and process.poll() is None:
        time.sleep(0.5)
        if log.exists():
            run = read_run(log)
            scores = len(run.scalars("eval/score").values) if "eval/score" in run.scalar_topics() else 0
    assert scores >= 2, process.stderr.read() if process.poll() is not None else "no evaluation in 240 s"
    process.send_signal(signal.SIGTERM)
    assert process.wait(timeout=60) == 143
    run = read_run(log)
    assert run.complete
    assert len(run.scalars("eval/score").values) >= scores


@pytest.mark.parametrize("method, algo, exploration", [("dqn", "dqn", "egreedy"), ("ddqn", "ddqn", "egreedy"),
                                                       ("adfq_egreedy", "adfq", "egreedy"),
                                                       ("adfq_ts", "adfq", "thompson")])
def test_method_sets_algo_and_exploration(method, algo, exploration):
    with initialize_config_module(config_module="aia.conf", version_base="1.3"):
        cfg = compose(config_name="train", overrides=[f"method={method}", "experiment=paper_small3"])
    assert (cfg.algo.name, cfg.exploration.name, cfg.env.num_targets) == (algo, exploration, 3)
    assert cfg.method == method  # the name aia-log plot --group-by method groups by


def test_a_full_disk_ends_the_run_in_one_line_with_its_log_and_checkpoint_intact(tmp_path, monkeypatch, capsys,
                                                                                  full_disk):
    """The second checkpoint's write fails (the in-process app): exit status 1, one stderr line naming the file
    and the OS error; the log says why and keeps every evaluation; the first checkpoint stays; no temporary file,
    no lock left."""
    full_disk(checkpoint_files, room=20_000, after=1)
    monkeypatch.setattr(sys, "argv", ["aia-train", f"hydra.run.dir={tmp_path}", "hydra.output_subdir=null",
                                      "hydra/job_logging=disabled", "hydra/hydra_logging=disabled", "frames=200",
                                      "checkpoint_every_frames=40", "env.max_steps=40", "warmup_frames=100",
                                      "eval.episodes=2", "batch_size=16", "hidden=[32,32]",
                                      "logger.record_every_evaluations=0"])
    with pytest.raises(SystemExit) as info:
        train_app.main()
    lines = [line for line in capsys.readouterr().err.split("\n") if line and "frame/s" not in line]  # no bar
    last = tmp_path / "checkpoints" / "last.pt"
    assert info.value.code == 1 and len(lines) == 1
    assert lines[0].startswith(f"aia-train: error: could not write {last} ([Errno 28] No space left on device)")
    run = read_run(tmp_path / "run.mcap")
    assert run.complete and run.failure == f"failed: {lines[0].removeprefix('aia-train: error: ')}"
    assert run.scalars("eval/score").frames.tolist() == [40, 80]
    assert torch.load(last, weights_only=False)["state"]["frames"] == 40
    assert sorted(p.name for p in tmp_path.rglob("*")) == ["checkpoints", "last.pt", "run.mcap"]


def test_a_run_that_ends_before_its_first_update_says_so(capsys):
    with initialize_config_module(config_module="aia.conf", version_base="1.3"):
        short, long = (compose(config_name="train", overrides=[f"frames={frames}", "warmup_frames=500"])
                       for frames in (499, 500))
    train_app.note_no_updates(short)
    assert capsys.readouterr().err == ("note: frames=499 < warmup_frames=500: random actions only, no update (lower "
                                       "warmup_frames or raise frames to learn)\n")
    train_app.note_no_updates(long)  # frame 500 updates once
    assert capsys.readouterr().err == ""


def test_the_report_names_no_log_without_a_logger_and_a_stopped_population_as_stopped(tmp_path, capsys):
    with initialize_config_module(config_module="aia.conf", version_base="1.3"):
        silent, logged = (compose(config_name="train", overrides=[f"logger={name}"]) for name in ("none", "mcap"))
    state = TrainingState(frames=400, updates=10, episodes=4, evaluations=1, eval_scores=[-12.5],
                          seconds={"collect": 1.0})
    train_app.report(silent, tmp_path, state)
    out = capsys.readouterr().out
    assert "log written" not in out and f"checkpoint: {tmp_path / 'checkpoints' / 'last.pt'}" in out
    train_app.report_population([silent, logged], [tmp_path / "0", tmp_path / "1"], [state, state], stopped=True)
    lines = capsys.readouterr().out.splitlines()
    assert lines[0].startswith("population of 2 stopped at 400 frames, 4 episodes, 10 updates each")
    assert lines[1].endswith("last eval score -12.5, no log (logger=none)")
    assert lines[2].endswith(f"last eval score -12.5, log {tmp_path / '1' / 'run.mcap'}")
