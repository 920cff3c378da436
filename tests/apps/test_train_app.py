"""The aia-train app: parallel local sweeps (joblib) and the SLURM launcher config."""

from __future__ import annotations

import subprocess
import sys

from hydra import compose, initialize_config_module


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
