"""The apps' JSON summaries: whole or not at all, a failed write in one line."""

from __future__ import annotations

import json

import pytest

import aia.apps.summary as summary
from aia.config.errors import WriteFailed


def test_a_summary_is_written_whole_and_a_full_disk_leaves_the_previous_one(tmp_path, full_disk):
    path = tmp_path / "eval.json"
    summary.write_json(path, {"scores": [1.0, 2.0]})
    assert json.loads(path.read_text()) == {"scores": [1.0, 2.0]}
    full_disk(summary, room=5)
    with pytest.raises(WriteFailed) as info:
        summary.write_json(path, {"scores": [3.0] * 100})
    assert str(path) in str(info.value) and "No space left on device" in str(info.value)
    assert "\n" not in str(info.value)
    assert json.loads(path.read_text()) == {"scores": [1.0, 2.0]} and sorted(tmp_path.iterdir()) == [path]
