"""freeze_at_exit: the objects alive at exit are frozen before the interpreter's teardown, registered once."""

from __future__ import annotations

import subprocess
import sys

CHILD = """
import atexit, gc, sys
atexit.register(lambda: print("frozen at exit:", gc.get_freeze_count() > 0))  # runs after the handlers below
from aia.runtime.process_exit import freeze_at_exit
before = atexit._ncallbacks()
freeze_at_exit()
freeze_at_exit()
print("handlers added:", atexit._ncallbacks() - before)
print("frozen while running:", gc.get_freeze_count() > 0)
"""


def test_a_process_freezes_its_objects_once_its_exit_handlers_run_and_registers_once():
    result = subprocess.run([sys.executable, "-c", CHILD], capture_output=True, text=True, timeout=60, check=True)
    assert result.stdout.splitlines() == ["handlers added: 1", "frozen while running: False", "frozen at exit: True"]
