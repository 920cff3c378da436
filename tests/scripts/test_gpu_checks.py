"""scripts/gpu_checks.sh refuses, in one line and before writing anything but its folder, a device it cannot use
and a step it does not have."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

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
