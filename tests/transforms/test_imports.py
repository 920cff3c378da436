"""The transforms package imports on its own, before the env package (it builds on the env's modules, and the
env's factory composes the transforms)."""

from __future__ import annotations

import subprocess
import sys


def test_the_transforms_import_before_the_env_package():
    code = "import aia.transforms\nfrom aia.envs import TrackingTransformedEnv, make_env\n"
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert result.returncode == 0, result.stderr.strip().splitlines()[-1:]
