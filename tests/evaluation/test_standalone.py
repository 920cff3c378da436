"""Policies scored outside training: seeded and batched, a sweep's seeds in one rollout as each alone, the same
scores as the rollout app's, bad input named."""

from __future__ import annotations

import pytest
from hydra import compose, initialize_config_module

from aia.evaluation.standalone import evaluate_checkpoint, evaluate_planner, evaluate_scripted_seeds, score_scripted


def test_evaluation_is_seeded_and_batched(checkpoint):
    first = evaluate_checkpoint(checkpoint, episodes=6, epsilon=0.05, seed=3, device="cpu")
    again = evaluate_checkpoint(checkpoint, episodes=6, epsilon=0.05, seed=3, device="cpu")
    other = evaluate_checkpoint(checkpoint, episodes=6, epsilon=0.05, seed=4, device="cpu")
    assert first["scores"] == again["scores"] and first["scores"] != other["scores"]
    assert len(first["scores"]) == 6 and first["frames_trained"] == 200 and first["algo"] == "dqn"
    assert first["score_mean"] == pytest.approx(sum(first["scores"]) / 6, rel=1e-5)


def test_bad_checkpoints_are_named(tmp_path, checkpoint):
    with pytest.raises(ValueError, match="missing.pt.*expected an existing checkpoint"):
        evaluate_checkpoint(tmp_path / "missing.pt", 2, 0.05, 0, "cpu")
    junk = tmp_path / "junk.pt"
    junk.write_text("not a checkpoint")
    with pytest.raises(ValueError, match="junk.pt.*not a whole zip archive"):
        evaluate_checkpoint(junk, 2, 0.05, 0, "cpu")
    with pytest.raises(ValueError, match="epsilon=1.5"):
        evaluate_checkpoint(checkpoint, 2, 1.5, 0, "cpu")


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


def test_pursuit_scores_as_aia_rollout_and_its_seeds_together_as_each_alone():
    with initialize_config_module(config_module="aia.conf", version_base="1.3"):
        cfg = compose(config_name="eval", overrides=["policy=pursuit", "env=ttenv_v2", "env.max_steps=15"])
        rollout = compose(config_name="rollout", overrides=["env=ttenv_v2", "env.max_steps=15", "num_worlds=3",
                                                            "seed=1"])
    together = evaluate_scripted_seeds("pursuit", cfg.env, 3, [1, 2], "cpu", standoff=cfg.pursuit_standoff)
    alone = [evaluate_scripted_seeds("pursuit", cfg.env, 3, [seed], "cpu")[0] for seed in (1, 2)]
    assert together == alone and together[0]["scores"] != together[1]["scores"]
    assert together[0]["policy"] == "pursuit" and together[0]["pursuit_standoff"] == 0.5
    assert together[0]["score_mean"] == pytest.approx(score_scripted(rollout, "pursuit")["score_mean"], rel=1e-6)
