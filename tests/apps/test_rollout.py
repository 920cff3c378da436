"""The aia-rollout app: runs, prints its table and where its log went (bad input: tests/apps/test_bad_inputs.py)."""

from __future__ import annotations

import json
import subprocess
import sys


def _run(tmp_path, *overrides):
    return subprocess.run(
        [sys.executable, "-m", "aia.apps.rollout", f"hydra.run.dir={tmp_path}", *overrides],
        capture_output=True, text=True, timeout=300, cwd=tmp_path,
    )


def test_rollout_app_writes_its_log(tmp_path):
    result = _run(tmp_path, "env=small2", "num_worlds=4", "env.max_steps=20", "seed=3")
    assert result.returncode == 0, result.stderr
    assert f"log written to {tmp_path / 'rollout.json'}" in result.stdout
    log = json.loads((tmp_path / "rollout.json").read_text())
    assert [r["policy"] for r in log["results"]] == ["random", "pursuit"]
    assert log["setting"] == "small2" and log["config"]["env"]["num_targets"] == 2
    for r in log["results"]:
        assert r["episodes"] == 4 and r["score_std"] >= 0 and r["belief_error"] > 0
        assert r["policy"] in result.stdout and f"{r['belief_error']:.2f}" in result.stdout
