"""The checks every benchmark's command line shares: ``--device`` and ``--out`` are refused in one line (exit
status 2) before any measuring, instead of a traceback after it."""

from __future__ import annotations

import argparse
import os

from aia.config.checks import Device
from aia.config.errors import ConfigError, os_error_text


def parse_checked(parser: argparse.ArgumentParser) -> argparse.Namespace:
    """``parser.parse_args()`` with its ``--device`` (a device this machine has: the apps' check,
    :class:`aia.config.checks.Device`) and ``--out`` (a file path whose folder exists or can be made, not a folder)
    checked; the folder of ``--out`` is made here."""
    args = parser.parse_args()
    device = getattr(args, "device", None)
    if device is not None:
        try:
            Device()("--device", device)  # the apps' check of device=
        except ConfigError as err:
            parser.error(f"--device {device!r}: expected {err.allowed}")
    out = getattr(args, "out", None)
    if out is not None:
        if out.is_dir() or str(out).endswith(os.sep):
            parser.error(f"--out {out}: a folder, expected a file path (e.g. {out / 'results.json'})")
        try:
            out.parent.mkdir(parents=True, exist_ok=True)
        except OSError as err:
            parser.error(f"--out {out}: its folder cannot be made ({os_error_text(err)})")
        if not os.access(out.parent, os.W_OK):
            parser.error(f"--out {out}: its folder {out.parent} is not writable")
    return args
