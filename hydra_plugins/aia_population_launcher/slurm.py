"""The population launcher on SLURM (``hydra/launcher=population_slurm``): a sweep's populations as SLURM jobs.

It prepares and groups the jobs exactly as :class:`~.population_launcher.PopulationLauncher` does (the same
job folders, configs, groups and lines), then submits the populations to SLURM through submitit as one job
array, each array task running one population on ``cpus_per_task`` cores, and waits for them, saying when each
starts and ends. Every job gets its own ``JobReturn`` as with the local launcher.

Time limits and preemption. Each task asks SLURM for SIGUSR1 ``signal_delay_s`` seconds before its time limit
(``--signal=USR1@<s>``; submitit's own USR2 is never asked for). A population ends its episode on it, writes
its members' checkpoints and marks their logs stopped; its process exits, and its batch script requeues the
task (``scontrol requeue``), up to ``max_requeues`` times. A task that SLURM runs again (requeued by itself,
by the scheduler's preemption or by an administrator: ``SLURM_RESTART_COUNT`` > 0) continues every member
whose folder holds a checkpoint with ``resume=auto``. A SIGTERM (``scancel``, a preemption) stops a population
the same way and leaves its task without a result, so that submitit follows the task through the scheduler's
accounting: one that SLURM requeues comes back and continues, one that was cancelled fails its jobs with a
line naming the task and saying how to continue them. A population that has used up its requeues fails its
jobs saying where it stopped.
"""

from __future__ import annotations

import contextlib
import io
import os
import re
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

from hydra_plugins.aia_population_launcher.population_launcher import PopulationLauncher, done_line, largest_first
from hydra_plugins.aia_population_launcher.workers import Call, Outcome, run_stoppable, training

# What SLURM sends a task before its time limit (``--signal``), and what a population requeues itself on.
REQUEUE_SIGNAL = signal.SIGUSR1
# The exit status by which a population asks its batch script to requeue its task: the script's last lines
# (after the population's process has exited, so that nothing of it is killed by the requeue). An array task
# is named ``<array>_<task>``: its ``SLURM_JOB_ID`` may be the array's own id, which would requeue every task
# (found on the local cluster, 2026-12-05: a task's requeue took its sibling along and failed).
REQUEUE_STATUS = 128 + REQUEUE_SIGNAL
REQUEUE_TEARDOWN = [
    "status=$?",
    'task=${SLURM_ARRAY_JOB_ID:+${SLURM_ARRAY_JOB_ID}_${SLURM_ARRAY_TASK_ID}}',
    f'if [ "$status" -eq {REQUEUE_STATUS} ]; then scontrol requeue "${{task:-$SLURM_JOB_ID}}"; fi',
]


class PopulationJob:
    """What one population's SLURM task runs (submitit pickles it with its call): the population, stoppable
    (:func:`~.workers.run_stoppable`), continued with ``resume=auto`` when SLURM runs the task again, and
    requeued after a stop on :data:`REQUEUE_SIGNAL` while fewer than ``max_requeues`` restarts have run.
    Returns ``("done", outcome)`` or ``("stopped", exit status)``; raises ``SystemExit`` (no result: submitit
    follows the task through SLURM) with :data:`REQUEUE_STATUS` to have its task requeued, or after a SIGTERM."""

    def __init__(self, max_requeues: int) -> None:
        self.max_requeues = max_requeues

    def __call__(self, call: Call) -> tuple[str, object]:
        from aia.runtime.process_exit import freeze_at_exit  # imported here, as training()

        freeze_at_exit()
        restarts = int(os.environ.get("SLURM_RESTART_COUNT", "0") or 0)
        start_resource_tracker_blocking(REQUEUE_SIGNAL)
        if restarts:
            call = resumed(call)
            print(f"population job: run {restarts + 1} of this SLURM task: members with a checkpoint continue "
                  "from it (resume=auto)", flush=True)
        kind, payload = run_stoppable(call)
        if kind != "stopped":
            return kind, payload
        if payload == REQUEUE_STATUS and restarts < self.max_requeues:
            print(f"population job: stopped at its time limit's signal: its batch script requeues this SLURM task "
                  f"(restart {restarts + 1} of at most {self.max_requeues})", flush=True)
            raise SystemExit(REQUEUE_STATUS)
        if payload == 128 + signal.SIGTERM:  # cancelled, or preempted (SLURM may run it again)
            raise SystemExit(payload)
        return kind, payload


def start_resource_tracker_blocking(signum: int) -> None:
    """Start multiprocessing's resource tracker (tqdm's lock would start it at the first progress bar) with
    ``signum`` blocked in it: SLURM's ``--signal`` reaches every process of a task, and the tracker, which ignores
    only SIGINT and SIGTERM, would die of SIGUSR1 and leave a traceback in the task's output at every stop."""
    from multiprocessing import resource_tracker

    previous = signal.pthread_sigmask(signal.SIG_BLOCK, {signum})  # the child inherits the mask
    try:
        resource_tracker.ensure_running()
    finally:
        signal.pthread_sigmask(signal.SIG_SETMASK, previous)


def resumed(call: Call) -> Call:
    """``call`` with ``resume=auto`` for every training member whose job folder holds a checkpoint (``last.pt`` or
    ``previous.pt``) or that started fresh (a task stopped before its first checkpoint starts afresh, where a
    fresh start would be refused over the log its first run left); a member's ``resume=<path>`` stays."""
    task, cfgs, out_dirs, threads = call
    has_checkpoint = training().has_checkpoint
    cfgs = [{**cfg, "resume": "auto"} if "resume" in cfg and (cfg["resume"] is None or has_checkpoint(out_dir))
            else cfg for cfg, out_dir in zip(cfgs, out_dirs, strict=True)]
    return task, cfgs, out_dirs, threads


class PopulationSlurmLauncher(PopulationLauncher):
    """Launches a sweep's populations as SLURM jobs (see the module docstring); settings in
    ``conf/hydra/launcher/population_slurm.yaml``."""

    def __init__(self, task: str | None = None, submitit_folder: str = ".submitit/%j", name: str = "aia",
                 partition: str | None = None, timeout_min: int = 720, cpus_per_task: int = 4, gpus_per_node: int = 0,
                 mem_gb: int = 16, signal_delay_s: int = 300, max_requeues: int = 3, array_parallelism: int = 64,
                 poll_every_s: float = 5.0, setup: list[str] | None = None,
                 additional_parameters: dict | None = None) -> None:
        super().__init__(n_jobs=1, task=task)
        self.submitit_folder = submitit_folder
        self.name = name
        self.partition = partition
        self.timeout_min = timeout_min
        self.cpus_per_task = cpus_per_task
        self.gpus_per_node = gpus_per_node
        self.mem_gb = mem_gb
        self.signal_delay_s = signal_delay_s
        self.max_requeues = max_requeues
        self.array_parallelism = array_parallelism
        self.poll_every_s = poll_every_s
        self.setup_lines = list(setup or [])
        self.additional_parameters = dict(additional_parameters or {})

    def _check_settings(self, task: str) -> None:
        super()._check_settings(task)
        from aia.config.checks import check_number, require  # imported here: see workers.training

        for key, minimum in (("timeout_min", 1), ("cpus_per_task", 1), ("gpus_per_node", 0), ("mem_gb", 1),
                             ("signal_delay_s", 0), ("max_requeues", 0), ("array_parallelism", 1)):
            check_number(f"hydra.launcher.{key}", getattr(self, key), ge=minimum, integer=True)
        check_number("hydra.launcher.poll_every_s", self.poll_every_s, gt=0)
        require(self.signal_delay_s < 60 * self.timeout_min, "hydra.launcher.signal_delay_s", self.signal_delay_s,
                f"fewer seconds than the time limit (timeout_min={self.timeout_min}: {60 * self.timeout_min} s)")
        require("signal" not in self.additional_parameters, "hydra.launcher.additional_parameters.signal",
                self.additional_parameters.get("signal"), "no value: the launcher asks for SIGUSR1 signal_delay_s "
                "seconds before the time limit itself")
        try:
            import submitit  # noqa: F401
        except ImportError:
            submitit = None
        require(submitit is not None, "hydra/launcher", "population_slurm", "submitit installed: pip install -e "
                "'.[cluster]'")
        require(shutil.which("sbatch") is not None, "hydra/launcher", "population_slurm", "a SLURM login node "
                "(sbatch is not on PATH here; a local cluster: scripts/slurm_local.sh start)")

    def _arrange(self, groups: list[list[int]], configs) -> list[list[int]]:
        """The populations largest first: the array's tasks start in this order when ``array_parallelism``
        holds some back."""
        return largest_first(groups, configs)

    def _run(self, task: str, members: list[tuple[list[dict], list[str]]], names: list[str]) -> list[Outcome]:
        """Submit each population as a task of one job array, then wait for them, saying when each starts and
        ends; a stop signal to the launcher leaves the tasks running and exits with 128 + signal."""
        import submitit

        executor = submitit.SlurmExecutor(folder=self.submitit_folder)
        executor.update_parameters(
            job_name=self.name, time=self.timeout_min, cpus_per_task=self.cpus_per_task, mem=f"{self.mem_gb}G",
            gpus_per_node=self.gpus_per_node, array_parallelism=self.array_parallelism, setup=self.setup_lines,
            teardown=REQUEUE_TEARDOWN,
            additional_parameters={**self.additional_parameters,
                                   "signal": f"{REQUEUE_SIGNAL.name[3:]}@{self.signal_delay_s}"},
            **({"partition": self.partition} if self.partition else {}))
        job = PopulationJob(self.max_requeues)
        try:
            # one sbatch call as the block ends; submitit prints a refusal's lines, which the error below holds
            with contextlib.redirect_stderr(io.StringIO()), executor.batch():
                tasks = [executor.submit(job, (task, cfgs, out_dirs, self.cpus_per_task))
                         for cfgs, out_dirs in members]
        except submitit.core.utils.FailedJobError as err:  # sbatch refused the array: a setting this cluster lacks
            from aia.config.errors import ConfigError

            refusal = next((line.strip() for line in str(err).splitlines() if line.strip()), "no message")
            raise ConfigError("hydra.launcher", refusal, "settings this cluster's sbatch accepts (partition, "
                              "timeout_min, cpus_per_task, gpus_per_node, mem_gb, additional_parameters); nothing "
                              "was submitted") from None
        array = tasks[0].job_id.split("_")[0]
        which = ", ".join(f"{name}: task {t.job_id}" for name, t in zip(names, tasks, strict=True))
        cpus = f"{self.cpus_per_task} CPU" + ("s" if self.cpus_per_task != 1 else "")
        print(f"population launcher: submitted as SLURM job array {array} ({cpus}, "
              f"{self.timeout_min} min each): {which}; their output: "
              f"{Path(str(tasks[0].paths.stdout)).parent.parent}/<task>/", flush=True)
        outcomes: list[Outcome] = [[] for _ in tasks]
        states = ["" for _ in tasks]
        waiting, start, done = set(range(len(tasks))), time.monotonic(), 0

        def leave_running(signum: int, first: bool) -> None:
            print(f"population launcher: {signal.Signals(signum).name}: stopped waiting; the populations go on as "
                  f"SLURM job array {array} (cancel them: scancel {array}); each job's results stay in its folder",
                  file=sys.stderr)
            raise SystemExit(128 + signum)

        with training().StopOnSignals(on_signal=leave_running):
            while waiting:
                for index in sorted(waiting):
                    if tasks[index].done():
                        waiting.discard(index)
                        outcomes[index] = task_outcome(tasks[index], names[index], len(members[index][0]))
                        done += 1
                        print(done_line(done, len(tasks), start, names[index], outcomes[index]), flush=True)
                        continue
                    state = tasks[index].state
                    if state != states[index] and state in ("PENDING", "RUNNING", "REQUEUED"):
                        states[index] = state
                        reason = _pending_reason(tasks[index].job_id) if state == "PENDING" else ""
                        print(f"population launcher: {names[index]} (task {tasks[index].job_id}): {state.lower()}"
                              + (f" ({reason})" if reason else ""), flush=True)
                if waiting:
                    time.sleep(self.poll_every_s)
        return outcomes


def task_outcome(task, name: str, size: int) -> Outcome:
    """What a finished task gives each of its population's ``size`` jobs: the population's own outcome, or
    for a population that stopped or whose task ended without a result, an error each
    (:class:`~aia.config.errors.JobFailed`) naming the jobs (``name``), the task and how to go on."""
    import submitit

    from aia.config.errors import JobFailed

    try:
        kind, payload = task.result()
    except submitit.core.utils.FailedJobError as err:  # the task raised (a kind of UncompletedJobError)
        error = JobFailed(f"{name}: SLURM task {task.job_id} failed: {_raised(str(err))} (its output: "
                          f"{task.paths.stderr})")
        return [(False, error)] * size
    except submitit.core.utils.UncompletedJobError:
        error = JobFailed(f"{name}: SLURM task {task.job_id} ended {task.state.split()[0]} without a result (its "
                          f"output: {task.paths.stderr}); members that wrote a checkpoint continue with resume=auto")
        return [(False, error)] * size
    if kind == "done":
        return payload
    error = JobFailed(f"{name}: stopped by {signal.Signals(payload - 128).name if payload > 128 else payload} "
                      f"in SLURM task {task.job_id} with every member's checkpoint (no requeue left); continue "
                      "them: the same command with resume=auto")
    return [(False, error)] * size


def _pending_reason(job_id: str) -> str:
    """Why SLURM holds the pending task ``job_id`` (``squeue``'s reason: ``Resources``, ``Priority``,
    ``PartitionConfig`` for a request no node of the partition can meet, ...); empty if squeue cannot say."""
    try:
        return subprocess.run(["squeue", "--noheader", f"--jobs={job_id}", "--format=%r"], capture_output=True,
                              text=True, timeout=30).stdout.strip()
    except (OSError, subprocess.SubprocessError):
        return ""


def _raised(message: str) -> str:
    """The exception's line (``ValueError: ...``) of the traceback in a submitit ``FailedJobError``'s message,
    which frames the trace between two rules of dashes."""
    parts = re.split(r"\n-{10,}\n", message)
    trace = parts[1] if len(parts) > 2 else message
    lines = [line.strip() for line in trace.splitlines() if line.strip()]
    return lines[-1] if lines else "no message"
