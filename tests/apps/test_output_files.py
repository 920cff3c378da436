"""The apps' output files: whole or not at all (a full disk, Ctrl-C while writing), a failed write in one line."""

from __future__ import annotations

import json

import pytest

import aia.apps.output_files as output_files
from aia.config.errors import WriteFailed


def test_a_summary_is_written_whole_and_a_full_disk_leaves_the_previous_one(tmp_path, full_disk):
    path = tmp_path / "eval.json"
    output_files.write_json(path, {"scores": [1.0, 2.0]})
    assert json.loads(path.read_text()) == {"scores": [1.0, 2.0]}
    full_disk(output_files, room=5)
    with pytest.raises(WriteFailed) as info:
        output_files.write_json(path, {"scores": [3.0] * 100})
    assert str(path) in str(info.value) and "No space left on device" in str(info.value)
    assert "\n" not in str(info.value)
    assert json.loads(path.read_text()) == {"scores": [1.0, 2.0]} and sorted(tmp_path.iterdir()) == [path]


def test_an_interrupted_write_leaves_the_previous_file_and_no_part_of_the_new_one(tmp_path):
    path = tmp_path / "curves.png"
    path.write_bytes(b"previous")
    with pytest.raises(KeyboardInterrupt), output_files.written_whole(path) as temporary:
        assert temporary.suffix == ".png" and temporary.parent == tmp_path
        temporary.write_bytes(b"half of the ne")
        raise KeyboardInterrupt
    assert sorted(tmp_path.iterdir()) == [path] and path.read_bytes() == b"previous"
    with output_files.written_whole(path) as temporary:
        temporary.write_bytes(b"new")
    assert sorted(tmp_path.iterdir()) == [path] and path.read_bytes() == b"new"
