"""aia-log: summary, scalars, plot, stats and render on small logs written here."""

from __future__ import annotations

import csv
import json
import os
import re
import signal
import subprocess
import sys

import numpy as np
import pytest
import torch
from PIL import Image

from aia.apps import log_cli
from aia.apps.log_cli import main
from aia.envs import make_env
from aia.logging import MCAPLogger, SceneRecorder
from aia.logging.stats import rliable_modules


def _fake_run(folder, algo, seed, scores, env_map="empty", **config):
    logger = MCAPLogger("exp", folder)
    logger.log_hparams({"algo": {"name": algo}, "seed": seed, "env": {"map": env_map, "max_steps": 50}, **config})
    for i, score in enumerate(scores):
        logger.log_scalar("eval/score", score, step=100 * (i + 1))
    logger.close()
    return folder / "run.mcap"


@pytest.fixture(scope="module")
def recorded(tmp_path_factory):
    folder = tmp_path_factory.mktemp("recorded")
    logger = MCAPLogger("exp", folder)
    env = make_env("empty1", batch_size=2, seed=0, overrides=["max_steps=9"])
    recorder = SceneRecorder(logger)
    env.append_transform(recorder)
    recorder.record(episode=2, frame=50)
    torch.manual_seed(0)  # the rollout's random actions
    env.rollout(9, break_when_any_done=False)
    logger.log_scalar("eval/score", 12.5, step=50)
    logger.close()
    return folder / "run.mcap"


def test_summary_lists_topics_episodes_and_scores(recorded, capsys):
    assert main(["summary", str(recorded)]) == 0
    out = capsys.readouterr().out
    assert "[complete]" in out and "/scene" in out and "foxglove.SceneUpdate" in out
    assert "1 recorded: 2" in out and "last 12.5 at frame 50" in out


def test_reading_commands_start_without_torch(recorded, tmp_path):
    """summary, scalars and plot read logs without importing torch or TorchRL (a fresh interpreter each): the
    writers load on first use, a recorded episode's index comes without rasterising its map."""
    runs = [_fake_run(tmp_path / f"r{seed}", "dqn", seed, [1.0, 2.0]) for seed in (0, 1)]
    commands = [["summary", str(recorded)],
                ["scalars", str(runs[0]), "--topic", "eval/score", "--csv", str(tmp_path / "s.csv")],
                ["plot", str(tmp_path), "--group-by", "algo", "--out", str(tmp_path / "p.png")]]
    for command in commands:
        code = (f"import sys; from aia.apps.log_cli import main; assert main({command!r}) == 0; "
                "print(sorted(m for m in ('torch', 'torchrl', 'tensordict') if m in sys.modules))")
        result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
        assert result.returncode == 0, result.stderr[-2000:]
        assert result.stdout.strip().splitlines()[-1] == "[]", command


def test_a_stop_signal_ends_a_command_in_one_line(monkeypatch, capsys):
    monkeypatch.setattr(log_cli, "run_command", lambda args: os.kill(os.getpid(), signal.SIGTERM))
    assert log_cli.main(["summary", "any.mcap"]) == 128 + signal.SIGTERM
    assert capsys.readouterr().err == "aia-log: stopped by SIGTERM\n"


def test_summary_of_a_truncated_file_says_so(recorded, tmp_path, capsys):
    data = recorded.read_bytes()
    (tmp_path / "cut.mcap").write_bytes(data[: len(data) // 2])
    assert main(["summary", str(tmp_path / "cut.mcap")]) == 0
    captured = capsys.readouterr()
    assert "truncated:" in captured.out and "messages recovered" in captured.out
    assert "warning:" in captured.err


def test_a_file_that_is_not_mcap_gets_a_one_line_error(tmp_path, capsys):
    (tmp_path / "x.mcap").write_bytes(b"\x89PNG\r\n\x1a\n" + bytes(100))
    assert main(["summary", str(tmp_path / "x.mcap")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("aia-log: error:") and "not an MCAP file" in err


def test_scalars_to_csv(tmp_path, capsys):
    run = _fake_run(tmp_path / "r", "dqn", 0, [1.0, 2.5])
    assert main(["scalars", str(run), "--topic", "eval/score", "--csv", str(tmp_path / "s.csv")]) == 0
    with open(tmp_path / "s.csv") as f:
        rows = list(csv.DictReader(f))
    assert [(r["topic"], r["frame"], float(r["value"])) for r in rows] == [("eval/score", "100", 1.0),
                                                                         ("eval/score", "200", 2.5)]
    assert "2 rows written" in capsys.readouterr().out
    assert main(["scalars", str(run), "--topic", "eval/nothing"]) == 2


def test_plot_aggregates_runs_per_group(tmp_path, capsys):
    _fake_run(tmp_path / "m/0", "adfq", 0, [1.0, 2.0, 3.0])
    _fake_run(tmp_path / "m/1", "adfq", 1, [3.0, 4.0, 8.0])
    _fake_run(tmp_path / "m/2", "adfq", 2, [5.0, 9.0, 10.0])
    _fake_run(tmp_path / "m/3", "dqn", 0, [0.0, 0.0, 1.0])
    out = tmp_path / "curves.png"
    assert main(["plot", str(tmp_path / "m"), "--group-by", "algo", "--out", str(out)]) == 0
    printed = capsys.readouterr().out
    final = np.array([3.0, 8.0, 10.0])
    assert f"algo=adfq: 3 runs, final eval/score {final.mean():.1f} +- {final.std():.1f}" in printed
    assert "algo=dqn: 1 runs" in printed
    assert Image.open(out).format == "PNG"
    assert main(["plot", str(tmp_path / "m"), "--out", str(tmp_path / "c.jpg")]) == 2


def test_plot_leaves_out_runs_without_the_metric(tmp_path, capsys):
    _fake_run(tmp_path / "m/0", "adfq", 0, [1.0, 2.0, 3.0])
    _fake_run(tmp_path / "m/1", "adfq", 1, [])  # no evaluation yet
    (tmp_path / "m/2").mkdir()
    (tmp_path / "m/2/run.mcap").write_bytes(b"\x89MCAP0\r\n")  # a run that has only just started
    assert main(["plot", str(tmp_path / "m"), "--group-by", "algo", "--out", str(tmp_path / "c.png")]) == 0
    captured = capsys.readouterr()
    assert "algo=adfq: 1 runs, final eval/score 3.0" in captured.out
    assert "m/1/run.mcap: no 'eval/score' yet, left out" in captured.err
    assert "m/2/run.mcap: no 'eval/score' yet, left out" in captured.err
    assert "m/2/run.mcap: truncated: 0 eval/score messages recovered (file ends early" in captured.err  # all it read
    assert main(["plot", str(tmp_path / "m/1"), "--out", str(tmp_path / "c.png")]) == 2
    assert "--metric 'eval/score': no run has logged it; expected a scalar topic" in capsys.readouterr().err


def test_plot_with_a_baseline_filters_and_the_episode_axis(tmp_path, capsys):
    _fake_run(tmp_path / "m/0", "adfq", 0, [1.0, 2.0, 6.0])
    _fake_run(tmp_path / "m/1", "adfq", 1, [3.0, 6.0, 8.0])
    _fake_run(tmp_path / "m/2", "adfq", 2, [9.0, 9.0, 9.0], env_map="obstacles4")  # filtered out
    for seed, score in enumerate([4.0, 5.0]):
        _fake_run(tmp_path / f"arvi/{seed}", "arvi", seed, [score])
    out = tmp_path / "fig2.png"
    assert main(["plot", str(tmp_path / "m"), "--where", "env.map=empty", "--group-by", "algo", "--x", "episode",
                 "--baseline", str(tmp_path / "arvi"), "--baseline-label", "ARVI", "--out", str(out)]) == 0
    printed = capsys.readouterr().out
    # means per evaluation 2, 4, 7 at episodes 2, 4, 6 (frames 100, 200, 300 over 50-step episodes):
    # ARVI's mean 4.5 is first reached at episode 6
    assert "| algo=adfq | 2 | 7.0 +- 1.0 | 7.0 +- 1.0 | 6 |" in printed
    assert "training episodes to reach ARVI (4.5 +- 0.5)" in printed
    assert main(["plot", str(tmp_path / "m"), "--where", "env.map", "--out", str(out)]) == 2
    assert "--where 'env.map' must look like KEY=VALUE" in capsys.readouterr().err


def test_plot_with_two_baselines(tmp_path, capsys):
    _fake_run(tmp_path / "m/0", "adfq", 0, [1.0, 2.0, 6.0])
    _fake_run(tmp_path / "m/1", "adfq", 1, [3.0, 6.0, 8.0])
    for seed, score in enumerate([4.0, 5.0]):
        _fake_run(tmp_path / f"weak/{seed}", "arvi", seed, [score])
    _fake_run(tmp_path / "strong/0", "arvi", 0, [9.0])
    out = tmp_path / "fig2.png"
    arguments = ["plot", str(tmp_path / "m"), "--x", "episode", "--out", str(out),
                 "--baseline", str(tmp_path / "weak"), "--baseline-label", "ARVI",
                 "--baseline", str(tmp_path / "strong"), "--baseline-label", "ARVI 2 m"]
    assert main(arguments) == 0
    printed = capsys.readouterr().out
    assert "to reach ARVI (4.5 +- 0.5) | training episodes to reach ARVI 2 m (9.0 +- 0.0) |" in printed
    assert "| all | 2 | 7.0 +- 1.0 | 7.0 +- 1.0 | 6 | never |" in printed
    # read as a lower-is-better metric, the means (2, 4, 7 at episodes 2, 4, 6) are at or below both
    # baselines' means (4.5 and 9.0) from the first evaluation on
    assert main([*arguments, "--better", "lower"]) == 0
    printed = capsys.readouterr().out
    assert "training episodes to fall to ARVI 2 m (9.0 +- 0.0) |" in printed
    assert "| all | 2 | 7.0 +- 1.0 | 7.0 +- 1.0 | 2 | 2 |" in printed
    assert main([*arguments, "--baseline-label", "third"]) == 2
    assert "3 --baseline-label for 2 --baseline" in capsys.readouterr().err


def test_render_png_strip_and_gif(recorded, tmp_path, capsys):
    assert main(["render", str(recorded), "--out", str(tmp_path / "e.png"), "--frames", "4", "--size", "64"]) == 0
    assert Image.open(tmp_path / "e.png").size == (4 * 64, 64)
    assert main(["render", str(recorded), "--episode", "2", "--out", str(tmp_path / "e.gif"), "--size", "80"]) == 0
    gif = Image.open(tmp_path / "e.gif")
    durations = []
    for index in range(gif.n_frames):  # Pillow merges identical consecutive frames, adding their durations
        gif.seek(index)
        durations.append(gif.info["duration"])
    assert gif.size == (80, 80) and sum(durations) == 10 * 100  # 10 steps at the default 10 frames/s
    assert main(["render", str(recorded), "--episode", "9", "--out", str(tmp_path / "x.gif")]) == 2
    assert "no recorded episode 9; recorded: [2]" in capsys.readouterr().err
    assert main(["render", str(recorded), "--out", str(tmp_path / "x.mp4")]) == 2


def test_plot_refuses_a_group_by_key_that_no_run_has(tmp_path, capsys):
    _fake_run(tmp_path / "m/0", "adfq", 0, [1.0, 2.0])
    assert main(["plot", str(tmp_path / "m"), "--group-by", "algoo", "--out", str(tmp_path / "c.png")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "--group-by 'algoo'" in err
    assert "no run has this config key; every key: algo, algo.name, env.map, env.max_steps, seed\n" in err
    assert not (tmp_path / "c.png").exists()


def test_plot_refuses_a_group_by_key_that_every_run_leaves_unset(tmp_path, capsys):
    for seed in (0, 1):
        _fake_run(tmp_path / f"m/{seed}", "adfq", seed, [1.0, 2.0], method=None)
    assert main(["plot", str(tmp_path / "m"), "--group-by", "method", "--out", str(tmp_path / "c.png")]) == 2
    assert capsys.readouterr().err == ("aia-log: error: --group-by 'method': every run has method=None; the 2 runs "
                                       "differ in: seed; every key: algo, algo.name, env.map, env.max_steps, "
                                       "method, seed\n")


def test_summary_shows_a_failed_start(tmp_path, capsys):
    logger = MCAPLogger("exp", tmp_path)
    logger.log_hparams({"algo": {"name": "dqn"}})
    with pytest.raises(RuntimeError):
        try:
            raise RuntimeError("the env could not be built")
        finally:
            logger.close()
    assert main(["summary", str(tmp_path / "run.mcap")]) == 0
    captured = capsys.readouterr()
    assert "[failed: RuntimeError: the env could not be built]" in captured.out
    assert "failed: RuntimeError" in captured.err  # the warning of a run that is not complete


def test_summary_reports_a_damaged_chunk_in_one_line_and_reads_around_it(tmp_path, capsys):
    logger = MCAPLogger("exp", tmp_path, flush_interval_s=3600, compression="none")
    logger.log_hparams({"algo": {"name": "dqn"}, "seed": 0})
    for i in range(120):
        logger.log_scalar("eval/score", float(i), step=i)
        if i == 39:
            logger.flush()
            first_chunk_end = (tmp_path / "run.mcap").stat().st_size
        if i % 40 == 39:
            logger.flush()
    logger.close()
    data = bytearray((tmp_path / "run.mcap").read_bytes())
    data[first_chunk_end + 500] ^= 0x01  # inside the second chunk's records: only its CRC-32 tells
    (tmp_path / "run.mcap").write_bytes(bytes(data))
    assert main(["summary", str(tmp_path / "run.mcap")]) == 0
    captured = capsys.readouterr()
    damage = r"chunk 2 \(logged [-0-9: >]+\) fails its CRC-32 check: its messages are skipped"
    assert re.fullmatch(f"warning: {re.escape(str(tmp_path / 'run.mcap'))}: {damage}\n", captured.err)
    assert re.search(rf"\[{damage}\]", captured.out) and re.search(r"eval/score +aia.Scalar +80\n", captured.out)


def _stats_runs(root):
    """Two learners (5 seeds each, 10 evaluations) and a baseline of 4 runs, seeded."""
    rng = np.random.default_rng(0)
    for algo, level in (("adfq", 1500.0), ("dqn", 700.0)):
        for seed in range(5):
            _fake_run(root / f"m/{algo}{seed}", algo, seed, (level * (1 - np.exp(-np.arange(1, 11) / 3))
                                                             + rng.normal(0, 100, 10)).round(1).tolist())
    for seed in range(4):
        _fake_run(root / f"arvi/{seed}", "arvi", seed, [float(1000 + 50 * seed)], policy="arvi")


def test_stats_equals_rliable_called_directly(tmp_path, capsys):
    library, metrics = rliable_modules()
    _stats_runs(tmp_path)
    arguments = ["stats", str(tmp_path / "m"), "--group-by", "algo", "--baseline", str(tmp_path / "arvi"),
                 "--baseline-label", "ARVI", "--reps", "200", "--seed", "3"]
    assert main([*arguments, "--json"]) == 0
    printed = json.loads(capsys.readouterr().out)
    groups = {g["group"]: g for g in printed["groups"]}
    assert list(groups) == ["algo=adfq", "algo=dqn"] and printed["baselines"][0]["runs"] == 4
    baseline = np.array(printed["baselines"][0]["levels"])[:, None]
    assert baseline[:, 0].tolist() == [1000.0, 1050.0, 1100.0, 1150.0]
    for label, group in groups.items():
        levels = np.array(group["levels"])[:, None]  # 10 evaluations: a level is the last one
        np.random.seed(3)
        points, cis = library.get_interval_estimates(
            {label: levels}, lambda s: np.array([metrics.aggregate_iqm(s), metrics.aggregate_mean(s)]), reps=200)
        assert group["iqm"]["estimate"] == pytest.approx(points[label][0], rel=1e-12)
        assert group["iqm"]["ci"] == pytest.approx(cis[label][:, 0].tolist(), rel=1e-12)
        assert group["mean"]["ci"] == pytest.approx(cis[label][:, 1].tolist(), rel=1e-12)
        np.random.seed(3)
        points, cis = library.get_interval_estimates(
            {label: [levels, baseline]}, lambda x, y: np.array([metrics.probability_of_improvement(x, y)]), reps=200)
        comparison = group["comparisons"][0]
        assert comparison["probability_of_improvement"]["estimate"] == pytest.approx(points[label][0], rel=1e-12)
        assert comparison["probability_of_improvement"]["ci"] == pytest.approx(cis[label][:, 0].tolist(), rel=1e-12)
    assert groups["algo=adfq"]["comparisons"][0]["verdict"] == "above"
    assert groups["algo=dqn"]["comparisons"][0]["verdict"] == "below"
    assert groups["algo=dqn"]["comparisons"][0]["first_reaching"] == {"estimate": None, "ci": [None, None]}
    # the table: the same numbers, and the verdicts
    assert main([*arguments, "--x", "evaluation"]) == 0
    table = capsys.readouterr().out
    assert "95% stratified-bootstrap CIs (rliable, 200 resamples, seed 3)" in table
    assert "| P(above ARVI) [95% CI] | IQM - ARVI [95% CI] | vs ARVI | evaluation to reach ARVI [95% CI] |" in table
    adfq = groups["algo=adfq"]
    assert f"| algo=adfq | 5 | {adfq['iqm']['estimate']:.1f} [{adfq['iqm']['ci'][0]:.1f}, " in table
    assert "| above |" in table and "| below | never [never, never] |" in table


def test_stats_of_evaluations_has_no_column_of_reaching(tmp_path, capsys):
    """Runs of one evaluation each (aia-eval's): their verdicts, and no curve to reach a baseline along."""
    for seed in range(4):
        _fake_run(tmp_path / f"eval/{seed}", "dqn", seed, [1500.0 + 10 * seed])
        _fake_run(tmp_path / f"arvi/{seed}", "arvi", seed, [1000.0 + 50 * seed])
    arguments = ["stats", str(tmp_path / "eval"), "--baseline", str(tmp_path / "arvi"), "--baseline-label", "ARVI",
                 "--reps", "100"]
    assert main(arguments) == 0
    table = capsys.readouterr().out
    assert "| vs ARVI |\n" in table and "to reach" not in table and "| 1.00 [1.00, 1.00] |" in table
    assert "| above |\n" in table and "| ARVI (baseline) | 4 |" in table
    assert main([*arguments, "--json"]) == 0
    comparison = json.loads(capsys.readouterr().out)["groups"][0]["comparisons"][0]
    assert comparison["verdict"] == "above" and comparison["first_reaching"] is None


def test_stats_refuses_a_bad_group_key_too_few_runs_and_bad_options_in_one_line(tmp_path, capsys):
    _stats_runs(tmp_path)
    runs = str(tmp_path / "m")
    for arguments, message in (
            (["--group-by", "algoo"], "--group-by 'algoo': no run has this config key; the 10 runs differ in: "
                                      "algo, seed; every key: algo, algo.name"),
            (["--group-by", "seed"], "'seed=0' has 2 runs: --statistic iqm needs at least 4 (iqm needs 4, mean "
                                     "needs 2)"),
            # named without --baseline-label by the policy of aia-eval's runs
            (["--baseline", str(tmp_path / "arvi/0")], "'arvi' has 1 run: --statistic iqm needs at least 4"),
            (["--statistic", "median"], "argument --statistic: invalid choice: 'median' (choose from 'iqm', 'mean')"),
            (["--verdict-by", "ci"], "invalid choice: 'ci' (choose from 'poi', 'difference')"),
            (["--ci-level", "95"], "--ci-level 95.0: expected a number in (0, 1), e.g. 0.95"),
            (["--reps", "x"], "argument --reps: invalid int value: 'x'"),
            (["--baseline-label", "ARVI"], "--baseline-label 'ARVI' without --baseline: name the baseline's runs"),
            (["--metric", "eval/nope"], "--metric 'eval/nope': no run has logged it; expected a scalar topic of the "
                                        "runs: eval/score"),
            (["--where", "seed=7"], "matches --where seed=7")):
        assert main(["stats", runs, *arguments]) == 2, arguments
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and message in err and err.startswith("aia-log"), err
    # with the mean, 2 runs per group are enough; their IQM, which would trim nothing, is not given
    assert main(["stats", runs, "--group-by", "seed", "--statistic", "mean", "--reps", "50"]) == 0
    assert "| seed=0 | 2 | (needs 4 runs) | " in capsys.readouterr().out
    assert main(["stats", runs, "--group-by", "seed", "--statistic", "mean", "--reps", "50", "--json"]) == 0
    assert {group["iqm"] for group in json.loads(capsys.readouterr().out)["groups"]} == {None}


def test_plot_with_bootstrap_bands(tmp_path, capsys, monkeypatch):
    """Curves and the baseline as the statistic with its CI; the baseline's line and band are aia-log stats' IQM
    and CI of its runs' levels."""
    import matplotlib.axes

    _stats_runs(tmp_path)
    out = tmp_path / "ci.png"
    drawn = {}
    axhline, axhspan = matplotlib.axes.Axes.axhline, matplotlib.axes.Axes.axhspan

    def line(self, y, **kw):
        drawn["line"] = (y, kw["label"])
        return axhline(self, y, **kw)

    def band(self, low, high, **kw):
        drawn["band"] = (low, high)
        return axhspan(self, low, high, **kw)

    monkeypatch.setattr(matplotlib.axes.Axes, "axhline", line)
    monkeypatch.setattr(matplotlib.axes.Axes, "axhspan", band)
    baseline = ["--baseline", str(tmp_path / "arvi"), "--baseline-label", "ARVI", "--reps", "100", "--seed", "3"]
    assert main(["plot", str(tmp_path / "m"), "--group-by", "algo", "--ci", "bootstrap", *baseline,
                 "--out", str(out)]) == 0
    assert "algo=adfq: 5 runs" in capsys.readouterr().out and Image.open(out).format == "PNG"
    assert main(["stats", str(tmp_path / "m"), "--group-by", "algo", *baseline, "--json"]) == 0
    iqm = json.loads(capsys.readouterr().out)["baselines"][0]["iqm"]
    assert drawn["line"] == (iqm["estimate"], "ARVI (4 runs, IQM and 95% CI)") and drawn["band"] == tuple(iqm["ci"])
    assert main(["plot", str(tmp_path / "m"), "--group-by", "seed", "--ci", "bootstrap", "--out", str(out)]) == 2
    assert "'seed=0' has 2 runs: --statistic iqm needs at least 4" in capsys.readouterr().err
