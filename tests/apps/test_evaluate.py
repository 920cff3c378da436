"""aia-eval: scores a saved policy or the ARVI planner reproducibly; names a bad checkpoint or policy."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest
from hydra import compose, initialize_config_module

from aia.apps.evaluate import evaluate_checkpoint, evaluate_planner
from aia.logging import read_run
from aia.training import train


@pytest.fixture(scope="module")
def checkpoint(tmp_path_factory):
    out = tmp_path_factory.mktemp("run")
    with initialize_config_module(config_module="aia.conf", version_base="1.3"):
        cfg = compose(config_name="train", overrides=["frames=200", "env.max_steps=40", "warmup_frames=100",
                                                      "logger=none", "eval.episodes=2", "batch_size=16"])
    train(cfg, out)
    return out / "checkpoints" / "last.pt"


def test_evaluation_is_seeded_and_batched(checkpoint):
    first = evaluate_checkpoint(checkpoint, episodes=6, epsilon=0.05, seed=3, device="cpu")
    again = evaluate_checkpoint(checkpoint, episodes=6, epsilon=0.05, seed=3, device="cpu")
    other = evaluate_checkpoint(checkpoint, episodes=6, epsilon=0.05, seed=4, device="cpu")
    assert first["scores"] == again["scores"] and first["scores"] != other["scores"]
    assert len(first["scores"]) == 6 and first["frames_trained"] == 200 and first["algo"] == "dqn"
    assert first["score_mean"] == pytest.approx(sum(first["scores"]) / 6, rel=1e-5)


def test_bad_checkpoints_are_named(tmp_path, checkpoint):
    with pytest.raises(ValueError, match="does not exist"):
        evaluate_checkpoint(tmp_path / "missing.pt", 2, 0.05, 0, "cpu")
    junk = tmp_path / "junk.pt"
    junk.write_text("not a checkpoint")
    with pytest.raises(ValueError, match="junk.pt.*not a readable torch checkpoint"):
        evaluate_checkpoint(junk, 2, 0.05, 0, "cpu")
    with pytest.raises(ValueError, match="epsilon=1.5"):
        evaluate_checkpoint(checkpoint, 2, 1.5, 0, "cpu")


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


def _arvi_config(*overrides):
    with initialize_config_module(config_module="aia.conf", version_base="1.3"):
        return compose(config_name="eval", overrides=["policy=arvi", "env.max_steps=10", "planner.time_budget=null",
                                                      "planner.max_passes=1", *overrides])


def test_arvi_is_scored_through_the_evaluation_path():
    cfg = _arvi_config()
    first = evaluate_planner(cfg.env, cfg.planner, episodes=3, seed=1, device="cpu")
    again = evaluate_planner(cfg.env, cfg.planner, episodes=3, seed=1, device="cpu")
    assert first["scores"] == again["scores"] and len(first["scores"]) == 3  # deterministic budget: reproducible
    assert first["planner"]["horizon"] == 12 and first["planner"]["eps"] == "inf"
    with pytest.raises(ValueError, match="planner.horizon=0"):
        evaluate_planner(cfg.env, _arvi_config("planner.horizon=0").planner, episodes=1, seed=1, device="cpu")


def test_app_runs_arvi(tmp_path):  # an unknown policy is named in tests/apps/test_bad_inputs.py
    command = [sys.executable, "-m", "aia.apps.evaluate", "policy=arvi", "episodes=2", "env.max_steps=10",
               "planner.time_budget=0.02", "threads=1", f"hydra.run.dir={tmp_path}"]
    result = subprocess.run(command, capture_output=True, text=True, timeout=120)
    assert result.returncode == 0, result.stderr
    assert "arvi: score" in result.stdout and "over 2 episodes, belief error " in result.stdout
    assert " m (horizon 12, budget 0.02 s)" in result.stdout
    written = json.loads((tmp_path / "eval.json").read_text())
    assert written["policy"] == "arvi" and written["belief_error"] > 0
