"""A run's checkpoint files: written whole or not at all, the last two kept, verified before they are read.

``torch.save`` writes a zip archive whose every record (the pickle, each tensor's bytes) carries a CRC-32 that
``torch.load`` never checks; :func:`checkpoint_damage` checks them all (``zipfile``'s ``testzip``) and the one
bit of the zip directory that ``testzip`` ignores but torch's reader obeys, so a torn or bit-flipped file is
refused instead of resuming from corrupted parameters, Adam moments or replay rows. (Of a 58 kB checkpoint, every
byte outside the records' data flipped in turn: each flip is refused here, refused by ``torch.load`` itself, or
loads exactly the original.)

:func:`save_checkpoints` writes every member's new checkpoint beside its old one (``last.tmp``, flushed to
disk) and only when all of them are written moves each member's ``last.pt`` to ``previous.pt`` and the new file
to ``last.pt``. A failed write (a full disk, a lost mount) removes the temporary files and leaves every member's
checkpoints as they were (a population stays at one point), and raises :class:`~aia.config.errors.WriteFailed`.
"""

from __future__ import annotations

import os
import zipfile
from collections.abc import Iterable
from pathlib import Path

import torch

from aia.config.errors import WriteFailed, os_error_text
from aia.training.checkpoint_names import CHECKPOINT_NAME, PREVIOUS_CHECKPOINT_NAME

_MSDOS_FOLDER = 0x10  # the folder bit of a zip record's external attributes: torch's reader skips such a record


def checkpoint_damage(path: Path) -> str | None:
    """None if ``path`` is a whole zip archive whose every record matches its CRC-32, else what is wrong."""
    try:
        with zipfile.ZipFile(path) as archive:
            bad = archive.testzip()
            folders = [info.filename for info in archive.infolist() if info.external_attr & _MSDOS_FOLDER]
    except OSError as err:
        return f"it cannot be read ({os_error_text(err)})"
    except Exception as err:  # noqa: BLE001  (BadZipFile, or struct/zlib/EOF errors of a garbled zip directory)
        return f"it is not a whole zip archive ({type(err).__name__}: cut short or overwritten)"
    if bad is not None:
        return f"its record {bad} fails its CRC-32 check (damaged after it was written)"
    if folders:  # a flipped attribute bit in the zip directory, which testzip ignores and torch.load does not
        return f"its zip directory marks the record {folders[0]} as a folder (damaged after it was written)"
    return None


def save_checkpoints(checkpoints: Iterable[tuple[Path, dict]]) -> None:
    """Write each ``(run folder, checkpoint)`` as the folder's ``checkpoints/last.pt``, keeping the one before
    as ``checkpoints/previous.pt``: all of them or, on a failed write, none (see the module docstring)."""
    written: list[tuple[Path, Path]] = []  # (temporary file, run folder)
    target = Path()
    try:
        for out_dir, checkpoint in checkpoints:
            target = out_dir / CHECKPOINT_NAME
            written.append((_write_temporary(target, checkpoint), out_dir))
        for temporary, out_dir in written:
            target = out_dir / CHECKPOINT_NAME
            if target.exists():
                os.replace(target, out_dir / PREVIOUS_CHECKPOINT_NAME)
            os.replace(temporary, target)
    except BaseException as err:
        for temporary, _ in written:
            temporary.unlink(missing_ok=True)
        cause = _os_error(err)
        if cause is None:
            raise
        raise WriteFailed(target, os_error_text(cause)) from None


def _write_temporary(target: Path, checkpoint: dict) -> Path:
    """``checkpoint`` written and flushed to disk as ``target`` with the suffix ``.tmp`` (removed if that fails)."""
    temporary = target.with_suffix(".tmp")
    try:
        temporary.parent.mkdir(parents=True, exist_ok=True)
        with open(temporary, "wb") as file:
            torch.save(checkpoint, file)
            file.flush()
            os.fsync(file.fileno())
    except BaseException:
        temporary.unlink(missing_ok=True)
        raise
    return temporary


def _os_error(error: BaseException | None) -> OSError | None:
    """The OS error behind ``error`` (torch reports a failed write of its file object as a RuntimeError whose
    context is the OSError), or None."""
    while error is not None and not isinstance(error, OSError):
        error = error.__context__
    return error
