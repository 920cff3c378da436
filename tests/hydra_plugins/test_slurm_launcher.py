"""hydra/launcher=population_slurm without a scheduler: what a population's SLURM task does when it stops (asks
its batch script to requeue it, leaves no result, or returns the stop), how a task run again resumes its
members, the resource tracker that a task's signal must not kill, each task's outcome as its jobs see it, and
bad launcher settings. ``tests/cluster/test_slurm.py`` runs the launcher on the local SLURM."""

from __future__ import annotations

import contextlib
import os
import re
import signal
import subprocess
import sys
import textwrap
import uuid
from pathlib import Path
from types import SimpleNamespace

import pytest
import submitit
from hydra.core.plugins import Plugins
from hydra.core.utils import JobStatus

import aia.apps.train as train_app
from aia.config.errors import JobFailed
from aia.training.checkpoint_names import CHECKPOINT_NAME
from hydra_plugins.aia_population_launcher import slurm


@pytest.fixture
def entry(tmp_path, monkeypatch):
    """A population entry ``<module>.jobs`` (a module of its own per test) that records each member's
    ``resume`` in ``resumes.txt`` and then exits with the status in ``exit.txt`` (a population stopped by that
    signal, after checkpointing) or, if there is none, returns one objective per member."""
    module = f"fake_entry_{uuid.uuid4().hex}"
    (tmp_path / f"{module}.py").write_text(textwrap.dedent(f"""
        from pathlib import Path

        def jobs(cfgs, out_dirs):
            Path({str(tmp_path)!r}, "resumes.txt").write_text(" ".join(str(cfg.resume) for cfg in cfgs))
            status = Path({str(tmp_path)!r}, "exit.txt")
            if status.exists():
                raise SystemExit(int(status.read_text()))
            return [1.5] * len(cfgs)
        """))
    monkeypatch.syspath_prepend(str(tmp_path))
    return f"{module}.jobs"


def _call(entry: str, tmp_path, resumes=(None, None)) -> slurm.Call:
    """Two members in job folders ``a`` and ``b`` (each made), with these ``resume`` values."""
    out_dirs = [tmp_path / "a", tmp_path / "b"]
    for out_dir in out_dirs:
        out_dir.mkdir(parents=True, exist_ok=True)
    return entry, [{"seed": k, "resume": resume} for k, resume in enumerate(resumes)], [str(d) for d in out_dirs], 1


@pytest.mark.parametrize("restarts, status, expected", [
    (0, None, ("done", [(True, 1.5), (True, 1.5)])),
    (0, 128 + signal.SIGUSR1, SystemExit(slurm.REQUEUE_STATUS)),  # its time limit is near: requeue the task
    (2, 128 + signal.SIGUSR1, SystemExit(slurm.REQUEUE_STATUS)),
    (3, 128 + signal.SIGUSR1, ("stopped", 128 + signal.SIGUSR1)),  # max_requeues=3 used up: the jobs see the stop
    (0, 128 + signal.SIGTERM, SystemExit(128 + signal.SIGTERM)),  # cancelled or preempted: no result
    (0, 128 + signal.SIGINT, ("stopped", 128 + signal.SIGINT)),
])
def test_a_population_job_requeues_at_its_time_limit_until_its_requeues_are_used_up(
        entry, tmp_path, monkeypatch, capsys, restarts, status, expected):
    monkeypatch.setenv("SLURM_RESTART_COUNT", str(restarts))
    if status is not None:
        (tmp_path / "exit.txt").write_text(str(status))
    job = slurm.PopulationJob(max_requeues=3)
    if isinstance(expected, SystemExit):
        with pytest.raises(SystemExit) as raised:
            job(_call(entry, tmp_path))
        assert raised.value.code == expected.code
    else:
        assert job(_call(entry, tmp_path)) == expected
    requeued = "its batch script requeues this SLURM task" in capsys.readouterr().out
    assert requeued == (isinstance(expected, SystemExit) and expected.code == slurm.REQUEUE_STATUS)


def test_a_task_run_again_continues_the_members_that_have_a_checkpoint(entry, tmp_path, monkeypatch, capsys):
    """Run again (``SLURM_RESTART_COUNT`` > 0), a member with a checkpoint in its folder resumes from it; one
    without keeps its own ``resume`` (here a checkpoint of another run to start from), or continues with
    ``resume=auto`` if it started fresh."""
    call = _call(entry, tmp_path, resumes=(None, "/elsewhere/last.pt"))
    (tmp_path / "a" / CHECKPOINT_NAME).parent.mkdir()
    (tmp_path / "a" / CHECKPOINT_NAME).write_bytes(b"")
    slurm.PopulationJob(max_requeues=3)(call)
    assert (tmp_path / "resumes.txt").read_text() == "None /elsewhere/last.pt"  # the first run: as given

    monkeypatch.setenv("SLURM_RESTART_COUNT", "1")
    assert slurm.PopulationJob(max_requeues=3)(call)[0] == "done"
    assert (tmp_path / "resumes.txt").read_text() == "auto /elsewhere/last.pt"
    assert "run 2 of this SLURM task" in capsys.readouterr().out

    # a member that started fresh continues with resume=auto too (it may have left a log, a fresh start over
    # which is refused; without a checkpoint, auto starts afresh); aia-eval's members have no resume
    _, cfgs, _, _ = slurm.resumed(_call(entry, tmp_path / "fresh", resumes=(None, "/elsewhere/last.pt")))
    assert [cfg["resume"] for cfg in cfgs] == ["auto", "/elsewhere/last.pt"]
    _, cfgs, _, _ = slurm.resumed((entry, [{"seed": 0, "policy": "arvi"}], [str(tmp_path / "a")], 1))
    assert cfgs == [{"seed": 0, "policy": "arvi"}]


@pytest.mark.parametrize("blocking", [True, False])
def test_the_resource_tracker_outlives_the_signal_that_slurm_sends_every_process_of_a_task(blocking):
    """Started blocking SIGUSR1, multiprocessing's resource tracker (a child process) survives a SIGUSR1; started
    as usual, it dies of it (and would print a traceback into the task's output)."""
    start = ("slurm.start_resource_tracker_blocking(signal.SIGUSR1)" if blocking
             else "resource_tracker.ensure_running()")
    code = textwrap.dedent(f"""
        import os, signal, time
        from multiprocessing import resource_tracker
        from hydra_plugins.aia_population_launcher import slurm
        {start}
        pid = resource_tracker._resource_tracker._pid
        os.kill(pid, signal.SIGUSR1)
        time.sleep(0.5)
        print(os.waitpid(pid, os.WNOHANG)[0] == 0)
        """)
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True, timeout=60).stdout
    assert out.strip() == str(blocking)


class _FakeTask:
    """What :func:`slurm.task_outcome` reads of a submitit job."""

    def __init__(self, result=None, error: Exception | None = None, state: str = "COMPLETED") -> None:
        self.job_id, self.state, self.paths = "7_1", state, SimpleNamespace(stderr="/s/.submitit/7_1/7_1_0_log.err")
        self._result, self._error = result, error

    def result(self):
        if self._error is not None:
            raise self._error
        return self._result


@pytest.mark.parametrize("task, message", [
    (_FakeTask(("stopped", 128 + signal.SIGUSR1)), "jobs 0-1: stopped by SIGUSR1 in SLURM task 7_1 with every "
     "member's checkpoint (no requeue left); continue them: the same command with resume=auto"),
    (_FakeTask(error=submitit.core.utils.UncompletedJobError("no output"), state="CANCELLED by 0"),
     "jobs 0-1: SLURM task 7_1 ended CANCELLED without a result (its output: /s/.submitit/7_1/7_1_0_log.err); "
     "members that wrote a checkpoint continue with resume=auto"),
    (_FakeTask(error=submitit.core.utils.FailedJobError(  # as submitit words it
        "Job (task=0) failed during processing with trace:\n----------------------\nTraceback (most recent call "
        "last):\n  File x\nValueError: boom\n\n----------------------\nYou can check full logs with ...")),
     "jobs 0-1: SLURM task 7_1 failed: ValueError: boom (its output: /s/.submitit/7_1/7_1_0_log.err)"),
])
def test_a_task_that_did_not_finish_its_population_fails_each_job_saying_why(task, message):
    outcome = slurm.task_outcome(task, "jobs 0-1", 2)
    assert [ok for ok, _ in outcome] == [False, False]
    assert all(isinstance(error, JobFailed) and str(error) == message for _, error in outcome)


def test_a_finished_task_gives_each_job_its_own_result():
    assert slurm.task_outcome(_FakeTask(("done", [(True, 1.0), (False, "x")])), "jobs 0-1", 2) == [(True, 1.0),
                                                                                                  (False, "x")]


@pytest.mark.parametrize("override, message", [
    ("hydra.launcher.cpus_per_task=0", "hydra.launcher.cpus_per_task=0: expected an integer >= 1"),
    ("hydra.launcher.mem_gb=0.5", "hydra.launcher.mem_gb=0.5: expected an integer >= 1"),
    ("hydra.launcher.max_requeues=-1", "hydra.launcher.max_requeues=-1: expected an integer >= 0"),
    ("hydra.launcher.signal_delay_s=600", "hydra.launcher.signal_delay_s=600: expected fewer seconds than the time "
     "limit (timeout_min=10: 600 s)"),
    ("+hydra.launcher.additional_parameters.signal=USR2@90", "hydra.launcher.additional_parameters.signal='USR2@90': "
     "expected no value"),
    ("hydra.launcher.poll_every_s=0", "hydra.launcher.poll_every_s=0: expected a number > 0"),
])
def test_a_bad_setting_gets_one_line_before_any_job_folder(tmp_path, monkeypatch, capsys, override, message):
    monkeypatch.setattr(sys, "argv", ["aia-train", "-m", "seed=0,1", "hydra/launcher=population_slurm",
                                      "hydra.launcher.timeout_min=10", override, f"hydra.sweep.dir={tmp_path}"])
    with pytest.raises(SystemExit) as info:
        train_app.main()
    assert info.value.code == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and message in err, err
    assert not (tmp_path / "0").exists()


def test_a_machine_without_slurm_is_told_so(tmp_path, monkeypatch, capsys):
    monkeypatch.setattr(slurm.shutil, "which", lambda name: None)
    monkeypatch.setattr(sys, "argv", ["aia-train", "-m", "seed=0,1", "hydra/launcher=population_slurm",
                                      f"hydra.sweep.dir={tmp_path}"])
    with pytest.raises(SystemExit) as info:
        train_app.main()
    assert info.value.code == 2
    assert "hydra/launcher='population_slurm': expected a SLURM login node (sbatch is not on PATH here" in \
        capsys.readouterr().err


class _FakeExecutor:
    """``submitit.SlurmExecutor`` as the launcher uses it: tasks ``7_0``, ``7_1``, ... of array 7, each pending at
    its first poll, running at its second and done (run in this process) at its third; ``signal_at_poll``: the
    signal this process gets at the first task's first poll (to stop the launcher's waiting); ``refusal``: what
    sbatch says when it refuses the array."""

    last: _FakeExecutor | None = None
    signal_at_poll: int | None = None
    refusal: str | None = None  # sbatch's error: the submission fails with it, as submitit words it

    def __init__(self, folder: str) -> None:
        self.folder, self.parameters, self.tasks = folder, {}, []
        _FakeExecutor.last = self

    def update_parameters(self, **parameters) -> None:
        self.parameters.update(parameters)

    @contextlib.contextmanager
    def batch(self):
        yield
        if self.refusal:
            print(self.refusal, file=sys.stderr)  # submitit prints sbatch's lines, then raises
            raise submitit.core.utils.FailedJobError(self.refusal)

    def submit(self, function, call):
        job_id = f"7_{len(self.tasks)}"
        folder = Path(self.folder.replace("%j", job_id))
        task = SimpleNamespace(job_id=job_id, polls=0, paths=SimpleNamespace(stdout=folder / f"{job_id}_0_log.out"))
        task.done = lambda: self._poll(task) > 2
        task.result = lambda: function(call)
        self.tasks.append(task)
        return task

    def _poll(self, task) -> int:
        task.polls += 1
        task.state = "PENDING" if task.polls == 1 else "RUNNING"
        if self.signal_at_poll is not None:
            os.kill(os.getpid(), self.signal_at_poll)
        return task.polls


def _slurm_multirun(tmp_path, monkeypatch, capsys, entry: str, *overrides: str) -> tuple[list, str, str]:
    """The JobReturns of ``aia-train -m hydra/launcher=population_slurm`` on :class:`_FakeExecutor` (``sbatch``
    taken as found, squeue's reason for a pending task ``Priority``), its output and its errors."""
    monkeypatch.setattr(slurm.shutil, "which", lambda name: f"/usr/bin/{name}")
    monkeypatch.setattr(submitit, "SlurmExecutor", _FakeExecutor)
    launcher = Plugins.instance().class_name_to_class[f"{slurm.__name__}.PopulationSlurmLauncher"]
    monkeypatch.setattr(sys.modules[launcher.__module__], "_pending_reason", lambda job_id: "Priority")
    returns, launch = [], launcher.launch
    monkeypatch.setattr(launcher, "launch", lambda self, *args, **kwargs: returns.extend(launch(self, *args, **kwargs))
                        or returns)
    monkeypatch.setattr(sys, "argv", ["aia-train", "-m", f"hydra.sweep.dir={tmp_path / 'sweep'}", "seed=0,1",
                                      "hidden=[16],[24]", "hydra/launcher=population_slurm",
                                      f"hydra.launcher.task={entry}", "hydra.launcher.poll_every_s=0.01", *overrides])
    capsys.readouterr()
    train_app.main()
    captured = capsys.readouterr()
    return returns, captured.out, captured.err


def test_the_launcher_submits_each_population_as_a_task_and_says_as_they_start_and_end(entry, tmp_path,
                                                                                        monkeypatch, capsys):
    returns, out, _ = _slurm_multirun(tmp_path, monkeypatch, capsys, entry)
    assert [(r.status, r.return_value) for r in returns] == [(JobStatus.COMPLETED, 1.5)] * 4
    sweep = tmp_path / "sweep"
    # the larger networks' population first; each task in its own folder of the sweep's .submitit/
    assert (f"population launcher: submitted as SLURM job array 7 (4 CPUs, 720 min each): jobs 1, 3: task 7_0, "
            f"jobs 0, 2: task 7_1; their output: {sweep / '.submitit'}/<task>/\n") in out
    for name, task in (("jobs 1, 3", "7_0"), ("jobs 0, 2", "7_1")):
        assert f"population launcher: {name} (task {task}): pending (Priority)\n" in out
        assert f"population launcher: {name} (task {task}): running\n" in out
    assert re.search(r"population launcher: 1/2 done after 0:\d\d: jobs 1, 3\n", out)  # 0:00, or 0:01 on a busy machine
    assert re.search(r"population launcher: 2/2 done after 0:\d\d: jobs 0, 2\n", out)
    parameters = _FakeExecutor.last.parameters
    assert parameters["additional_parameters"] == {"signal": "USR1@300"}
    assert parameters["teardown"] == slurm.REQUEUE_TEARDOWN
    assert (parameters["time"], parameters["cpus_per_task"], parameters["mem"]) == (720, 4, "16G")
    assert parameters["job_name"] == "aia-train" and "partition" not in parameters


def test_a_signal_to_the_waiting_launcher_leaves_the_tasks_running_and_says_how_to_cancel_them(
        entry, tmp_path, monkeypatch, capsys):
    monkeypatch.setattr(_FakeExecutor, "signal_at_poll", signal.SIGTERM)
    with pytest.raises(SystemExit) as info:
        _slurm_multirun(tmp_path, monkeypatch, capsys, entry)
    assert info.value.code == 128 + signal.SIGTERM
    err = capsys.readouterr().err
    assert ("population launcher: SIGTERM: stopped waiting; the populations go on as SLURM job array 7 (cancel "
            "them: scancel 7); each job's results stay in its folder\n") in err
    assert [task.polls for task in _FakeExecutor.last.tasks] == [1, 0]


def test_an_array_that_sbatch_refuses_gets_one_line_naming_the_refusal(entry, tmp_path, monkeypatch, capsys):
    monkeypatch.setattr(_FakeExecutor, "refusal", "sbatch: error: invalid partition specified: nope\n"
                        "sbatch: error: Batch job submission failed: Invalid partition name specified")
    with pytest.raises(SystemExit) as info:
        _slurm_multirun(tmp_path, monkeypatch, capsys, entry, "hydra.launcher.partition=nope")
    assert info.value.code == 2
    assert capsys.readouterr().err == (
        "aia-train: error: hydra.launcher='sbatch: error: invalid partition specified: nope': expected settings "
        "this cluster's sbatch accepts (partition, timeout_min, cpus_per_task, gpus_per_node, mem_gb, "
        "additional_parameters); nothing was submitted\n")


@pytest.mark.parametrize("status, env, requeued", [
    (slurm.REQUEUE_STATUS, {"SLURM_JOB_ID": "54", "SLURM_ARRAY_JOB_ID": "53", "SLURM_ARRAY_TASK_ID": "1"}, "53_1"),
    (slurm.REQUEUE_STATUS, {"SLURM_JOB_ID": "53", "SLURM_ARRAY_JOB_ID": "53", "SLURM_ARRAY_TASK_ID": "1"}, "53_1"),
    (slurm.REQUEUE_STATUS, {"SLURM_JOB_ID": "13"}, "13"),  # a single population: a job, not an array
    (0, {"SLURM_JOB_ID": "13"}, None),
    (128 + signal.SIGTERM, {"SLURM_JOB_ID": "13"}, None),
])
def test_the_batch_script_requeues_its_own_task_only_when_the_population_asks(status, env, requeued):
    """The teardown lines after the population's process (exit ``status``) call ``scontrol requeue`` with the
    task's own name: an array task's ``SLURM_JOB_ID`` can be the array's id, which would requeue every task."""
    script = "scontrol() { echo \"$@\"; }\n" + f"(exit {status})\n" + "\n".join(slurm.REQUEUE_TEARDOWN)
    out = subprocess.run(["bash", "-c", script], env={"PATH": os.environ["PATH"], **env}, capture_output=True,
                         text=True, check=True, timeout=30).stdout
    assert out == (f"requeue {requeued}\n" if requeued else "")
