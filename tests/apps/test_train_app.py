"""The aia-train app: parallel local sweeps (joblib), the SLURM launcher config, killed runs keep their log."""

from __future__ import annotations

import signal
import subprocess
import sys
import time

import pytest
from hydra import compose, initialize_config_module

from aia.logging import read_run


def test_local_sweep_runs_every_job(tmp_path):
    result = subprocess.run(
        [sys.executable, "-m", "aia.apps.train", "-m", "algo=dqn,adfq", "frames=120", "logger=none",
         "env.max_steps=40", "warmup_frames=100", "eval.episodes=2", "threads=1", f"hydra.sweep.dir={tmp_path}"],
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
