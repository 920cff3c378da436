"""Optuna search through ``aia-train -m hydra/sweeper=paper_search``: each trial returns its objective
(aia.evaluation.search_objective), a trial that never evaluated fails alone, and the study's best trial is the one
whose run scored highest."""

from __future__ import annotations

import subprocess
import sys

import optuna
import pytest
import yaml
from hydra import compose, initialize_config_module

from aia.evaluation import search_objective
from aia.logging import read_run

TRIALS = 2  # one batch of the launcher's n_jobs (2): the population launcher trains both together


def test_paper_search_composes_a_maximising_optuna_sweeper():
    with initialize_config_module(config_module="aia.conf", version_base="1.3"):
        cfg = compose(config_name="train", overrides=["hydra/sweeper=paper_search"], return_hydra_config=True)
    sweeper = cfg.hydra.sweeper
    assert sweeper._target_.endswith("OptunaSweeper")
    assert sweeper.direction == "maximize"
    assert sweeper.params.lr.startswith("tag(log, interval(")
    assert sweeper.sampler._target_ == "optuna.samplers.TPESampler" and sweeper.sampler.seed == 0


def test_a_study_returns_the_lr_of_its_best_run(tmp_path):
    """The population launcher trains a batch's trials together and returns each one's objective. (The task
    function's own return, what Hydra's local and the SLURM launchers hand the sweeper, is checked through
    SLURM in tests/cluster/test_slurm.py.)"""
    storage = f"sqlite:///{tmp_path / 'study.db'}"  # the sqlite storage needs the pins of the `search` extra
    result = subprocess.run(
        [sys.executable, "-m", "aia.apps.train", "-m", "hydra/sweeper=paper_search",
         f"hydra.sweeper.n_trials={TRIALS}", f"hydra.sweeper.storage={storage}", "hydra.sweeper.study_name=tiny",
         "hydra/launcher=population", f"hydra.sweep.dir={tmp_path / 'sweep'}",
         # a trial with every_episodes=9 never evaluates (2 episodes): a failed trial, and the search goes on
         "eval.every_episodes=choice(1,9)",
         "frames=100", "warmup_frames=50", "env.max_steps=50", "eval.episodes=2", "eval.per_rollout=1",
         "logger.record_every_evaluations=0", "threads=1"],
        capture_output=True, text=True, timeout=300,
    )
    assert result.returncode == 0, result.stderr[-3000:]
    # the sweeper hands the launcher its trials n_jobs (2) at a time
    assert result.stdout.count("population launcher: 2 jobs in") == TRIALS // 2, result.stdout
    objectives, failed = {}, []
    for trial in range(TRIALS):
        run_dir = tmp_path / "sweep" / str(trial)
        overrides = dict(o.split("=", 1) for o in yaml.safe_load((run_dir / ".hydra" / "overrides.yaml").read_text()))
        run = read_run(run_dir / "run.mcap")
        if overrides["eval.every_episodes"] == "9":
            assert "eval/score" not in run.scalar_topics()
            failed.append(float(overrides["lr"]))
        else:
            objectives[float(overrides["lr"])] = search_objective(list(run.scalars("eval/score").values))
    assert len(objectives) == 1 and len(failed) == 1  # (the sampler's seed draws one of each)
    assert all(1e-4 <= lr <= 3e-3 for lr in [*objectives, *failed])
    best_lr = max(objectives, key=objectives.get)
    results = yaml.safe_load((tmp_path / "sweep" / "optimization_results.yaml").read_text())
    assert results["best_params"]["lr"] == pytest.approx(best_lr)
    assert results["best_value"] == pytest.approx(objectives[best_lr])
    study = optuna.load_study(study_name="tiny", storage=storage)
    trials = sorted(study.trials, key=lambda t: t.state.name)  # COMPLETE, FAIL
    assert [t.state for t in trials] == [optuna.trial.TrialState.COMPLETE, optuna.trial.TrialState.FAIL]
    assert trials[0].params["lr"] == pytest.approx(best_lr) and trials[0].value == pytest.approx(objectives[best_lr])
    assert trials[1].params["lr"] == pytest.approx(failed[0]) and trials[1].value is None
