"""hydra/launcher=population: one -m command trains its jobs as populations (2 and 3 members here), each job
with its own folder, configs, log and checkpoint; a sweep that cannot share a program splits, saying why;
a member with a bad config fails its own job only; a member equals the same job run alone. The app runs
in-process (``main()`` with ``sys.argv`` patched)."""

from __future__ import annotations

import os
import re
import sys

import pytest
import torch
import yaml
from hydra._internal.config_loader_impl import ConfigLoaderImpl
from hydra.core.plugins import Plugins
from hydra.core.utils import JobStatus

import aia.apps.train as train_app
from aia.logging import read_run
from aia.runtime import cpu_threads

LAUNCHER = "hydra_plugins.aia_population_launcher.population_launcher.PopulationLauncher"
SMALL = ["frames=130", "warmup_frames=100", "env.max_steps=30", "eval.episodes=2", "batch_size=16",
         "logger.record_every_evaluations=0", "hydra/launcher=population"]


def _jobs(tmp_path, **jobs: tuple[int, list[int]]) -> list[str]:
    """Overrides sweeping a config group ``job`` whose options set a seed and a network each (the way to
    give one -m command groups of different sizes): ``name=(seed, hidden)``."""
    folder = tmp_path / "conf" / "job"
    folder.mkdir(parents=True)
    for name, (seed, hidden) in jobs.items():
        (folder / f"{name}.yaml").write_text(f"# @package _global_\nseed: {seed}\nhidden: {hidden}\n")
    return [f"hydra.searchpath=[file://{tmp_path / 'conf'}]", f"+job={','.join(jobs)}"]


def _multirun(tmp_path, monkeypatch, capsys, *overrides: str, exit_code: int | None = None, processes: int = 1
              ) -> tuple[list, str]:
    """The JobReturns of ``aia-train -m ...`` and what it printed (``exit_code``: the app's exit status when a
    job fails, which Hydra reports at the end of the sweep: 2 for invalid input; ``processes``: populations at
    a time, ``hydra.launcher.n_jobs``)."""
    returns = []
    # the launcher class Hydra's plugin scan found (the scan imports the module afresh)
    launcher = Plugins.instance().class_name_to_class[LAUNCHER]
    launch = launcher.launch

    def spy(self, job_overrides, initial_job_idx):
        returns.extend(launch(self, job_overrides, initial_job_idx))
        return returns

    monkeypatch.setattr(launcher, "launch", spy)
    monkeypatch.setattr(sys, "argv", ["aia-train", "-m", f"hydra.sweep.dir={tmp_path / 'sweep'}", *SMALL,
                                      f"hydra.launcher.n_jobs={processes}", *overrides])
    capsys.readouterr()
    if exit_code is not None:
        with pytest.raises(SystemExit) as info:
            train_app.main()
        assert info.value.code == exit_code
    else:
        train_app.main()
    # only the workers' fork server is marked as one: a fork of the launcher's own process still counts as forked
    assert not cpu_threads._FORK_SERVER
    return returns, capsys.readouterr().out


def test_one_sweep_trains_a_2_and_a_3_member_population(tmp_path, monkeypatch, capsys):
    jobs = _jobs(tmp_path, a=(0, [16]), b=(1, [16]), c=(2, [24]), d=(3, [24]), e=(4, [24]))
    composed = []
    compose = ConfigLoaderImpl.load_sweep_config

    def counting(self, master_config, sweep_overrides):
        composed.append(list(sweep_overrides))
        return compose(self, master_config, sweep_overrides)

    monkeypatch.setattr(ConfigLoaderImpl, "load_sweep_config", counting)
    returns, out = _multirun(tmp_path, monkeypatch, capsys, *jobs)
    assert len(composed) == 5  # each job's config composed once (the sweeper's check; the launcher reuses it)
    assert "5 jobs in 2 populations of 2 and 3 members" in out
    assert "as a population of 2, seeds [0, 1]" in out and "as a population of 3, seeds [2, 3, 4]" in out
    # a population's shared counters and time once, then a line per member naming its seed and log
    assert out.count("population of 2 trained: 130 frames") == 1 and out.count("population of 3 trained:") == 1
    assert out.count("time: ") == 2
    # a line as each population ends: how many of all, after how long, which jobs
    assert re.search(r"population launcher: 1/2 done after 0:\d\d: jobs 0-1\n", out)
    assert re.search(r"population launcher: 2/2 done after 0:\d\d: jobs 2-4\n", out)
    assert [r.status for r in returns] == [JobStatus.COMPLETED] * 5
    assert [r.hydra_cfg.hydra.job.num for r in returns] == [0, 1, 2, 3, 4]
    for job, ret in enumerate(returns):
        folder = tmp_path / "sweep" / str(job)
        assert ret.working_dir and (folder / "checkpoints" / "last.pt").is_file()
        overrides = yaml.safe_load((folder / ".hydra" / "overrides.yaml").read_text())
        assert f"+job={'abcde'[job]}" in overrides
        run = read_run(folder / "run.mcap")
        assert run.complete and run.config_value("seed") == job
        assert run.config_value("hidden") == ([16] if job < 2 else [24])
        assert ret.return_value == pytest.approx(run.scalars("eval/score").values[-1])  # the search objective
        last, lr = run.scalars("eval/score").values[-1], run.config_value("lr")
        assert f" seed {job} lr {lr:g}: last eval score {last:.1f}, log {folder / 'run.mcap'}\n" in out
    assert (tmp_path / "sweep" / "multirun.yaml").is_file()


def test_a_mixed_sweep_splits_and_says_which_key_kept_a_job_apart(tmp_path, monkeypatch, capsys):
    returns, out = _multirun(tmp_path, monkeypatch, capsys, "seed=0,1", "lr=1e-3,5e-4", "hidden=[16],[24]")
    assert "8 jobs in 2 populations of 4 members each" in out
    assert [r.status for r in returns] == [JobStatus.COMPLETED] * 8


def test_a_sweep_over_methods_plots_grouped_by_method(tmp_path, monkeypatch, capsys):
    """The issue's workflow: ``-m method=... seed=...`` trains a population per method, and ``aia-log plot
    <sweep> --group-by method`` reads each run's method from its log."""
    from aia.apps.log_cli import main as log_main

    returns, out = _multirun(tmp_path, monkeypatch, capsys, "method=dqn,ddqn,adfq_ts", "seed=0,1")
    # DQN and Double DQN share a network and a loss: one population of 4
    assert "6 jobs in 2 populations of 4 and 2 members" in out
    assert "training dqn (egreedy), ddqn (egreedy) on empty with 1 target(s) for 130 frames as a population of 4" in out
    assert [r.status for r in returns] == [JobStatus.COMPLETED] * 6
    assert log_main(["plot", str(tmp_path / "sweep"), "--group-by", "method", "--out", str(tmp_path / "m.png")]) == 0
    out = capsys.readouterr().out
    assert "method=adfq_ts: 2 runs" in out and "method=dqn: 2 runs" in out and "method=ddqn: 2 runs" in out
    assert [read_run(tmp_path / "sweep" / str(job) / "run.mcap").config_value("algo.name") for job in range(4)] == [
        "dqn", "dqn", "ddqn", "ddqn"]


def test_a_member_with_a_bad_value_fails_alone(tmp_path, monkeypatch, capsys):
    returns, out = _multirun(tmp_path, monkeypatch, capsys, "seed=0,1", "lr=1e-3,-1", exit_code=2)
    assert re.search(r"population launcher: 1/1 done after 0:\d\d: jobs 0-3 \(2 of 4 failed\)\n", out)
    assert [r.status for r in returns] == [JobStatus.COMPLETED, JobStatus.FAILED, JobStatus.COMPLETED,
                                           JobStatus.FAILED]
    assert "lr=-1" in str(returns[1]._return_value)
    sweep = tmp_path / "sweep"
    assert read_run(sweep / "0" / "run.mcap").complete and not (sweep / "1" / "run.mcap").exists()


def _task_module(tmp_path, monkeypatch, name: str, body: str) -> str:
    """A population entry ``<name>.jobs`` that runs ``body`` (Python, with ``cfgs`` at hand) before training,
    importable in this process and in the launcher's worker processes; returns its dotted path."""
    lines = "\n    ".join(body.splitlines())
    (tmp_path / f"{name}.py").write_text("import os\nfrom aia.apps.train import train_jobs\n\n\n"
                                         f"def jobs(cfgs, out_dirs):\n    {lines}\n"
                                         "    return train_jobs(cfgs, out_dirs)\n")
    monkeypatch.syspath_prepend(str(tmp_path))  # a worker is handed this process's sys.path as it starts
    return f"{name}.jobs"


def test_a_population_whose_process_dies_fails_alone_and_the_others_train(tmp_path, monkeypatch, capsys):
    """A worker process that dies (here ``os._exit(9)``; the OOM killer's SIGKILL alike) fails its own
    population's jobs, named in one line; the population in the other worker trains to its end. The workers are
    forked from the fork server, which ran no parallel region: they run kernels on torch's OpenMP team."""
    body = ("if list(cfgs[0].hidden) == [24]:\n    os._exit(9)\n"
            "from aia.runtime import cpu_threads\n(out_dirs[0].parent / 'forked').write_text(str(cpu_threads._FORKED))")
    task = _task_module(tmp_path, monkeypatch, "dying", body)
    jobs = _jobs(tmp_path, a=(0, [16]), b=(1, [16]), c=(2, [24]), d=(3, [24]))
    returns, out = _multirun(tmp_path, monkeypatch, capsys, *jobs, f"hydra.launcher.task={task}",
                             "hydra.launcher.progress_every_s=0", exit_code=1, processes=2)
    assert [r.status for r in returns] == [JobStatus.COMPLETED] * 2 + [JobStatus.FAILED] * 2
    died = "jobs 2-3: the process running their population exited with status 9 before returning its results"
    assert died in str(returns[2]._return_value) and died in str(returns[3]._return_value)
    assert re.search(r"population launcher: \d/2 done after 0:\d\d: jobs 2-3 \(2 of 2 failed\)\n", out)
    assert all(read_run(tmp_path / "sweep" / str(job) / "run.mcap").complete for job in (0, 1))
    assert (tmp_path / "sweep" / "forked").read_text() == "False"
    # the worker's lines and its bar's progress reach the launcher, which prints them whole
    assert re.search(r"\ntraining dqn \(egreedy\) on .* as a population of 2, seeds \[0, 1\]\n", out)
    assert re.search(r"\npopulation launcher: jobs 0-1: dqn x2 130/130 frames \(100%\), [\d,]+ frames/s", out)


def test_a_population_stopped_by_a_signal_ends_the_sweep_after_the_running_ones(tmp_path, monkeypatch, capsys):
    """A population stopped by a signal (its members checkpointed: the app exits with 128 + signal) stops the
    sweep as a solo run stops: the population running beside it ends, the waiting one never starts, and the
    launcher exits with that status."""
    # the launcher starts the largest populations first: [32] (stops at once) beside [24]; [16] waits
    stop_at_once = "if list(cfgs[0].hidden) == [32]:\n    raise SystemExit(143)"
    task = _task_module(tmp_path, monkeypatch, "stopping", stop_at_once)
    jobs = _jobs(tmp_path, a=(0, [16]), b=(1, [24]), c=(2, [32]))
    returns, _ = _multirun(tmp_path, monkeypatch, capsys, *jobs, f"hydra.launcher.task={task}", exit_code=143,
                           processes=2)
    assert returns == []  # the sweep ended on the signal, as a solo run's SystemExit ends it
    sweep = tmp_path / "sweep"
    assert read_run(sweep / "1" / "run.mcap").complete  # ran beside the stopped one, to its end
    assert not (sweep / "0" / "run.mcap").exists()  # waiting when the signal came: never started


def test_a_signal_to_the_launcher_alone_stops_the_running_populations_with_their_checkpoints(
        tmp_path, monkeypatch, capsys):
    """``kill PID`` (or a container's stop) signals the launcher only: it forwards the signal to the running
    workers, whose populations end their episode, checkpoint and mark their logs stopped; the waiting one never
    starts, and the launcher exits with 143. Both running populations are held at their first episode's end
    until both are training; then one signals the launcher and waits for the forwarded signal."""
    at_first_episode_end = (
        "import signal, time\n"
        "from pathlib import Path\n"
        "from aia.training import loop\n"
        f"flags = Path({str(tmp_path)!r})\n"
        "end_episodes = loop._Run.end_episodes\n"
        "def held(self, *args):\n"
        "    if not hasattr(held, 'done'):\n"
        "        held.done = True\n"
        "        (flags / f'training{list(cfgs[0].hidden)[0]}').touch()\n"
        "        if list(cfgs[0].hidden) == [32]:\n"
        "            while not (flags / 'training24').exists():\n"
        "                time.sleep(0.01)\n"
        f"            os.kill({os.getpid()}, signal.SIGTERM)\n"  # the launcher: this test's process
        "        time.sleep(2)  # the forwarded signal arrives meanwhile\n"
        "    return end_episodes(self, *args)\n"
        "loop._Run.end_episodes = held")
    task = _task_module(tmp_path, monkeypatch, "signalling", at_first_episode_end)
    jobs = _jobs(tmp_path, a=(0, [16]), b=(1, [24]), c=(2, [32]))
    returns, out = _multirun(tmp_path, monkeypatch, capsys, *jobs, f"hydra.launcher.task={task}", exit_code=143,
                             processes=2)
    assert returns == []
    assert "population launcher: SIGTERM: the running populations stop at the end of their episodes" in out
    sweep = tmp_path / "sweep"
    for job in (1, 2):  # stopped at the end of the first episode (30 frames of 130)
        run = read_run(sweep / str(job) / "run.mcap")
        assert run.complete and run.failure.startswith("stopped: SIGTERM at frame 30")
        checkpoint = torch.load(sweep / str(job) / "checkpoints" / "last.pt", weights_only=False)
        assert checkpoint["state"]["frames"] == 30
    assert not (sweep / "0" / "run.mcap").exists()


def test_a_grown_sweep_resumes_its_old_jobs_and_starts_its_new_ones_as_populations_apart(
        tmp_path, monkeypatch, capsys):
    """``-m seed=0,1`` then ``-m seed=0,1,2 resume=auto`` with a larger budget: jobs 0-1 continue from their
    checkpoints as one population, job 2 starts fresh in another (one population of all three would be refused:
    its members must all resume from one point)."""
    _multirun(tmp_path, monkeypatch, capsys, "seed=0,1")
    monkeypatch.undo()  # the launcher's spy and sys.argv, set again below
    returns, out = _multirun(tmp_path, monkeypatch, capsys, "seed=0,1,2", "frames=160", "resume=auto")
    assert "3 jobs in 2 populations of 2 and 1 members" in out
    assert "population launcher: jobs 0-1: resuming from frame 130 (a population of their own)" in out
    assert "population launcher: job 2: starting fresh (a population of its own)" in out
    assert [r.status for r in returns] == [JobStatus.COMPLETED] * 3
    # the old jobs' episode under way at frame 130 was abandoned (a resumed run starts the next one)
    episode_ends = {0: [30, 60, 90, 120, 160], 1: [30, 60, 90, 120, 160], 2: [30, 60, 90, 120, 150]}
    for job in range(3):
        run = read_run(tmp_path / "sweep" / str(job) / "run.mcap")
        assert run.complete and run.scalars("train/score").frames.tolist() == episode_ends[job]
        checkpoint = torch.load(tmp_path / "sweep" / str(job) / "checkpoints" / "last.pt", weights_only=False)
        assert checkpoint["state"]["frames"] == 160
    assert f"resuming from {tmp_path / 'sweep' / '0' / 'checkpoints' / 'last.pt'} at frame 130" in out
    # the sweep grown again without resume=auto: the runs there are refused, each alone, the new job trains
    monkeypatch.undo()
    returns, out = _multirun(tmp_path, monkeypatch, capsys, "seed=0,1,2,3", "frames=160", exit_code=2)
    assert "population launcher: job 0: cannot start from " in out
    assert [r.status for r in returns] == [JobStatus.FAILED] * 3 + [JobStatus.COMPLETED]
    assert "resume=null: expected auto to continue the run in" in str(returns[0]._return_value)
    kept = torch.load(tmp_path / "sweep" / "0" / "checkpoints" / "last.pt", weights_only=False)
    assert kept["state"]["frames"] == 160  # the refused job's checkpoint as it was


def test_a_job_that_differs_from_all_others_runs_alone_and_says_why(tmp_path, monkeypatch, capsys):
    jobs = _jobs(tmp_path, a=(0, [16]), b=(1, [16]), c=(2, [24]))
    returns, out = _multirun(tmp_path, monkeypatch, capsys, *jobs)
    assert "job 2 runs alone: its hidden=[24] differs from job 0's [16]" in out
    assert [r.status for r in returns] == [JobStatus.COMPLETED] * 3


def test_an_app_without_a_population_entry_is_named(tmp_path, monkeypatch, capsys):
    import aia.apps.rollout as rollout_app

    monkeypatch.setattr(sys, "argv", ["aia-rollout", "-m", "seed=0,1", "hydra/launcher=population",
                                      f"hydra.sweep.dir={tmp_path}"])
    with pytest.raises(SystemExit) as info:
        rollout_app.main()
    assert info.value.code == 2
    assert "hydra.launcher.task=null: expected the dotted path of a population entry" in capsys.readouterr().err
    assert not (tmp_path / "0").exists()  # refused before any job was prepared


@pytest.mark.parametrize("override, message", [
    ("hydra.launcher.n_jobs=0", "hydra.launcher.n_jobs=0: expected an integer >= 1"),
    ("hydra.launcher.n_jobs=abc", "hydra.launcher.n_jobs='abc': expected an integer >= 1"),
    ("hydra.launcher.split_to_fill=maybe", "hydra.launcher.split_to_fill='maybe': expected true or false"),
    ("hydra.launcher.progress_every_s=-1", "hydra.launcher.progress_every_s=-1: expected a number >= 0"),
    ("hydra.launcher.task=nope.train_jobs", "hydra.launcher.task='nope.train_jobs': expected the dotted path of"),
    ("hydra.launcher.task=aia.apps.train.nope", "hydra.launcher.task='aia.apps.train.nope': expected the dotted"),
])
def test_a_bad_launcher_setting_gets_one_line_before_any_job_folder(tmp_path, monkeypatch, capsys, override,
                                                                    message):
    monkeypatch.setattr(sys, "argv", ["aia-train", "-m", "seed=0,1", "hydra/launcher=population", override,
                                      f"hydra.sweep.dir={tmp_path}"])
    with pytest.raises(SystemExit) as info:
        train_app.main()
    assert info.value.code == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and message in err
    assert not (tmp_path / "0").exists()


@pytest.mark.parametrize("groups, processes, expected", [
    ([[0, 1, 2, 3, 4]], 2, [[0, 1, 2], [3, 4]]),
    ([[0, 1, 2, 3, 4]], 4, [[0], [1], [2], [3, 4]]),  # ties: the first of the largest
    ([[0, 1], [2, 3, 4, 5]], 3, [[0, 1], [2, 3], [4, 5]]),
    ([[0], [1]], 4, [[0], [1]]),  # no group left to split
    ([[0, 1, 2]], 1, [[0, 1, 2]]),  # enough processes already
])
def test_split_to_fill_splits_the_largest_group_until_every_process_has_one(groups, processes, expected):
    from hydra_plugins.aia_population_launcher.population_launcher import split_to_fill

    assert split_to_fill(groups, processes) == expected


@pytest.mark.parametrize("groups, expected", [
    ([[0, 1]], "1 population of 2 members"),
    ([[0]], "1 population of 1 member"),
    ([[0], [1], [2]], "3 populations of 1 member each"),
    ([[0, 1], [2, 3]], "2 populations of 2 members each"),
    ([[0, 1], [2, 3, 4], [5]], "3 populations of 2, 3 and 1 members"),
])
def test_the_launcher_counts_populations_and_members_in_words(groups, expected):
    from hydra_plugins.aia_population_launcher.population_launcher import _sizes

    assert _sizes(groups) == expected
    assert _sizes(groups, "process", "processes") == expected.replace("populations", "processes").replace(
        "population", "process")


def test_largest_first_orders_groups_by_their_work():
    from omegaconf import OmegaConf

    from hydra_plugins.aia_population_launcher.population_launcher import largest_first

    cfgs = [OmegaConf.create(c) for c in (
        {"frames": 100, "hidden": [128, 128], "algo": {"name": "dqn"}},  # work per member 100 x 2 = 200
        {"frames": 100, "hidden": [128, 128], "algo": {"name": "dqn"}},
        {"frames": 100, "hidden": [256, 256, 256], "algo": {"name": "dqn"}},  # 100 x 4 = 400
        {"frames": 300, "hidden": [128, 128], "algo": {"name": "ddqn"}},  # 600
        {"episodes": 5},  # an evaluation: 5
        {"frames": 100, "hidden": [256, 256, 256], "algo": {"name": "adfq"}},  # 400 x 1.2 = 480
    )]
    # 600, 480, 400 (a tie: kept in order), 400, 5
    assert largest_first([[0, 1], [2], [3], [4], [5]], cfgs) == [[3], [5], [0, 1], [2], [4]]
