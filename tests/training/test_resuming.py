"""Preemption: a signal ends the run at the end of its episode with every evaluation, a checkpoint and a log
marked stopped; resume=auto continues in the same folder into the log's next segment, and the joined history
is the uninterrupted run's (counters, evaluation frames, scores), after a signal and after kill -9;
checkpoints of another run are refused."""

from __future__ import annotations

import signal
import subprocess
import sys
import time

import pytest
import torch
from hydra import compose, initialize_config_module

from aia.apps.train import report
from aia.config.errors import ConfigError
from aia.logging import find_runs, read_run
from aia.runtime.stopping import StopOnSignals
from aia.training import train
from aia.training.resuming import load_resumable, resume_path, resume_point

SMALL = ("env.max_steps=40", "warmup_frames=100", "eval.episodes=2", "batch_size=16", "hidden=[32,32]",
         "algo=adfq", "exploration=thompson")
LOGGED = (*SMALL, "logger.record_every_evaluations=0")


def _config(*overrides: str):
    with initialize_config_module(config_module="aia.conf", version_base="1.3"):
        return compose(config_name="train", overrides=list(overrides))


class SignalAfter(StopOnSignals):
    """A SIGTERM that arrives after the loop's ``steps``-th step (the loop reads ``signal`` once a step)."""

    def __init__(self, steps: int) -> None:
        super().__init__()
        self.reads = steps

    @property
    def signal(self) -> int | None:
        self.reads -= 1
        return signal.SIGTERM if self.reads < 0 else None

    @signal.setter
    def signal(self, value: int | None) -> None:
        pass


def test_a_signal_ends_the_episode_then_checkpoints_and_resume_auto_continues_one_history(tmp_path, capsys):
    whole = train(_config(*LOGGED, "frames=240"), tmp_path / "whole")
    stopped = train(_config(*LOGGED, "frames=240"), tmp_path / "run", stop=SignalAfter(130))
    assert stopped.frames == 160  # the episode under way at the signal (frames 121-160) was finished
    assert len(stopped.eval_scores) == 4 and stopped.eval_scores == whole.eval_scores[:4]
    first = read_run(tmp_path / "run" / "run.mcap")
    assert first.complete and first.failure.startswith("stopped: SIGTERM at frame 160")
    checkpoint = torch.load(tmp_path / "run" / "checkpoints" / "last.pt", weights_only=False)
    assert checkpoint["state"]["frames"] == 160

    resumed = train(_config(*LOGGED, "frames=240", "resume=auto"), tmp_path / "run")
    assert (resumed.frames, resumed.updates, resumed.episodes, resumed.evaluations) == (
        whole.frames, whole.updates, whole.episodes, whole.evaluations)
    assert resumed.eval_scores == pytest.approx(whole.eval_scores, rel=1e-5)
    assert (tmp_path / "run" / "run.1.mcap").is_file()
    capsys.readouterr()
    report(_config(*LOGGED, "frames=240", "resume=auto"), tmp_path / "run", resumed)  # what aia-train prints
    run = tmp_path / "run"
    assert f"log written to {run / 'run.1.mcap'} (the run's whole history: aia-log summary {run / 'run.mcap'})" in (
        capsys.readouterr().out)
    joined, alone = read_run(tmp_path / "run" / "run.mcap"), read_run(tmp_path / "whole" / "run.mcap")
    assert joined.complete and joined.failure is None and len(joined.segments) == 1
    for topic in ("eval/score", "train/score"):
        assert joined.scalars(topic).frames.tolist() == alone.scalars(topic).frames.tolist()
    assert joined.scalars("eval/score").values.tolist() == pytest.approx(alone.scalars("eval/score").values, rel=1e-5)
    assert find_runs([str(tmp_path / "run")]) == [tmp_path / "run" / "run.mcap"]  # one run, not two
    # continued once more when finished (resume=auto over a whole protocol): nothing trained, written or lost
    saved = (tmp_path / "run" / "checkpoints" / "last.pt").stat().st_mtime_ns
    again = train(_config(*LOGGED, "frames=240", "resume=auto"), tmp_path / "run")
    assert "finished already at frame 240 (frames=240): nothing to train" in capsys.readouterr().out
    assert again == resumed and not (tmp_path / "run" / "run.2.mcap").exists()
    assert (tmp_path / "run" / "checkpoints" / "last.pt").stat().st_mtime_ns == saved


def test_resume_auto_without_a_checkpoint_starts_fresh(tmp_path):
    state = train(_config(*SMALL, "frames=120", "resume=auto", "logger=none"), tmp_path)
    assert state.frames == 120 and (tmp_path / "checkpoints" / "last.pt").is_file()


def test_a_checkpoint_of_another_run_is_refused_naming_each_difference(tmp_path):
    """Each differing setting is named; a setting added after the checkpoint was written (``env.features.im_size``
    and ``conv_layers`` taken out of its config) matches a run that leaves it at its default, not one that sets it."""
    train(_config(*SMALL, "frames=120", "logger=none"), tmp_path / "a")
    path = tmp_path / "a" / "checkpoints" / "last.pt"
    checkpoint = torch.load(path, weights_only=False)
    del checkpoint["config"]["env"]["features"]["im_size"], checkpoint["config"]["conv_layers"]
    older = tmp_path / "older.pt"
    torch.save(checkpoint, older)
    assert load_resumable(older, _config(*SMALL, "frames=200"), "cpu")["state"]["frames"] == 120
    with pytest.raises(ConfigError, match=r"differs in env.features.im_size \(None in the checkpoint, 8 now\)$"):
        load_resumable(older, _config(*SMALL, "frames=200", "env.features.im_size=8"), "cpu")
    with pytest.raises(ConfigError, match=r"differs in env.map \('empty' in the checkpoint, 'empty_small' now\)"
                                          r".*hidden \(\[32, 32\] in the checkpoint, \[64\] now\)"):
        train(_config(*SMALL, "frames=200", "env=small2", "hidden=[64]", "logger=none", f"resume={path}"),
              tmp_path / "b")
    broken = tmp_path / "broken.pt"
    broken.write_text("not a checkpoint")
    with pytest.raises(ConfigError, match=f"resume='{broken}': expected an undamaged checkpoint, but it is not a "
                                          "whole zip archive"):
        train(_config(*SMALL, "frames=200", "logger=none", f"resume={broken}"), tmp_path / "c")


def test_resume_point_is_where_a_run_continues_without_loading_it_for_training(tmp_path):
    """What the population launcher groups jobs by: a fresh start (no resume, or auto without a checkpoint),
    the checkpoint's counters, or the path of a file that is no checkpoint (its run then fails alone)."""
    cfg = _config(*SMALL, "frames=120", "logger=none")
    assert resume_point(cfg, tmp_path / "a") is None
    auto = _config(*SMALL, "frames=200", "logger=none", "resume=auto")
    assert resume_point(auto, tmp_path / "a") is None
    state = train(cfg, tmp_path / "a")
    assert resume_point(auto, tmp_path / "a") == (120, state.updates, state.episodes, state.evaluations) == (
        120, 21, 3, 3)
    # no resume asked for, over a run: that job fails alone (resume_path's refusal)
    assert resume_point(cfg, tmp_path / "a") == str(tmp_path / "a" / "checkpoints" / "last.pt")
    with pytest.raises(ConfigError, match=r"^resume=null: expected auto to continue the run in .*last.pt is there"):
        train(cfg, tmp_path / "a")
    assert resume_point(auto, tmp_path / "a")[0] == 120  # its checkpoint is as it was
    broken = tmp_path / "broken.pt"
    broken.write_text("not a checkpoint")
    assert resume_point(_config(*SMALL, f"resume={broken}"), tmp_path / "b") == str(broken)


def test_a_fresh_run_over_a_run_log_alone_is_refused_and_the_log_kept(tmp_path):
    # a run killed before its first checkpoint leaves its log only; resume=auto continues it as a fresh start
    (tmp_path / "run.mcap").write_bytes(b"an earlier run's log")
    with pytest.raises(ConfigError, match=r"^resume=null: expected auto .*run.mcap is there"):
        resume_path(_config(*SMALL), tmp_path)
    assert resume_path(_config(*SMALL, "resume=auto"), tmp_path) is None
    assert resume_path(_config(*SMALL, "logger=csv"), tmp_path) is None  # no run log of that name
    assert (tmp_path / "run.mcap").read_bytes() == b"an earlier run's log"


def test_resume_auto_after_kill_9_gives_the_uninterrupted_history(tmp_path):
    """A run killed outright after a checkpoint: its log holds steps the resumed run does again; the joined
    history drops them, so it is the uninterrupted run's, evaluation by evaluation. Flushing by time is off
    (an hour): every evaluation reaches the killed run's log file because each evaluation flushes it."""
    overrides = [*LOGGED, "checkpoint_every_frames=80", "eval.per_rollout=1", "logger.flush_interval_s=3600",
                 "threads=1"]
    run_dir = tmp_path / "run"
    process = subprocess.Popen([sys.executable, "-m", "aia.apps.train", *overrides, "frames=100000",
                                f"hydra.run.dir={run_dir}"], stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
                               text=True)
    deadline = time.monotonic() + 240
    checkpoint, log = run_dir / "checkpoints" / "last.pt", run_dir / "run.mcap"

    def evaluated_past_the_checkpoint() -> bool:
        if not (checkpoint.exists() and log.exists()) or "eval/score" not in read_run(log).scalar_topics():
            return False
        frames = torch.load(checkpoint, weights_only=False)["state"]["frames"]
        return frames >= 160 and read_run(log).scalars("eval/score").frames.max() > frames

    while not evaluated_past_the_checkpoint():
        assert time.monotonic() < deadline and process.poll() is None, process.stderr.read()[-2000:]
        time.sleep(0.2)
    process.kill()
    process.wait(timeout=60)
    saved = torch.load(checkpoint, weights_only=False)["state"]["frames"]
    frames = saved + 80
    resumed = train(_config(*overrides, f"frames={frames}", "resume=auto"), run_dir)
    whole = train(_config(*overrides, f"frames={frames}"), tmp_path / "whole")
    assert resumed.eval_scores == pytest.approx(whole.eval_scores, rel=1e-5)
    joined, alone = read_run(log), read_run(tmp_path / "whole" / "run.mcap")
    assert joined.segments == [run_dir / "run.1.mcap"]  # the resumed run's segment, joined
    for topic in ("eval/score", "train/score"):
        assert joined.scalars(topic).frames.tolist() == alone.scalars(topic).frames.tolist(), topic
