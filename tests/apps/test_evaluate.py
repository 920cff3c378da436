"""aia-eval: scores a saved policy, the ARVI planner or belief pursuit reproducibly; names a bad checkpoint or
policy; a stop signal ends it in one line."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys

import numpy as np
import pytest

import aia.apps.evaluate as evaluate_app
from aia.evaluation.standalone import evaluate_checkpoint
from aia.logging import read_run
from tests.apps.test_bad_inputs import run_app


def test_app_prints_and_writes_its_log(tmp_path, checkpoint):
    result = subprocess.run([sys.executable, "-m", "aia.apps.evaluate", f"checkpoint={checkpoint}", "episodes=3",
                             f"hydra.run.dir={tmp_path}"], capture_output=True, text=True, timeout=120)
    assert result.returncode == 0, result.stderr
    assert "over 3 episodes" in result.stdout and f"log written to {tmp_path / 'eval.json'}" in result.stdout
    run = read_run(tmp_path / "run.mcap")
    assert run.complete and len(run.scalars("eval/episode_score").values) == 3
    assert run.scalars("eval/score").values.tolist() == pytest.approx([json.loads(
        (tmp_path / "eval.json").read_text())["score_mean"]])
    assert run.config_value("algo") == "dqn" and run.config_value("env.max_steps") == 40
    assert run.metadata["run"]["policy"] == "checkpoint"
    info, frames = run.episode("first")
    assert info.frame == 200 and len(frames) == 41  # world 0's episode of 40 steps, labelled by frames trained
    assert len(json.loads((tmp_path / "eval.json").read_text())["scores"]) == 3


def test_app_runs_arvi(tmp_path):  # an unknown policy is named in tests/apps/test_bad_inputs.py
    command = [sys.executable, "-m", "aia.apps.evaluate", "policy=arvi", "episodes=2", "env.max_steps=10",
               "planner.time_budget=0.02", "threads=1", f"hydra.run.dir={tmp_path}"]
    result = subprocess.run(command, capture_output=True, text=True, timeout=120)
    assert result.returncode == 0, result.stderr
    assert "arvi: score" in result.stdout and "over 2 episodes, belief error " in result.stdout
    assert " m (horizon 12, budget 0.02 s)" in result.stdout
    written = json.loads((tmp_path / "eval.json").read_text())
    assert written["policy"] == "arvi" and written["belief_error"] > 0


def _eval_app(monkeypatch, *overrides: str) -> None:
    """``aia-eval <overrides>`` in-process (``main()`` with ``sys.argv`` patched)."""
    monkeypatch.setattr(sys, "argv", ["aia-eval", *overrides])
    evaluate_app.main()


def test_population_launcher_plans_all_seeds_in_one_batch_as_each_seed_alone(tmp_path, monkeypatch, capsys):
    """``-m seed=0,1 hydra/launcher=population``: one batch, a budget group per seed; every job's eval.json and
    run.mcap (scores, config, world 0's recorded episode) equal the seed's own ``aia-eval`` run's."""
    # small2 at 800 nodes: one budget shared by the batch would change the plans of seed 1's world 0
    small = ["policy=arvi", "env=small2", "episodes=2", "env.max_steps=10", "planner.time_budget=null",
             "planner.max_nodes=800", "threads=1"]
    _eval_app(monkeypatch, "-m", *small, "seed=0,1", "hydra/launcher=population", f"hydra.sweep.dir={tmp_path}")
    out = capsys.readouterr().out
    assert "2 jobs in 1 population of 2 members" in out and out.count("arvi: score") == 2
    for seed in (0, 1):
        _eval_app(monkeypatch, *small, f"seed={seed}", f"hydra.run.dir={tmp_path / f'alone{seed}'}")
        together, alone = tmp_path / str(seed), tmp_path / f"alone{seed}"
        assert json.loads((together / "eval.json").read_text()) == json.loads((alone / "eval.json").read_text())
        runs = read_run(together / "run.mcap"), read_run(alone / "run.mcap")
        assert runs[0].config() == runs[1].config() and runs[0].config_value("seed") == seed
        for topic in ("eval/episode_score", "eval/score", "eval/score_std", "eval/belief_error"):
            assert runs[0].scalars(topic).values.tolist() == runs[1].scalars(topic).values.tolist()
        (info, frames), (alone_info, alone_frames) = (run.episode("first") for run in runs)
        assert (info.episode, info.frame, info.num_targets) == (alone_info.episode, alone_info.frame, 2)
        assert len(frames) == 11
        for frame, alone_frame in zip(frames, alone_frames, strict=True):
            assert frame.step == alone_frame.step and np.array_equal(frame.robot_pose, alone_frame.robot_pose)
            assert np.array_equal(frame.belief_cov, alone_frame.belief_cov)
            assert np.array_equal(frame.targets, alone_frame.targets)
    first, second = (json.loads((tmp_path / str(s) / "eval.json").read_text())["scores"] for s in (0, 1))
    assert first != second


def test_population_launcher_runs_checkpoint_jobs_one_by_one_and_a_bad_job_fails_alone(tmp_path, monkeypatch,
                                                                                       checkpoint):
    with pytest.raises(SystemExit) as info:  # Hydra reports the failed jobs once the sweep has ended
        _eval_app(monkeypatch, "-m", f"checkpoint={checkpoint}", "episodes=2", "seed=0,1", "epsilon=0.05,1.5",
                  "hydra/launcher=population", "hydra.launcher.n_jobs=1", f"hydra.sweep.dir={tmp_path}")
    assert info.value.code == 2
    for job, seed in ((0, 0), (2, 1)):  # jobs 1 and 3 have epsilon=1.5
        written = json.loads((tmp_path / str(job) / "eval.json").read_text())
        assert written["scores"] == evaluate_checkpoint(checkpoint, 2, 0.05, seed, "cpu")["scores"]
        assert read_run(tmp_path / str(job) / "run.mcap").metadata["run"]["seed"] == str(seed)
    assert not (tmp_path / "1" / "eval.json").exists() and not (tmp_path / "3" / "run.mcap").exists()


def test_a_map_checkpoint_plays_on_another_map_of_its_layout_and_another_layout_is_refused(
        tmp_path, monkeypatch, capsys, checkpoint, map_checkpoint):
    """``env=<preset>`` or ``env.<key>=...`` (the checkpoint's setting with that key) with a checkpoint: the
    same observation layout on another map (the empty map, random maps) plays; another layout (no map image,
    another image size or channel count, other belief features) is refused in one line naming both, exit status
    2, no run log."""
    for name, overrides in (("empty", ["env=ttenv_v4", "env.features.im_size=8", "env.max_steps=20"]),
                            ("random_obstacles", ["env.target.collision_rule=reflect"])):
        _eval_app(monkeypatch, f"checkpoint={map_checkpoint}", "episodes=2", f"env.map={name}", *overrides,
                  f"hydra.run.dir={tmp_path / name}")
        written = json.loads((tmp_path / name / "eval.json").read_text())
        assert len(written["scores"]) == 2 and np.isfinite(written["scores"]).all()
        run = read_run(tmp_path / name / "run.mcap")
        assert run.config_value("env.map") == name and run.config_value("env.features.im_size") == 8
        assert run.config_value("trained_env.map") == "obstacles4"  # where the policy learned, to group by
    trained = "layout of the setting {} was trained in, observation [8]{}"
    maps, features = trained.format(map_checkpoint, ", local_map [1, 8, 8] ("), trained.format(checkpoint, " (")
    for path, overrides, words in (
            (map_checkpoint, ["env=ttenv_v1"],  # the keys that differ, those that shape the observation first
             ["env='observation [8]'", maps, "differs from it in env.features.local_map='none' ('occupancy' there)"]),
            (map_checkpoint, ["env=ttenv_v4"], ["env='observation [8], local_map [1, 28, 28]'", maps]),
            (map_checkpoint, ["env.features.local_map=occupancy_visits"], ["local_map [5, 8, 8]'", maps]),
            (checkpoint, ["env=small2"], ["env='observation [14]'", features, "env.num_targets=2 (1 there), "]),
            (map_checkpoint, ["env.num_targets=0"], ["env.num_targets=0: expected an integer >= 1"]),
    ):
        capsys.readouterr()
        with pytest.raises(SystemExit) as info:
            _eval_app(monkeypatch, f"checkpoint={path}", "episodes=1", *overrides, f"hydra.run.dir={tmp_path / 'no'}")
        err = capsys.readouterr().err.strip()
        assert info.value.code == 2 and len(err.splitlines()) == 1 and err.startswith("aia-eval: error: env"), err
        assert all(word in err for word in words), err
    assert not (tmp_path / "no").exists() or not list((tmp_path / "no").rglob("*.mcap"))


def test_a_stop_signal_ends_an_evaluation_in_one_line_with_its_log_marked_stopped(tmp_path, monkeypatch, capsys):
    """SIGTERM while the evaluation runs (in-process: the signal sent from inside its rollout): one line, exit
    status 143, the log closed and marked stopped, no eval.json."""
    def signalled(*args, **kwargs):
        os.kill(os.getpid(), signal.SIGTERM)
        raise AssertionError("the signal did not stop the evaluation")

    monkeypatch.setattr(evaluate_app, "evaluate_scripted_seeds", signalled)
    code, err = run_app(evaluate_app.main, ["policy=pursuit", "env=empty1", "episodes=1"], tmp_path, monkeypatch,
                        capsys)
    run_dir = tmp_path / "run"
    assert code == 143 and err == (f"aia-eval: stopped by SIGTERM before the end: the run in {run_dir} is "
                                   "unfinished (its log, if it wrote one, is marked stopped)\n")
    run = read_run(run_dir / "run.mcap")
    assert run.complete and run.failure == "stopped: SIGTERM"
    assert not (run_dir / "eval.json").exists()
