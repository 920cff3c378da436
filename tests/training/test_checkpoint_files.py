"""Checkpoint files: a flipped byte anywhere that matters is refused by every reader (resume=, resume=auto, the
population launcher's grouping, aia-eval); resume=auto falls back to the previous checkpoint and says so; a failed
write leaves every member's checkpoints as they were and no temporary file. One tiny real run serves them all."""

from __future__ import annotations

import shutil
import zipfile

import pytest
import torch
from hydra import compose, initialize_config_module

import aia.training.checkpoint_files as checkpoint_files
from aia.config.errors import ConfigError, WriteFailed
from aia.evaluation.checkpoints import load_checkpoint
from aia.training import train
from aia.training.checkpoint_files import checkpoint_damage, save_checkpoints
from aia.training.resuming import load_resumable, resume_path, resume_point

SMALL = ("env.max_steps=40", "warmup_frames=100", "eval.episodes=2", "batch_size=16", "hidden=[32,32]",
         "logger=none", "checkpoint_every_frames=40", "seed=5")


def _config(*overrides: str):
    with initialize_config_module(config_module="aia.conf", version_base="1.3"):
        return compose(config_name="train", overrides=[*SMALL, *overrides])


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    """A 100-frame run's folder: checkpoints/last.pt at frame 100 (its end), checkpoints/previous.pt at frame 80."""
    folder = tmp_path_factory.mktemp("run")
    train(_config("frames=100"), folder)
    return folder


def _copy(run, tmp_path):
    shutil.copytree(run, tmp_path / "run")
    return tmp_path / "run"


def _record_of(path, tensor: torch.Tensor) -> str:
    """The zip record holding ``tensor``'s bytes."""
    with zipfile.ZipFile(path) as archive:
        wanted = tensor.numpy().tobytes()
        return next(name for name in archive.namelist() if archive.read(name) == wanted)


def _record_offset(path, name: str) -> int:
    """Where record ``name``'s data starts in the file."""
    with zipfile.ZipFile(path) as archive, open(path, "rb") as file:
        info = archive.getinfo(name)
        file.seek(info.header_offset + 26)
        lengths = file.read(4)
        return info.header_offset + 30 + int.from_bytes(lengths[:2], "little") + int.from_bytes(lengths[2:], "little")


def _flip(path, offset: int) -> None:
    data = bytearray(path.read_bytes())
    data[offset] ^= 0xFF
    path.write_bytes(bytes(data))


def test_the_run_keeps_its_last_two_checkpoints(run):
    assert sorted(p.name for p in (run / "checkpoints").iterdir()) == ["last.pt", "previous.pt"]
    frames = [torch.load(run / "checkpoints" / name, weights_only=False)["state"]["frames"]
              for name in ("last.pt", "previous.pt")]
    assert frames == [100, 80] and checkpoint_damage(run / "checkpoints" / "last.pt") is None
    assert not (run / "run.lock").exists()


@pytest.mark.parametrize("part", ["the pickle", "a parameter", "an Adam moment", "a replay row",
                                  "a zip directory CRC", "a zip directory folder bit", "a torn file"])
def test_a_flipped_byte_is_refused_by_every_reader(run, tmp_path, part):
    folder = _copy(run, tmp_path)
    last = folder / "checkpoints" / "last.pt"
    saved = torch.load(last, weights_only=False)
    with zipfile.ZipFile(last) as archive:
        directory, first = archive.start_dir, archive.infolist()[0]
    records = {"the pickle": "data.pkl", "a parameter": next(iter(saved["online"].values())),
               "an Adam moment": saved["optimizer"]["exp_avg_sq"][0],
               "a replay row": saved["replay"]["transitions"]["observation"]}
    if part in records:
        record = records[part]
        name = record if isinstance(record, str) else _record_of(last, record)
        name = next(n for n in zipfile.ZipFile(last).namelist() if n.endswith(name))
        offset, expected = _record_offset(last, name) + 5, f"its record {name} fails its CRC-32 check"
    elif part == "a zip directory CRC":
        offset, expected = directory + 16, f"its record {first.filename} fails its CRC-32 check"
    elif part == "a zip directory folder bit":  # testzip ignores it; torch.load would read the record as empty
        offset, expected = directory + 38, f"marks the record {first.filename} as a folder"
    else:  # cut at three quarters, as by a node lost while a copy was under way
        offset, expected = None, "not a whole zip archive"
        last.write_bytes(last.read_bytes()[:last.stat().st_size * 3 // 4])
    if offset is not None:
        _flip(last, offset)
    assert expected in checkpoint_damage(last)
    with pytest.raises(ConfigError, match=f"resume='{last}': expected an undamaged checkpoint, but .*"
                                          f"continue from resume=.*previous.pt"):
        load_resumable(last, _config(), "cpu")
    with pytest.raises(ConfigError, match=f"checkpoint='{last}': expected an undamaged torch checkpoint"):
        load_checkpoint(last)  # aia-eval checkpoint=
    # the population launcher groups the job by the checkpoint resume=auto falls back to
    assert resume_point(_config("resume=auto"), folder)[0] == 80
    assert resume_point(_config(f"resume={last}"), folder) == str(last)  # fails alone, with load_resumable's line


def test_resume_auto_falls_back_to_the_previous_checkpoint_and_says_so(run, tmp_path, capsys):
    folder = _copy(run, tmp_path)
    last = folder / "checkpoints" / "last.pt"
    pickle = next(name for name in zipfile.ZipFile(last).namelist() if name.endswith("data.pkl"))
    _flip(last, _record_offset(last, pickle) + 5)  # inside a record (its middle byte may fall in a header)
    state = train(_config("frames=160", "resume=auto"), folder)
    out = capsys.readouterr().out
    assert f"{last} is damaged: its record" in out
    assert f"resuming from the checkpoint before it, {folder / 'checkpoints' / 'previous.pt'}" in out
    assert "at frame 80" in out and state.frames == 160
    assert torch.load(last, weights_only=False)["state"]["frames"] == 160  # the damaged file is replaced


def test_resume_auto_refuses_when_both_checkpoints_are_damaged(run, tmp_path):
    folder = _copy(run, tmp_path)
    for name in ("last.pt", "previous.pt"):
        _flip(folder / "checkpoints" / name, 100)
    with pytest.raises(ConfigError, match="resume='auto': expected an undamaged checkpoint in the run folder, but "
                                          ".*last.pt is damaged.*previous.pt is damaged.*start afresh"):
        resume_path(_config("resume=auto"), folder)
    assert resume_point(_config("resume=auto"), folder) == str(folder / "checkpoints" / "last.pt")


def test_a_failed_write_keeps_every_members_checkpoints_and_leaves_no_temporary_file(run, tmp_path, full_disk):
    """A population of two whose second member's write fails: neither member's files change (they stay at one
    point), the error names the file and the OS error, no .tmp is left."""
    folders = [_copy(run, tmp_path / str(k)) for k in range(2)]
    before = {p: p.read_bytes() for f in folders for p in (f / "checkpoints").iterdir()}
    checkpoint = torch.load(folders[0] / "checkpoints" / "last.pt", weights_only=False)
    full_disk(checkpoint_files, room=20_000, after=1)  # the first member's file is written whole
    with pytest.raises(WriteFailed) as failed:
        save_checkpoints((folder, checkpoint) for folder in folders)
    assert str(failed.value).startswith(f"could not write {folders[1] / 'checkpoints' / 'last.pt'} ([Errno 28] "
                                        "No space left on device)")
    assert {p: p.read_bytes() for f in folders for p in (f / "checkpoints").iterdir()} == before
