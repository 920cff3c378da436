"""The apps' output files (``eval.json``, ``rollout.json``, ``aia-log``'s figures and tables): written whole or not
at all."""

from __future__ import annotations

import json
import os
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

from aia.config.errors import WriteFailed, os_error_text


@contextmanager
def written_whole(path: Path) -> Iterator[Path]:
    """A temporary path beside ``path`` to write its content to (with ``path``'s suffix, by which writers such as
    matplotlib's and PIL's pick the format), renamed over ``path`` when the block ends and removed if it raises
    (a full disk, Ctrl-C): ``path`` is then the previous file, or none, never part of the new one."""
    temporary = path.with_name(f".{path.stem}.partial{path.suffix}")
    try:
        yield temporary
        os.replace(temporary, path)
    except BaseException:
        temporary.unlink(missing_ok=True)
        raise


def write_json(path: Path, data: object) -> None:
    """Write ``data`` as JSON to ``path`` (:func:`written_whole`, synced to the disk first): a failed write ends
    the app in one line (:class:`~aia.config.errors.WriteFailed`, exit status 1)."""
    try:
        with written_whole(path) as temporary, open(temporary, "wb") as file:
            file.write(json.dumps(data, indent=2).encode())
            file.flush()
            os.fsync(file.fileno())
    except OSError as err:
        raise WriteFailed(path, os_error_text(err)) from None
