"""``aia-train -m hydra/launcher=slurm`` on a real scheduler (the local cluster of scripts/slurm_local.sh):
a sweep runs end to end and its job that fails inside SLURM is reported as failed instead of waited on, a
preempted job comes back and finishes its run through ``resume=auto``, and ``hydra/launcher=population_slurm``
runs a sweep's populations as SLURM tasks that requeue themselves at their time limit's signal and finish, as
``scripts/reproduce.sh`` does with ``LAUNCHER=population_slurm``."""

from __future__ import annotations

import math
import pickle
import re
import subprocess
import time
import uuid
from pathlib import Path

import pytest
import torch
import yaml

from aia.evaluation import search_objective
from aia.logging import read_run
from tests.cluster.conftest import TEST_RESOURCES

# Tiny jobs: a warm-up episode of 50 steps and a training one, each followed by an evaluation of 2 worlds.
EPISODES = 2
TINY = (f"frames={50 * EPISODES}", "warmup_frames=50", "env.max_steps=50", "eval.episodes=2", "eval.per_rollout=1",
        "logger.record_every_evaluations=0", "threads=1")


def test_a_sweep_runs_its_jobs_and_reports_the_one_that_fails_inside_slurm(slurm_cluster, tmp_path):
    """Job 0 trains and returns its objective; job 1 (Thompson sampling with DQN) is refused by the job itself
    (``aia-train: error: ...``, exit status 2): it leaves no result, so submitit learns of its end from sacct
    (slurmdbd) alone, and the sweep fails naming it."""
    sweep_dir = tmp_path / "sweep"
    name, result = slurm_cluster.sweep(sweep_dir, *TINY, "algo=dqn", "exploration=egreedy,thompson")
    assert result.returncode != 0
    assert "exploration='thompson'" in result.stderr, result.stderr[-3000:]  # the failed job's own error line

    multirun = yaml.safe_load((sweep_dir / "multirun.yaml").read_text())
    assert multirun["hydra"]["launcher"]["_target_"].endswith("SlurmLauncher")
    assert multirun["hydra"]["overrides"]["task"][-1] == "exploration=egreedy,thompson"
    jobs = slurm_cluster.jobs(name)
    assert [(job.state, job.exit_code) for job in jobs] == [("COMPLETED", "0:0"), ("FAILED", "2:0")], jobs
    array_id = jobs[0].job_id.split("_")[0]
    run_dir = sweep_dir / "0"
    assert "exploration=egreedy" in yaml.safe_load((run_dir / ".hydra" / "overrides.yaml").read_text())
    scores = read_run(run_dir / "run.mcap").scalars("eval/score").values
    assert len(scores) == EPISODES  # one evaluation after every episode
    # submitit's record of the job: Hydra's JobReturn, holding the objective the task returned
    status, job_return = pickle.loads(
        (sweep_dir / ".submitit" / f"{array_id}_0" / f"{array_id}_0_0_result.pkl").read_bytes())
    assert status == "success"
    assert job_return.status.name == "COMPLETED"
    assert job_return.overrides[-1] == "exploration=egreedy"
    assert job_return.return_value == pytest.approx(search_objective(list(scores)))
    assert math.isfinite(job_return.return_value)
    assert not (sweep_dir / "1" / "run.mcap").exists()


def test_a_preempted_job_is_requeued_and_finishes_its_run_through_resume_auto(slurm_cluster, tmp_path):
    """``scontrol requeue`` of a running job: SLURM sends SIGTERM, the run ends its episode with a checkpoint,
    the job comes back (its 2-minute requeue delay cut short) with the same command, and ``resume=auto`` takes
    it to the end: one history in the job's folder (two log segments), every evaluation once."""
    sweep_dir = tmp_path / "sweep"
    frames, steps = 1000, 50
    overrides = (f"frames={frames}", "warmup_frames=50", f"env.max_steps={steps}", "eval.episodes=2",
                 "logger.record_every_evaluations=0", "threads=1", "resume=auto", "seed=0")
    name, command = slurm_cluster.sweep_command(sweep_dir, *overrides)
    sweep = subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                             env=slurm_cluster.env(), cwd=tmp_path)
    try:
        log = sweep_dir / "0" / "run.mcap"
        deadline = time.monotonic() + slurm_cluster.sweep_timeout_s
        while not (log.exists() and "eval/score" in read_run(log).scalar_topics()):
            assert time.monotonic() < deadline and sweep.poll() is None, "the job logged no evaluation"
            time.sleep(0.5)
        job_id = _squeue(name)
        subprocess.run(["scontrol", "requeue", job_id], check=True, timeout=30)
        while _squeue(name, "%T") != "PENDING":  # requeued: pending until its begin time
            assert time.monotonic() < deadline, f"the job did not come back pending: {slurm_cluster.queue()}"
            time.sleep(0.5)
        _start_now(job_id)
        _, err = sweep.communicate(timeout=max(1.0, deadline - time.monotonic()))
    finally:
        _end(sweep, name)
    assert sweep.returncode == 0, err[-3000:]
    assert (sweep_dir / "0" / "run.1.mcap").is_file()  # the requeued job's segment
    run = read_run(log)
    assert run.complete and run.failure is None
    assert run.scalars("eval/score").frames.tolist() == [float(steps * k) for k in range(1, frames // steps + 1)]
    assert torch.load(sweep_dir / "0" / "checkpoints" / "last.pt", weights_only=False)["state"]["frames"] == frames
    [job] = slurm_cluster.jobs(name)
    assert job.state == "COMPLETED"


def test_population_slurm_runs_each_population_as_a_task_that_requeues_itself_at_its_time_limit(slurm_cluster,
                                                                                                tmp_path):
    """``hydra/launcher=population_slurm``: two populations of two, one SLURM task each. SIGUSR1 to each task
    once its two jobs are training (what ``--signal=USR1@<s>`` sends before the time limit): each population
    stops at an episode's end with its checkpoints, its batch script requeues its task, and the task, run again
    (its 2-minute requeue delay cut short), continues with ``resume=auto`` to the end. The sweep succeeds with
    every job's full history in its folder, in two log segments. The tasks are handled one by one, as each
    trains: with another test's job on one of the node's two CPUs they run one after the other (seen twice)."""
    sweep_dir, frames, steps, name = tmp_path / "sweep", 1500, 50, f"aia-test-{uuid.uuid4().hex[:8]}"
    command = ["aia-train", "-m", "hydra/launcher=population_slurm", "hydra.launcher.cpus_per_task=1",
               "hydra.launcher.mem_gb=1", "hydra.launcher.timeout_min=10", "hydra.launcher.poll_every_s=1",
               f"hydra.launcher.name={name}", f"hydra.sweep.dir={sweep_dir}", "seed=0,1", "hidden=[16],[24]",
               f"frames={frames}", "warmup_frames=50", f"env.max_steps={steps}", "eval.episodes=2",
               "logger.record_every_evaluations=0"]
    logs = [sweep_dir / str(job) / "run.mcap" for job in range(4)]
    deadline = time.monotonic() + slurm_cluster.sweep_timeout_s
    printed = tmp_path / "sweep.out"  # the launcher's lines as they come: which task trains which jobs
    with printed.open("w") as stdout:
        sweep = subprocess.Popen(command, stdout=stdout, stderr=subprocess.PIPE, text=True, env=slurm_cluster.env(),
                                 cwd=tmp_path)

    def wait_for(find, what: str):
        """``find()``'s first truthy value, polled until the deadline."""
        while not (found := find()):
            assert time.monotonic() < deadline and sweep.poll() is None, f"{what}; squeue: {slurm_cluster.queue()}"
            time.sleep(0.5)
        return found

    def training_task(left: dict[str, list[int]]) -> str | None:
        """A task of ``left`` that runs and whose jobs have each logged an evaluation."""
        return next((task for task, jobs in left.items() if _task_state(task) == "RUNNING" and all(
            logs[j].exists() and "eval/score" in read_run(logs[j]).scalar_topics() for j in jobs)), None)

    try:
        wait_for(lambda: "submitted as SLURM job array" in printed.read_text(), "the array was not submitted")
        left = _tasks_of_jobs(printed.read_text())
        assert sorted(job for jobs in left.values() for job in jobs) == [0, 1, 2, 3], left
        while left:
            task = wait_for(lambda: training_task(left), "no task trained its jobs")
            subprocess.run(["scancel", "--signal=USR1", task], check=True, timeout=30)
            wait_for(lambda task=task: _task_state(task) == "PENDING", f"task {task} was not requeued")
            _start_now(task)
            del left[task]
        _, err = sweep.communicate(timeout=max(1.0, deadline - time.monotonic()))
        out = printed.read_text()
    finally:
        _end(sweep, name)
    assert sweep.returncode == 0, err[-3000:]
    assert "population launcher: 4 jobs in 2 populations of 2 members each" in out
    assert "population launcher: 2/2 done after" in out and "failed" not in out
    for log in logs:
        assert (log.parent / "run.1.mcap").is_file()  # the requeued task's segment
        run = read_run(log)
        assert run.complete and run.failure is None, (log, run.failure)
        assert run.scalars("eval/score").frames.tolist() == [float(steps * k) for k in range(1, frames // steps + 1)]
        assert torch.load(log.parent / "checkpoints" / "last.pt", weights_only=False)["state"]["frames"] == frames
    outputs = " ".join(path.read_text() for path in (sweep_dir / ".submitit").glob("*/*_log.out"))
    assert outputs.count("its batch script requeues this SLURM task (restart 1 of at most 3)") == 2
    assert outputs.count("run 2 of this SLURM task") == 2


def test_reproduce_sh_sends_its_learners_and_arvi_to_slurm(slurm_cluster, tmp_path):
    """``LAUNCHER=population_slurm scripts/reproduce.sh`` on a tiny budget: the learners' population as a task of a
    job array, the ARVI seed as a SLURM job of its own (``PHASES=learners,arvi``: the figures, drawn on this
    machine whatever the launcher, are tested in tests/scripts/test_reproduce.py)."""
    script = Path(__file__).resolve().parents[2] / "scripts" / "reproduce.sh"
    env = {**slurm_cluster.env(), "SETTINGS": "small2", "SEEDS": "0", "METHODS": "adfq_egreedy,adfq_ts",
           "FRAMES": "300", "ARVI_SEEDS": "0", "ARVI_EPISODES": "1", "ARVI_NODES": "100", "ARVI_MIN_RANGES": "2",
           "OUT": "out", "PHASES": "learners,arvi",
           "TRAIN_OVERRIDES": "compile.update=false compile.env=false compile.policy=false",
           "LAUNCHER": "population_slurm", "SLURM_OVERRIDES": " ".join(TEST_RESOURCES)}
    result = subprocess.run(["bash", str(script)], cwd=tmp_path, env=env, capture_output=True, text=True,
                            timeout=slurm_cluster.sweep_timeout_s)
    assert result.returncode == 0, result.stderr[-3000:]
    assert "2 jobs in 1 population of 2 members" in result.stdout
    assert "population launcher: submitted as SLURM job array" in result.stdout
    out = tmp_path / "out"
    for method in ("adfq_egreedy", "adfq_ts"):
        assert read_run(out / "small2" / "learners" / f"method={method},seed=0" / "run.mcap").complete
    assert read_run(out / "small2" / "arvi_min2" / "seed=0" / "run.mcap").complete
    # each phase's SLURM jobs left their submitit records in its sweep folder
    assert list((out / "sweeps" / "learners" / ".submitit").glob("*/*_result.pkl"))
    assert list((out / "sweeps" / "arvi_min2" / ".submitit").glob("*/*_result.pkl"))
    assert not list((out / "figures").iterdir())


def _start_now(job_id: str) -> None:
    """Cut short the requeued (pending) job's requeue delay: it may start at once. Not in the second of the
    requeue, though: slurmd refuses a job whose credential is no newer than the revocation of its previous run's
    ("Killing non-startable batch JobId=62: Job credential revoked", seen twice in three runs on 2026-12-05)."""
    time.sleep(2)
    subprocess.run(["scontrol", "update", f"JobId={job_id}", "StartTime=now"], check=True, timeout=30)


def _end(sweep: subprocess.Popen, name: str, settle_s: float = 30.0) -> None:
    """After a test: kill its sweep if it still runs and cancel whatever of its jobs (named ``name``) is left.

    A sweep that returned by itself may have a job still finishing (submitit reads the result before SLURM
    marks the job COMPLETED): its jobs get ``settle_s`` to leave the queue first, or the cancel would record a
    job that ended well as CANCELLED."""
    if sweep.poll() is None:
        sweep.kill()
    else:
        deadline = time.monotonic() + settle_s
        while _squeue(name) and time.monotonic() < deadline:
            time.sleep(0.5)
    subprocess.run(["scancel", f"--name={name}"], check=False, timeout=30)


def _tasks_of_jobs(printed: str) -> dict[str, list[int]]:
    """Each task of the array (``"12_0"``) and its population's job numbers, from the launcher's line
    ``submitted as SLURM job array 12 (...): jobs 1, 3: task 12_0, jobs 0, 2: task 12_1; ...``."""
    tasks = {}
    for numbers, task in re.findall(r"jobs? ([0-9][0-9, -]*?): task (\d+_\d+)", printed):
        jobs = []
        for part in numbers.split(", "):
            first, _, last = part.partition("-")
            jobs.extend(range(int(first), int(last or first) + 1))
        tasks[task] = jobs
    return tasks


def _task_state(task: str) -> str:
    """The SLURM state of array task ``task`` (``RUNNING``, ``PENDING``, ...; empty once it left the queue)."""
    return subprocess.run(["squeue", "--noheader", "--array", f"--jobs={task}", "--format", "%T"],
                          capture_output=True, text=True, timeout=30).stdout.strip()


def _squeue(name: str, field: str = "%i") -> str:
    """One field of the queued job named ``name`` (its id by default; empty once it has left the queue)."""
    return subprocess.run(["squeue", "--noheader", f"--name={name}", "--format", field], capture_output=True,
                          text=True, check=True, timeout=30).stdout.strip()
