"""A checkpoint as aia-eval reads it: once per state of its file, and refused once damaged."""

from __future__ import annotations

import os

import pytest

from aia.evaluation.checkpoints import load_checkpoint


def test_a_checkpoint_is_read_once_per_state_of_its_file(tmp_path, checkpoint):
    copy = tmp_path / "copy.pt"
    copy.write_bytes(checkpoint.read_bytes())
    first = load_checkpoint(copy)
    assert load_checkpoint(str(copy)) is first  # the validation, the guard and the evaluation
    os.utime(copy, ns=(copy.stat().st_atime_ns, copy.stat().st_mtime_ns + 1))  # written again: read again
    again = load_checkpoint(copy)
    assert again is not first and again["state"]["frames"] == first["state"]["frames"]
    copy.write_bytes(copy.read_bytes()[:1000])  # damaged since: refused, not the copy read before
    with pytest.raises(ValueError, match="copy.pt.*not a whole zip archive"):
        load_checkpoint(copy)
