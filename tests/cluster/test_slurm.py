"""``aia-train -m hydra/launcher=slurm`` on a real scheduler (the local cluster of scripts/slurm_local.sh):
a sweep runs end to end, and a job that fails inside SLURM is reported as failed instead of waited on."""

from __future__ import annotations

import math
import pickle

import pytest
import yaml

from aia.logging import read_run
from aia.objective import search_objective

# Tiny jobs: a warm-up episode of 50 steps and a training one, each followed by an evaluation of 2 worlds.
EPISODES = 2
TINY = (f"frames={50 * EPISODES}", "warmup_frames=50", "env.max_steps=50", "eval.episodes=2", "eval.per_rollout=1",
        "logger.record_every_evaluations=0", "threads=1")


def test_a_two_job_sweep_runs_end_to_end(slurm_cluster, tmp_path):
    sweep_dir = tmp_path / "sweep"
    name, result = slurm_cluster.sweep(sweep_dir, *TINY, "seed=0,1")
    assert result.returncode == 0, result.stderr[-3000:]

    multirun = yaml.safe_load((sweep_dir / "multirun.yaml").read_text())
    assert multirun["hydra"]["launcher"]["_target_"].endswith("SlurmLauncher")
    assert multirun["hydra"]["overrides"]["task"][-1] == "seed=0,1"
    jobs = slurm_cluster.jobs(name)
    assert [job.state for job in jobs] == ["COMPLETED", "COMPLETED"], jobs
    array_id = jobs[0].job_id.split("_")[0]
    for index, seed in enumerate((0, 1)):
        run_dir = sweep_dir / str(index)
        overrides = yaml.safe_load((run_dir / ".hydra" / "overrides.yaml").read_text())
        assert f"seed={seed}" in overrides
        scores = read_run(run_dir / "run.mcap").scalars("eval/score").values
        assert len(scores) == EPISODES  # one evaluation after every episode
        # submitit's record of the job: Hydra's JobReturn, holding the objective the task returned
        status, job_return = pickle.loads(
            (sweep_dir / ".submitit" / f"{array_id}_{index}" / f"{array_id}_{index}_0_result.pkl").read_bytes())
        assert status == "success"
        assert job_return.status.name == "COMPLETED"
        assert job_return.overrides[-1] == f"seed={seed}"
        assert job_return.return_value == pytest.approx(search_objective(list(scores)))
        assert math.isfinite(job_return.return_value)


def test_a_job_that_fails_inside_slurm_is_reported_failed(slurm_cluster, tmp_path):
    """Thompson sampling with DQN is refused by the job itself (``aia-train: error: ...``, exit status 2):
    the job leaves no result, so submitit learns of its end from sacct (slurmdbd) alone."""
    sweep_dir = tmp_path / "sweep"
    name, result = slurm_cluster.sweep(sweep_dir, *TINY, "algo=dqn", "exploration=thompson")
    assert result.returncode != 0
    assert "exploration='thompson'" in result.stderr, result.stderr[-3000:]  # the job's own error line
    [job] = slurm_cluster.jobs(name)
    assert (job.state, job.exit_code) == ("FAILED", "2:0")
    assert not (sweep_dir / "0" / "run.mcap").exists()
