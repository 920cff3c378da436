"""A real single-node SLURM cluster for the tests (scripts/slurm_local.sh), shared by the whole session.

``slurm_cluster`` starts the cluster (installing its Debian packages on a fresh machine); tests/conftest.py stops
it at the end of the run if this run started it. Its ``sweep`` runs ``aia-train -m hydra/launcher=slurm``
with small per-job resources and a unique SLURM job name (``sweep_command`` gives the command line for a
test that acts on the jobs while they run, e.g. ``scontrol requeue``), and ``jobs`` reads back what
``sacct`` recorded of that sweep's jobs, so a test can check the scheduler's view as well as the files.
"""

from __future__ import annotations

import os
import subprocess
import sys
import time
import uuid
from dataclasses import dataclass
from pathlib import Path

import pytest

SCRIPT = Path(__file__).resolve().parents[2] / "scripts" / "slurm_local.sh"
START_TIMEOUT_S = 300          # apt-get install on a fresh machine (about 25 s), then the daemons (about 10 s)
SWEEP_TIMEOUT_S = 240          # one aia-train -m sweep of tiny jobs
SACCT_SETTLE_S = 60            # how long sacct may lag behind a job's end
# sacct's final job states (PREEMPTED and REQUEUED are not: the job comes back)
FINISHED = {"COMPLETED", "FAILED", "CANCELLED", "TIMEOUT", "OUT_OF_MEMORY", "NODE_FAIL", "BOOT_FAIL", "DEADLINE"}
# Per-job resources that fit two jobs at once on a 2-core machine; a time limit so a stuck job cannot
# outlive the session.
TEST_RESOURCES = ("hydra.launcher.cpus_per_task=1", "hydra.launcher.mem_gb=1", "hydra.launcher.timeout_min=10")


def script(command: str, timeout: float) -> subprocess.CompletedProcess:
    """``bash scripts/slurm_local.sh <command>``."""
    return subprocess.run(["bash", str(SCRIPT), command], capture_output=True, text=True, timeout=timeout)


@dataclass(frozen=True)
class SlurmJob:
    """One job (array task) as ``sacct`` recorded it."""

    job_id: str      # "12_0": array job 12, task 0
    state: str       # COMPLETED, FAILED, RUNNING, ...
    exit_code: str   # "<status>:<signal>", e.g. "2:0"


class SlurmCluster:
    """The running local cluster: submit ``aia-train`` sweeps to it and read its accounting."""

    sweep_timeout_s = SWEEP_TIMEOUT_S  # how long a test waits for one of its sweeps

    @staticmethod
    def env() -> dict[str, str]:
        """The environment with this interpreter's console scripts (aia-train) first on PATH; jobs inherit it."""
        return {**os.environ, "PATH": f"{Path(sys.executable).parent}{os.pathsep}{os.environ.get('PATH', '')}"}

    @staticmethod
    def sweep_command(sweep_dir: Path, *overrides: str) -> tuple[str, list[str]]:
        """A unique SLURM job name and the ``aia-train -m hydra/launcher=slurm <overrides>`` command line
        that sweeps into ``sweep_dir`` under it (run it with ``env=self.env()``, e.g. in a ``Popen`` to
        act on the jobs while they run)."""
        name = f"aia-test-{uuid.uuid4().hex[:8]}"
        return name, ["aia-train", "-m", "hydra/launcher=slurm", *TEST_RESOURCES, f"hydra.launcher.name={name}",
                      f"hydra.sweep.dir={sweep_dir}", *overrides]

    def sweep(self, sweep_dir: Path, *overrides: str, timeout: float = SWEEP_TIMEOUT_S) -> tuple[str,
                                                                                              subprocess.CompletedProcess]:
        """Run :meth:`sweep_command` to its end; return the SLURM job name and the finished process. A sweep
        still running after ``timeout`` seconds is killed, its jobs are cancelled, and the test fails saying so."""
        name, command = self.sweep_command(sweep_dir, *overrides)
        try:
            result = subprocess.run(command, capture_output=True, text=True, timeout=timeout, env=self.env(),
                                    cwd=sweep_dir.parent)
        except subprocess.TimeoutExpired as err:
            subprocess.run(["scancel", f"--name={name}"], check=False, timeout=30)
            pytest.fail(f"the sweep did not finish in {timeout} s; its jobs ({name}) were cancelled; squeue then: "
                        f"{self.queue()}; output: {(err.stderr or b'')[-2000:]!r}")
        return name, result

    def jobs(self, name: str) -> list[SlurmJob]:
        """The array tasks of job name ``name`` in ``sacct``, waiting until every one has finished there (the
        accounting record can trail submitit's view of a job by a few seconds)."""
        deadline = time.monotonic() + SACCT_SETTLE_S
        while True:
            out = subprocess.run(["sacct", "--noheader", "--parsable2", "--allocations", "--starttime=now-2hours",
                                  f"--name={name}", "--format=JobID,State,ExitCode"],
                                 capture_output=True, text=True, check=True, timeout=30).stdout
            jobs = [SlurmJob(*line.split("|")) for line in out.splitlines() if line]
            # "CANCELLED by 0" carries who cancelled: compare the first word
            if jobs and all(job.state.split()[0] in FINISHED for job in jobs):
                return sorted(jobs, key=lambda job: [int(part) for part in job.job_id.split("_")])
            if time.monotonic() > deadline:
                pytest.fail(f"sacct shows jobs {jobs} of {name} still unfinished {SACCT_SETTLE_S} s after the sweep")
            time.sleep(1)

    @staticmethod
    def queue() -> str:
        """``squeue``'s table (for failure messages)."""
        return subprocess.run(["squeue"], capture_output=True, text=True, timeout=30).stdout


@pytest.fixture(scope="session")
def slurm_cluster() -> SlurmCluster:
    """The local SLURM cluster, started (and its packages installed) if it is not up. Both workers may run SLURM
    tests (pytest-xdist 3.8 cannot group tests under pytest 9.2's node ids), so no worker stops it: a worker that
    finds it down marks the run as its starter, and the run's controller stops it at its end (tests/conftest.py);
    a cluster that another test run started is left to that run."""
    from tests.conftest import SLURM_STARTED, run_dir

    folder = run_dir()
    if folder is not None and script("status", timeout=60).returncode != 0:
        (folder / SLURM_STARTED).touch()
    try:
        started = script("start", timeout=START_TIMEOUT_S)
    except subprocess.TimeoutExpired:
        pytest.fail(f"scripts/slurm_local.sh start did not return in {START_TIMEOUT_S} s")
    if started.returncode != 0:
        pytest.fail(f"scripts/slurm_local.sh start failed: {started.stderr.strip()}")
    return SlurmCluster()
