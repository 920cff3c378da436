"""scripts/gpu_checks.sh refuses, in one line and before writing anything but its folder, a device it cannot use
and a step it does not have; every benchmark it calls accepts the options it passes."""

from __future__ import annotations

import os
import re
import shlex
import subprocess
import sys
from pathlib import Path

from tests.benchmarks.test_benchmarks import _main, _script

SCRIPT = Path(__file__).resolve().parents[2] / "scripts" / "gpu_checks.sh"


def test_a_device_this_machine_lacks_gets_one_line_and_status_2(tmp_path):
    path = f"{Path(sys.executable).parent}{os.pathsep}{os.environ.get('PATH', '')}"
    for device in ("cuda:99", "cpu"):
        result = subprocess.run(["bash", str(SCRIPT)], cwd=tmp_path, capture_output=True, text=True, timeout=120,
                                env={**os.environ, "PATH": path, "DEVICE": device, "OUT": "checks"})
        assert result.returncode == 2
        assert result.stderr == (f"gpu_checks.sh: DEVICE={device}: not a CUDA device this machine has (cuda, "
                                 "cuda:0, ...); run it where torch sees a GPU\n")
        assert list((tmp_path / "checks").iterdir()) == []


def test_an_unknown_step_gets_one_line_and_status_2(tmp_path):
    result = subprocess.run(["bash", str(SCRIPT)], cwd=tmp_path, capture_output=True, text=True, timeout=60,
                            env={**os.environ, "STEPS": "profile,nope", "OUT": "checks"})
    assert result.returncode == 2
    assert result.stderr == ("gpu_checks.sh: STEPS=profile,nope: expected a comma-separated subset of "
                             "profile,eager,compiled,quickstart,sweep,envs\n")
    assert list((tmp_path / "checks").iterdir()) == []


def _benchmark_calls(variables: dict[str, str]) -> list[tuple[str, list[str]]]:
    """Each ``python3 "$ROOT/benchmarks/<name>.py" ...`` call of the script: the benchmark's name and its arguments,
    with ``$VAR`` from ``variables`` and ``${VAR:-default}`` as its default (the script's lines joined where they
    continue)."""
    text = SCRIPT.read_text().replace("\\\n", " ")
    calls = []
    for match in re.finditer(r'python3 "\$ROOT/benchmarks/(\w+)\.py" ([^>\n]*)', text):
        words = re.sub(r"\$\{(\w+):-([^}]*)\}", r"\2", match[2])
        words = re.sub(r"\$(\w+)", lambda var: variables[var[1]], words)
        calls.append((match[1], shlex.split(words)))
    return calls


def test_every_benchmark_call_parses_with_its_benchmarks_options(tmp_path, monkeypatch):
    # a GPU session is rare and its device time short: an option the benchmark refuses (the envs step's cases with
    # overrides once were) must fail here, not there
    variables = {"DEVICE": "cuda", "ALGOS": "dqn,adfq,conv", "EAGER_P": "1,20,80,320", "COMPILED_P": "1,20,320",
                 "OUT": str(tmp_path)}
    calls = _benchmark_calls(variables)
    assert sorted({name for name, _ in calls}) == ["env_throughput", "population", "step_profile"]
    for name, args in calls:
        # --help last: argparse converts (and so checks) every option before it, then prints the help and exits 0
        assert _main(_script(name, monkeypatch), [*args, "--help"], monkeypatch) == 0, (name, args)
