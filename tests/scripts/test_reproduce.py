"""scripts/reproduce.sh end to end on a tiny budget (learner and ARVI runs, curves, table, trajectory picture), its
refusals of bad or empty input, and its stop on a signal (with a stand-in sweep; generalisation.sh's as well)."""

from __future__ import annotations

import contextlib
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from PIL import Image

SCRIPT = Path(__file__).resolve().parents[2] / "scripts" / "reproduce.sh"


def run_script(cwd: Path, script: Path = SCRIPT, **env: str) -> subprocess.CompletedProcess:
    """``bash script`` (scripts/reproduce.sh) in ``cwd`` with this interpreter's console scripts first on PATH."""
    path = f"{Path(sys.executable).parent}{os.pathsep}{os.environ.get('PATH', '')}"
    return subprocess.run(["bash", str(script)], cwd=cwd, env={**os.environ, "PATH": path, **env},
                          capture_output=True, text=True, timeout=600)


def test_a_tiny_protocol_writes_runs_named_by_override_curves_table_and_trajectory(tmp_path):
    result = run_script(
        tmp_path, SETTINGS="small2", SEEDS="0", METHODS="dqn,adfq_ts", FRAMES="300", ARVI_SEEDS="0-1",
        ARVI_EPISODES="1", ARVI_NODES="100", ARVI_MIN_RANGES="2", JOBS="2", OUT="out",
        TRAIN_OVERRIDES="compile.update=false compile.env=false compile.policy=false",
    )
    assert result.returncode == 0, result.stderr[-3000:]
    # one sweep: DQN and ADFQ-TS are two programs, so two populations, trained in two processes whose ends are
    # announced as they come
    assert "2 jobs in 2 populations of 1 member each" in result.stdout
    assert "population launcher: 1/2 done after " in result.stdout
    assert "population launcher: 2/2 done after " in result.stdout
    setting = tmp_path / "out" / "small2"
    # Run folders are named by what varies (the compile switches are not part of a run's name).
    for method in ("dqn", "adfq_ts"):
        assert (setting / "learners" / f"method={method},seed=0" / "run.mcap").is_file()
    for seed in (0, 1):  # ARVI_SEEDS="0-1": a range
        assert (setting / "arvi_min2" / f"seed={seed}" / "run.mcap").is_file()
    assert not (setting / "arvi").exists()  # ARVI_MIN_RANGES="2": only the 2 m baseline
    # The trajectory step reads the checkpoint of a run whose folder name holds '=' and ','.
    assert (setting / "trajectory" / "run.mcap").is_file()
    assert (tmp_path / "out" / "sweeps" / "learners" / "multirun.yaml").is_file()
    figures = tmp_path / "out" / "figures"
    table = (figures / "small2.md").read_text()
    assert "| algo=adfq, exploration=thompson | 1 |" in table and "| algo=dqn, exploration=egreedy | 1 |" in table
    assert "training episodes to reach ARVI, min range 2 m" in table
    # one seed per learner: aia-log stats refuses (the IQM needs 4 runs), and the script goes on
    assert "has 1 run: --statistic iqm needs at least 4" in result.stdout
    assert "no statistics for small2" in result.stdout and not (figures / "small2_stats.md").exists()
    with Image.open(figures / "small2_trajectory.png") as strip:
        assert strip.size == (5 * 320, 320)  # 5 frames of 320 pixels
    with Image.open(figures / "small2.png") as curves:
        assert min(curves.size) > 200
    # Each phase's wall time, in the order the phases ran.
    phases = [line.split("\t") for line in (tmp_path / "out" / "wall_time.tsv").read_text().splitlines()]
    assert [name.split(":")[0] for name, _ in phases] == ["learners", "ARVI, min range 2 m", "figures"]
    assert all(int(seconds) >= 0 for _, seconds in phases)
    # The machine's matmul rate before and after, to read the wall times against.
    speeds = dict(line.split("\t") for line in (tmp_path / "out" / "machine.tsv").read_text().splitlines())
    assert list(speeds) == ["sgemm_gflops_start", "sgemm_gflops_end"]
    assert all(float(gflops) > 0 for gflops in speeds.values())
    # The figures drawn again from the same runs: the trajectory of the same checkpoint is not evaluated again.
    trajectory = (setting / "trajectory" / "run.mcap").stat().st_mtime_ns
    again = run_script(tmp_path, SETTINGS="small2", SEEDS="0", ARVI_MIN_RANGES="2", OUT="out", PHASES="figures")
    assert again.returncode == 0, again.stderr[-3000:]
    assert (setting / "trajectory" / "run.mcap").stat().st_mtime_ns == trajectory
    assert (figures / "small2.md").read_text() == table


def test_an_unknown_setting_is_named(tmp_path):
    result = run_script(tmp_path, SETTINGS="empty9", OUT="out")
    assert result.returncode == 2
    assert "unknown setting 'empty9'" in result.stderr and "empty1 obstacles1 small2 small3" in result.stderr


def test_seed_ranges_expand_and_a_bad_one_is_named(tmp_path):
    library = SCRIPT.parent / "lib" / "protocol.sh"
    expanded = subprocess.run(["bash", "-c", f"source {library}; seed_list SEEDS 0-3,7,10-12; seed_list SEEDS 0-19"],
                              capture_output=True, text=True, check=True).stdout.split()
    assert expanded == ["0,1,2,3,7,10,11,12", ",".join(map(str, range(20)))]
    for variable, value, bad in (("SEEDS", "5-2", "5-2"), ("ARVI_SEEDS", "0-4,x", "x")):
        result = run_script(tmp_path, **{variable: value}, OUT="out")
        assert result.returncode == 2
        assert result.stderr == (f"{variable}='{value}': '{bad}' is not a seed or a rising range; expected e.g. "
                                 "0,1,2 or 0-19 or 0-4,10\n")
    assert not (tmp_path / "out").exists()  # refused before anything was written


def test_an_unknown_launcher_or_phase_is_named(tmp_path):
    result = run_script(tmp_path, LAUNCHER="joblib", OUT="out")
    assert result.returncode == 2
    assert result.stderr == "LAUNCHER='joblib': expected population or population_slurm\n"
    result = run_script(tmp_path, PHASES="learners,plots", OUT="out")
    assert result.returncode == 2
    assert result.stderr == "PHASES='learners,plots': 'plots' is not a phase; expected some of learners,arvi,figures\n"
    assert not (tmp_path / "out").exists()  # refused before anything was written


@pytest.mark.parametrize("variable, accepts", [
    ("SEEDS", "seeds, e.g. 0,1,2 or 0-19 or 0-4,10, or unset for 0,1,2,3,4"),
    ("ARVI_SEEDS", "seeds, e.g. 0,1,2 or 0-19 or 0-4,10 (ARVI_MIN_RANGES= for no ARVI), or unset for 0,1,2,3,4,5,6,"),
    ("SETTINGS", "some of empty1 obstacles1 small2 small3"),
    ("JOBS", "a number of processes"),
    ("PHASES", "some of learners,arvi,figures")])
def test_an_empty_variable_is_refused_not_taken_for_its_default(tmp_path, variable, accepts):
    result = run_script(tmp_path, **{variable: ""}, OUT="out")
    assert result.returncode == 2
    assert result.stderr.startswith(f"{variable} is empty: expected {accepts}") and result.stderr.count("\n") == 1
    assert not (tmp_path / "out").exists()  # refused before anything was written


def test_jobs_is_a_whole_number_from_1_on(tmp_path):
    for jobs in ("0", "two"):
        result = run_script(tmp_path, JOBS=jobs, OUT="out")
        assert (result.returncode, result.stderr) == (2, f"JOBS='{jobs}': expected a whole number from 1 on\n")
    assert not (tmp_path / "out").exists()


def test_unfinished_seeds_are_named_and_their_partial_runs_removed(tmp_path):
    """With resume=auto, the ARVI seeds of a stopped call are evaluated again but for those that finished."""
    for seed, files in ((0, ("run.mcap", "eval.json")), (1, ("run.mcap",)), (3, ("eval.json",))):
        for name in files:
            (tmp_path / f"seed={seed}").mkdir(exist_ok=True)
            (tmp_path / f"seed={seed}" / name).touch()
    library = SCRIPT.parent / "lib" / "protocol.sh"
    todo = subprocess.run(["bash", "-c", f"source {library}; unfinished {tmp_path} 0,1,2,3"],
                          capture_output=True, text=True, check=True).stdout
    assert todo == "1,2\n"
    assert sorted(path.name for path in tmp_path.iterdir()) == ["seed=0", "seed=3"]  # seed=1's partial run went


# A stand-in for aia-train -m: like the population launcher, it ends (with status 128 + signal) half a second after
# a stop signal, once its worker process has ended; the worker ends at once on SIGINT or SIGTERM. Each notes what it
# got in $FAKE_LOG. The launcher does not forward signals to its worker, so the worker's note shows that the signal
# reached the sweep's whole process group.
FAKE_SWEEP = """#!{python}
import os, signal, subprocess, sys, time
log = os.environ["FAKE_LOG"]
def note(text):
    with open(log, "a") as f:
        f.write(text + "\\n")
got = []
def stop(signum, frame):
    got.append(signum)
    note(f"launcher got {{signal.Signals(signum).name}}")
for signum in (signal.SIGINT, signal.SIGTERM, signal.SIGUSR1):
    signal.signal(signum, stop)
worker = subprocess.Popen([sys.executable, "-c", WORKER, log])
while not (os.path.exists(log) and "ready" in open(log).read()):
    time.sleep(0.02)
note(f"started {{os.getpid()}}")
while not got:
    time.sleep(0.02)
time.sleep(0.5)  # the populations end their episodes and write their checkpoints
if worker.poll() is None:  # the signal did not reach it (SIGUSR1 to the launcher: the real one forwards it)
    worker.kill()
worker.wait()
note("ended")
sys.exit(128 + got[0])
"""
FAKE_WORKER = """import os, signal, sys, time
def stop(signum, frame):
    open(sys.argv[1], "a").write(f"worker got {signal.Signals(signum).name}\\n")
    sys.exit(128 + signum)
signal.signal(signal.SIGINT, stop)
signal.signal(signal.SIGTERM, stop)
open(sys.argv[1], "a").write(f"worker ready {os.getpid()}\\n")
time.sleep(30)
"""


def alive(pid: int) -> bool:
    """Whether process ``pid`` runs (a zombie, ended but not yet reaped, does not)."""
    try:
        return Path(f"/proc/{pid}/stat").read_text().rpartition(")")[2].split()[0] != "Z"
    except FileNotFoundError:
        return False


def _default_sigint() -> None:
    signal.signal(signal.SIGINT, signal.SIG_DFL)


@pytest.mark.parametrize("script, how", [
    (SCRIPT, "SIGTERM"), (SCRIPT, "SIGINT"), (SCRIPT, "timeout"), (SCRIPT, "SIGUSR1 to the sweep"),
    (SCRIPT, "SIGTERM twice"), (SCRIPT, "SIGTERM then to its group"),
    (SCRIPT.parent / "generalisation.sh", "SIGTERM")])
def test_a_stop_signal_stops_the_running_sweep_and_says_how_to_continue(tmp_path, script, how):
    """SIGTERM or SIGINT (Ctrl-C) to the script, or a timeout, reaches the running sweep's every process once; the
    script waits for the sweep to end and exits with 128 + signal and one line on how to continue. A sweep stopped
    by a signal of its own ends the script the same way. A second SIGTERM adds nothing (timeout sends its signal to
    the script and then to its process group: on a busy machine the script's trap ran for each), nor does a flood of
    SIGTERM to the script's process group, which ends any subshell the script forks meanwhile (a `$(jobs -pr)` in
    its trap so ended read as no job: the script hung or left the sweep running)."""
    fakes = tmp_path / "bin"
    fakes.mkdir()
    (fakes / "aia-train").write_text(FAKE_SWEEP.format(python=sys.executable).replace(
        "WORKER", repr(FAKE_WORKER)))
    (fakes / "python3").write_text("#!/bin/sh\necho 100\n")  # machine_speed's matmul rate, at once
    for fake in fakes.iterdir():
        fake.chmod(0o755)
    log = tmp_path / "fake.log"
    env = {**os.environ, "PATH": f"{fakes}{os.pathsep}{Path(sys.executable).parent}{os.pathsep}{os.environ['PATH']}",
           "FAKE_LOG": str(log), "PHASES": "learners", "OUT": str(tmp_path / "out"),
           "TRAIN_OVERRIDES": "compile.update=false"}
    command = ["timeout", "4", "bash", str(script)] if how == "timeout" else ["bash", str(script)]
    with (tmp_path / "stderr").open("w") as stderr:
        # with SIGINT as a terminal leaves it: a shell started with SIGINT ignored (a CI job run in the background)
        # cannot trap it, and passes that on to this script
        script_run = subprocess.Popen(command, env=env, stdout=subprocess.DEVNULL, stderr=stderr,
                                      preexec_fn=_default_sigint, start_new_session=how.endswith("group"))
    try:
        deadline = time.monotonic() + 20
        while not (log.exists() and "started" in log.read_text()):
            assert time.monotonic() < deadline and script_run.poll() is None, (tmp_path / "stderr").read_text()
            time.sleep(0.05)
        launcher, worker = fake_processes(log)
        if how.startswith("SIG"):
            signum = getattr(signal, how.split()[0])
            os.kill(launcher if how.endswith("to the sweep") else script_run.pid, signum)
            if how.endswith("twice"):
                time.sleep(0.2)  # while the script waits for the sweep
                os.kill(script_run.pid, signum)
            if how.endswith("group"):  # timeout's second signal, over and over while the script stops the sweep
                with contextlib.suppress(ProcessLookupError):  # the script's group is gone: it has ended
                    while script_run.poll() is None:
                        os.killpg(script_run.pid, signum)
                        time.sleep(0.001)
        else:
            signum = signal.SIGTERM  # what timeout sends
        script_run.wait(timeout=20)
        name = signal.Signals(signum).name
        lines = (tmp_path / "stderr").read_text().splitlines()
        assert script_run.returncode == (124 if how == "timeout" else 128 + signum), lines
        phase = "learners" if script == SCRIPT else "learners on paper_obstacles1"
        assert lines[-1] == (
            f"{script.name}: stopped by {name} in phase '{phase}', its running jobs ended: continue it with "
            'TRAIN_OVERRIDES="compile.update=false resume=auto" and the other variables as they were')
        notes = log.read_text().splitlines()[2:]
        if how.endswith("to the sweep"):
            assert notes[0] == f"launcher got {name}"
        else:  # each of the sweep's processes got the signal once
            assert sorted(notes[:-1]) == [f"launcher got {name}", f"worker got {name}"]
        assert notes[-1] == "ended"  # the script waited for the sweep
        assert not alive(launcher) and not alive(worker)
    finally:  # after a failure, nothing of the test is left running
        if script_run.poll() is None:
            script_run.kill()
            script_run.wait()
        for pid in fake_processes(log):
            if alive(pid):
                os.kill(pid, signal.SIGKILL)


def fake_processes(log: Path) -> list[int]:
    """The process ids of the fake sweep's launcher and worker that ``log`` names."""
    if not log.exists():
        return []
    words = log.read_text().split()
    pids = [int(words[words.index("ready") + 1])] if "ready" in words else []
    if "started" in words:
        pids = [int(words[words.index("started") + 1]), *pids]
    return pids
