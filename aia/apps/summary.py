"""The apps' JSON summaries (``eval.json``, ``rollout.json``): written whole or not at all."""

from __future__ import annotations

import json
import os
from pathlib import Path

from aia.config.errors import WriteFailed, os_error_text


def write_json(path: Path, data: object) -> None:
    """Write ``data`` as JSON to ``path`` through a temporary file renamed over it: a failed write (a full
    disk) leaves the previous file as it was and no temporary file, and ends the app in one line
    (:class:`~aia.config.errors.WriteFailed`, exit status 1)."""
    temporary = path.with_name(path.name + ".tmp")
    try:
        with open(temporary, "wb") as file:
            file.write(json.dumps(data, indent=2).encode())
            file.flush()
            os.fsync(file.fileno())
        os.replace(temporary, path)
    except OSError as err:
        temporary.unlink(missing_ok=True)
        raise WriteFailed(path, os_error_text(err)) from None
