"""read_run: complete logs, logs cut at any byte, corrupt chunks, and files that are not MCAP."""

from __future__ import annotations

import pytest

from aia.logging import MCAPLogger, RunLogError, find_runs, read_run, reader


def _chunked_log(path, chunks=6, per_chunk=40, compression="zstd"):
    """A log whose every ``per_chunk`` scalars end in a flush (one chunk each); returns the file size after
    each flush."""
    logger = MCAPLogger("exp", path, flush_interval_s=3600, compression=compression)
    logger.log_hparams({"algo": {"name": "dqn"}, "seed": 1})
    sizes = []
    for chunk in range(chunks):
        for i in range(per_chunk):
            logger.log_scalar("eval/score", float(chunk * per_chunk + i), step=chunk * per_chunk + i)
        logger.flush()
        sizes.append((path / "run.mcap").stat().st_size)
    logger.close()
    return (path / "run.mcap").read_bytes(), sizes


def test_complete_log(tmp_path):
    data, _ = _chunked_log(tmp_path)
    run = read_run(tmp_path / "run.mcap")
    assert run.complete and run.problem is None and run.damage == []
    assert run.scalars("eval/score").values.tolist() == [float(i) for i in range(240)]
    assert run.config_value("algo") == "dqn" and run.config_value("seed") == 1
    assert run.config_value("algo.name") == "dqn" and run.config_value("nothing.here") is None


@pytest.mark.parametrize("fraction", [0.15, 0.4, 0.55, 0.8, 0.97, 0.999])
def test_a_cut_file_yields_every_chunk_before_the_cut(tmp_path, fraction):
    data, sizes = _chunked_log(tmp_path)
    cut = int(len(data) * fraction)
    (tmp_path / "cut.mcap").write_bytes(data[:cut])
    run = read_run(tmp_path / "cut.mcap")
    flushed = sum(size <= cut for size in sizes)  # chunks whose records (and indexes) lie before the cut
    values = run.scalars("eval/score").values.tolist() if "eval/score" in run.scalar_topics() else []
    # the chunk in progress at the cut counts too when the cut falls after it, among its index records
    assert len(values) in (40 * flushed, 40 * (flushed + 1))
    assert values == [float(i) for i in range(len(values))]
    assert not run.complete and "ends early" in run.problem


def test_a_corrupt_chunk_is_skipped_and_counted(tmp_path):
    data, sizes = _chunked_log(tmp_path)
    middle = sizes[1] + 80  # the third chunk starts at sizes[1]; its compressed records after a 61-byte header
    damaged = bytearray(data)
    damaged[middle:middle + 8] = bytes(8)
    (tmp_path / "bad.mcap").write_bytes(bytes(damaged))
    run = read_run(tmp_path / "bad.mcap")
    assert len(run.damage) == 1 and run.damage[0].startswith("chunk 3 (logged ")
    assert run.scalars("eval/score").values.tolist() == [float(i) for i in range(240) if not 80 <= i < 120]


@pytest.mark.parametrize("offset", [70, 400, 1000])  # bytes into the second chunk's uncompressed records
def test_a_flipped_byte_in_a_chunk_fails_its_crc_and_is_read_around(tmp_path, offset):
    data, sizes = _chunked_log(tmp_path, compression="none")
    damaged = bytearray(data)
    damaged[sizes[0] + offset] ^= 0x01  # a scalar's digit: still a well-formed record, caught by the CRC alone
    (tmp_path / "bad.mcap").write_bytes(bytes(damaged))
    run = read_run(tmp_path / "bad.mcap")
    assert run.complete and len(run.damage) == 1
    assert run.damage[0].startswith("chunk 2 (logged ") and "fails its CRC-32 check" in run.damage[0]
    assert run.scalars("eval/score").values.tolist() == [float(i) for i in range(240) if not 40 <= i < 80]


def test_a_damaged_first_chunk_loses_only_its_own_messages(tmp_path):
    # the first chunk also holds the schema and channel records: the later chunks' messages are read through the
    # summary section's copies
    data, sizes = _chunked_log(tmp_path, compression="none")
    damaged = bytearray(data)
    first_chunk = data.index(b"eval/score")  # the channel record, inside the first chunk
    damaged[first_chunk + 200] ^= 0x01
    (tmp_path / "bad.mcap").write_bytes(bytes(damaged))
    run = read_run(tmp_path / "bad.mcap")
    assert run.complete and len(run.damage) == 1 and run.damage[0].startswith("chunk 1 (logged ")
    scores = run.scalars("eval/score")
    assert scores.values.tolist() == [float(i) for i in range(40, 240)]
    assert {m.schema for m in run.messages} == {"aia.Scalar"}


def test_a_damaged_record_outside_the_chunks_fails_the_data_crc(tmp_path):
    data, _ = _chunked_log(tmp_path)
    damaged = bytearray(data)
    where = data.index(b"algo.name")  # the config's metadata record, written outside the chunks
    damaged[where] = ord("A")
    (tmp_path / "bad.mcap").write_bytes(bytes(damaged))
    run = read_run(tmp_path / "bad.mcap")
    assert run.damage == ["the data section fails its CRC-32 check: a record outside the chunks (a schema, "
                          "channel, metadata or attachment) is damaged"]
    assert len(run.scalars("eval/score").values) == 240


def _two_topic_log(path, compression="zstd"):
    """A log of six chunks (one flush each): the first holds ``eval/score`` and ``train/loss`` (both channels are
    defined there), then ``train/loss`` alone and ``eval/score`` alone by turns; returns the file and the size after
    each flush."""
    logger = MCAPLogger("exp", path, flush_interval_s=3600, compression=compression)
    logger.log_hparams({"algo": {"name": "dqn"}, "seed": 1})
    sizes = []
    for chunk in range(6):
        topics = ("eval/score", "train/loss") if chunk == 0 else ("train/loss",) if chunk % 2 else ("eval/score",)
        for i in range(30):
            for topic in topics:
                logger.log_scalar(topic, float(chunk * 30 + i), step=chunk * 30 + i)
        logger.flush()
        sizes.append((path / "run.mcap").stat().st_size)
    logger.close()
    return (path / "run.mcap").read_bytes(), sizes


def _decompressions(monkeypatch) -> list[int]:
    """A list that grows by one at every chunk the reader decompresses."""
    calls: list[int] = []
    decompress = reader._decompress
    monkeypatch.setattr(reader, "_decompress", lambda *args: calls.append(1) or decompress(*args))
    return calls


def test_a_read_of_some_topics_keeps_their_messages_and_skips_the_other_chunks_unread(tmp_path, monkeypatch):
    _two_topic_log(tmp_path)
    calls = _decompressions(monkeypatch)
    whole = read_run(tmp_path / "run.mcap")
    assert len(calls) == 6 and whole.only_topics is None
    calls.clear()
    scores = read_run(tmp_path / "run.mcap", ["eval/score"])
    assert len(calls) == 3  # chunks 2, 4 and 6 hold train/loss alone: not decompressed
    assert scores.only_topics == {"eval/score"} and scores.complete and scores.damage == []
    assert scores.messages == [m for m in whole.messages if m.topic == "eval/score"]
    assert scores.scalars("eval/score").values.tolist() == [float(i) for i in (*range(30), *range(60, 90),
                                                                                *range(120, 150))]
    assert scores.metadata == whole.metadata and scores.attachments == whole.attachments
    assert scores.config_value("algo") == "dqn"


def test_a_damaged_chunk_skipped_unread_still_fails_the_data_crc(tmp_path):
    data, sizes = _two_topic_log(tmp_path, compression="none")
    damaged = bytearray(data)
    damaged[sizes[0] + 400] ^= 0x01  # inside the second chunk: train/loss alone
    (tmp_path / "bad.mcap").write_bytes(bytes(damaged))
    whole = read_run(tmp_path / "bad.mcap")
    assert len(whole.damage) == 1 and whole.damage[0].startswith("chunk 2 (logged ")
    scores = read_run(tmp_path / "bad.mcap", ["eval/score"])
    assert scores.damage == ["the data section fails its CRC-32 check: one of the 3 chunks not read or a record "
                             "outside the chunks (a schema, channel, metadata or attachment) is damaged"]
    assert scores.messages == [m for m in whole.messages if m.topic == "eval/score"]


@pytest.mark.parametrize("fraction", [0.1, 0.3, 0.5, 0.7, 0.9, 0.999])
def test_a_read_of_some_topics_of_a_cut_file_keeps_what_the_whole_read_keeps(tmp_path, fraction):
    data, _ = _two_topic_log(tmp_path)
    (tmp_path / "cut.mcap").write_bytes(data[:int(len(data) * fraction)])
    whole = read_run(tmp_path / "cut.mcap")
    scores = read_run(tmp_path / "cut.mcap", ["eval/score"])
    assert scores.messages == [m for m in whole.messages if m.topic == "eval/score"]
    assert scores.complete == whole.complete and scores.problem == whole.problem is not None


def test_files_that_are_not_logs(tmp_path):
    (tmp_path / "notes.mcap").write_text("hello, this is not a log\n" * 10)
    with pytest.raises(RunLogError, match="not an MCAP file"):
        read_run(tmp_path / "notes.mcap")
    (tmp_path / "empty.mcap").write_bytes(b"")
    with pytest.raises(RunLogError, match="empty.mcap: not a readable MCAP file"):
        read_run(tmp_path / "empty.mcap")
    (tmp_path / "magic.mcap").write_bytes(b"\x89MCAP0\r\n\x01\x05")  # a run that has only just started
    started = read_run(tmp_path / "magic.mcap")
    assert not started.complete and "ends early" in started.problem and started.messages == []
    with pytest.raises(RunLogError, match="no such file"):
        read_run(tmp_path / "missing.mcap")
    with pytest.raises(RunLogError, match=f"{tmp_path}: a folder, expected a run log file"):
        read_run(tmp_path)


def test_find_runs_expands_folders_and_globs(tmp_path):
    for name in ("a/0", "a/1", "b/0"):
        MCAPLogger("exp", tmp_path / name).close()
    assert len(find_runs([str(tmp_path / "a")])) == 2
    assert len(find_runs([str(tmp_path / "**" / "run.mcap")])) == 3
    assert len(find_runs([str(tmp_path / "a"), str(tmp_path / "a/0/run.mcap")])) == 2  # no duplicates
    with pytest.raises(RunLogError, match="nothing"):
        find_runs([str(tmp_path / "nothing*")])


def test_unknown_scalar_topic_names_the_known_ones(tmp_path):
    _chunked_log(tmp_path, chunks=1)
    with pytest.raises(ValueError, match=r"no scalar topic 'eval/scor'; it has \['eval/score'\]"):
        read_run(tmp_path / "run.mcap").scalars("eval/scor")
    assert len(read_run(tmp_path / "run.mcap").scalars("/eval/score").values) == 40
