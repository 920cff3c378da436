"""scripts/reproduce.sh end to end on a tiny budget: learner and ARVI runs, curves, table, trajectory picture."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

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
