"""Read aia run logs back: whole, truncated (a killed run) or with corrupt chunks.

One sequential pass over the records (with the checks of ``mcap``'s ``StreamReader``) serves every case: a
complete file ends with its footer; a file cut short (no footer) yields every complete chunk before the cut; a
chunk whose CRC-32 or compression is broken is skipped, and described in :attr:`RunLog.damage` (which chunk, when
its messages were logged); a data section whose CRC-32 (written by :class:`~aia.logging.MCAPLogger`) does not
match is described there too. A file that is not MCAP raises :class:`RunLogError` with a one-line reason.
"""

from __future__ import annotations

import glob
import json
import struct
import time
import zlib
from collections import Counter
from collections.abc import Collection
from dataclasses import dataclass, field
from io import BytesIO
from pathlib import Path
from typing import Any

import numpy as np
import yaml
import zstandard
from mcap.data_stream import ReadDataStream
from mcap.exceptions import EndOfFile, InvalidMagic
from mcap.opcode import Opcode
from mcap.records import Attachment, Channel, Metadata, Schema
from mcap.stream_reader import CRCValidationError

from aia.logging import schemas
from aia.logging.metadata import STATUS_METADATA
from aia.logging.scenes import (
    PARTICLES_TOPIC,
    SCENE_TOPIC,
    TF_TOPIC,
    WORLD_TOPIC,
    SceneFrame,
    WorldInfo,
    parse_frame,
    parse_particle_cloud,
    parse_world,
    world_episode,
)
from aia.logging.segments import RESUMED_AFTER_KEY, is_later_segment, later_segments

# libyaml's parser where PyYAML has it: the same safe subset of YAML, and a run's config (2.6 kB) parses in 1.4 ms
# instead of 13 ms (best of 5), about 1 s less of `aia-log stats` over 80 runs
_YAML_LOADER = getattr(yaml, "CSafeLoader", yaml.SafeLoader)


class RunLogError(ValueError):
    """A path that cannot be read as an aia run log (missing, unreadable, not MCAP)."""


@dataclass
class LoggedMessage:
    """One message of a run log."""

    topic: str
    schema: str
    log_time: int
    data: bytes


@dataclass
class ScalarSeries:
    """The messages of one scalar topic, in log-time order."""

    frames: np.ndarray   # float (NaN where the message carried no frame)
    times: np.ndarray    # seconds since the epoch
    values: np.ndarray   # float (NaN for a logged non-finite value)


@dataclass
class RunLog:
    """The decoded content of one MCAP run log."""

    path: Path
    messages: list[LoggedMessage]
    metadata: dict[str, dict[str, str]] = field(default_factory=dict)
    attachments: dict[str, bytes] = field(default_factory=dict)
    complete: bool = True          # the footer was read
    damage: list[str] = field(default_factory=list)  # what was read around: damaged chunks, a bad data CRC
    problem: str | None = None     # why reading stopped before the footer
    segments: list[Path] = field(default_factory=list)  # later segments joined in (one per resume)
    only_topics: frozenset[str] | None = None  # the topics whose messages were read (None: all; see read_run)
    _config: dict[str, Any] | None = field(default=None, init=False, repr=False)

    @property
    def failure(self) -> str | None:
        """``"failed: <reason>"`` or ``"stopped: <reason>"`` for a run that ended early (metadata ``status``),
        else None."""
        status = self.metadata.get("status")
        return f"{status.get('status', 'failed')}: {status.get('reason', '?')}" if status else None

    def topic_counts(self) -> dict[str, tuple[str, int]]:
        """``topic -> (schema, message count)`` in order of first appearance."""
        counts = Counter(m.topic for m in self.messages)
        schemas_of = {m.topic: m.schema for m in self.messages}
        return {topic: (schemas_of[topic], counts[topic]) for topic in dict.fromkeys(m.topic for m in self.messages)}

    def time_span(self) -> tuple[float, float] | None:
        """First and last log time in seconds, or None for a log without messages."""
        if not self.messages:
            return None
        return self.messages[0].log_time / 1e9, self.messages[-1].log_time / 1e9

    def scalar_topics(self) -> list[str]:
        """Topics holding ``aia.Scalar`` messages."""
        return [t for t, (schema, _) in self.topic_counts().items() if schema == schemas.SCALAR]

    def scalars(self, topic: str) -> ScalarSeries:
        """The series of a scalar topic (a leading ``/`` is ignored); ValueError naming the known topics."""
        topic = self._scalar_topic(topic)
        decoded = [(json.loads(m.data), m.log_time) for m in self.messages if m.topic == topic]
        return ScalarSeries(
            frames=np.array([np.nan if d.get("frame") is None else d["frame"] for d, _ in decoded], dtype=float),
            times=np.array([t / 1e9 for _, t in decoded]),
            values=np.array([np.nan if d["value"] is None else d["value"] for d, _ in decoded], dtype=float),
        )

    def _scalar_topic(self, topic: str) -> str:
        known = self.scalar_topics()
        for candidate in (topic, topic.lstrip("/")):
            if candidate in known:
                return candidate
        raise ValueError(f"{self.path}: no scalar topic {topic!r}; it has {known}")

    def config(self) -> dict[str, Any]:
        """The run's resolved config (attachment ``config.yaml``, parsed once), or ``{}`` when not logged."""
        if self._config is None:
            data = self.attachments.get("config.yaml")
            self._config = yaml.load(data, Loader=_YAML_LOADER) or {} if data else {}
        return self._config

    def config_value(self, key: str) -> Any:
        """The value at dotted ``key`` in the config; a group (``algo``) reads as its ``name`` entry.
        Falls back to metadata ``run`` entries (``seed``, ``git_commit`` ...); None when absent."""
        node: Any = self.config()
        for part in key.split("."):
            if not isinstance(node, dict) or part not in node:
                return self.metadata.get("run", {}).get(key)
            node = node[part]
        return node.get("name", node) if isinstance(node, dict) else node

    def episodes(self) -> list[int]:
        """Indices of the recorded episodes, in recording order."""
        return [world_episode(m.data) for m in self.messages if m.topic == WORLD_TOPIC]

    def episode(self, which: int | str = "last") -> tuple[WorldInfo, list[SceneFrame]]:
        """The map and the frames of a recorded episode: its index, ``"first"`` or ``"last"``."""
        starts = [i for i, m in enumerate(self.messages) if m.topic == WORLD_TOPIC]
        if not starts:
            raise ValueError(f"{self.path}: no recorded episode (no {WORLD_TOPIC} messages)")
        worlds = [parse_world(self.messages[i].data) for i in starts]
        if which in ("first", "last"):
            pick = 0 if which == "first" else len(starts) - 1
        else:
            indices = [w.episode for w in worlds]
            if int(which) not in indices:
                raise ValueError(f"{self.path}: no recorded episode {which}; recorded: {indices}, 'first', 'last'")
            pick = indices.index(int(which))
        info = worlds[pick]
        end = starts[pick + 1] if pick + 1 < len(starts) else len(self.messages)
        transforms: dict[int, bytes] = {}
        clouds = {m.log_time: m.data for m in self.messages[starts[pick]:end] if m.topic == PARTICLES_TOPIC}
        frames = []
        for message in self.messages[starts[pick]:end]:
            if message.topic == TF_TOPIC:
                transforms[message.log_time] = message.data
            elif message.topic == SCENE_TOPIC and message.log_time in transforms:
                frame = parse_frame(transforms.pop(message.log_time), message.data)
                if message.log_time in clouds:
                    frame.particles = parse_particle_cloud(clouds[message.log_time])[0]
                if frame.episode == info.episode:
                    frames.append(frame)
        return info, frames


def read_run(path: str | Path, only_topics: Collection[str] | None = None) -> RunLog:
    """Read every message, metadata record and attachment of the run log at ``path``, joined with its later
    segments (:mod:`aia.logging.segments`: one per resume) into one history.

    ``only_topics``: keep only the messages of these topics (``aia-log stats`` and ``plot`` read their metric's).
    A chunk whose message indexes (written after it) name only other topics is then skipped unread: neither
    decompressed nor checked but by the data section's CRC-32, which still reports its damage. A 20-seed
    learner's log of 200 episodes has 335 chunks, 18 of them with an evaluation score, most of the rest recorded
    scenes: a setting's 80 learner logs and 20 ARVI logs read in 0.41 s for ``eval/score`` against 1.3-1.7 s
    whole (three reads of each)."""
    path = Path(path)
    run = _read_file(path, only_topics)
    for segment in later_segments(path):
        part = _read_file(segment, only_topics)
        after = int(part.metadata.get("run", {}).get(RESUMED_AFTER_KEY, 0))
        run.messages = [m for m in run.messages if m.log_time <= after] + part.messages
        # the last segment says how the run ended; the latest config is the one in force
        run.metadata = {k: v for k, v in run.metadata.items() if k != STATUS_METADATA} | part.metadata
        run.attachments |= part.attachments
        run.complete, run.problem = part.complete, part.problem
        run.damage += part.damage
        run.segments.append(segment)
    return run


def _read_file(path: Path, only_topics: Collection[str] | None = None) -> RunLog:
    """Read every message (of ``only_topics``, see :func:`read_run`), metadata record and attachment of the MCAP
    file at ``path``."""
    if path.is_dir():
        raise RunLogError(f"{path}: a folder, expected a run log file (e.g. {path / 'run.mcap'})")
    if not path.is_file():
        raise RunLogError(f"{path}: no such file")
    try:
        data = path.read_bytes()
    except OSError as err:
        raise RunLogError(f"{path}: cannot be read ({err.strerror})") from None
    return _read_records(path, data, only_topics)


def _read_records(path: Path, data: bytes, only_topics: Collection[str] | None = None) -> RunLog:
    """The run in ``data`` (a whole file), read in one pass over its records as ``mcap``'s ``StreamReader``
    with CRC checks reads them, but with the hot records parsed here: a message's and a chunk's fixed header by
    one ``struct`` unpack, the message indexes skipped by their length, chunks decompressed by one reused zstd
    decompressor (a run of 200 episodes writes about 360 chunks, one per flush) and CRC-checked. Schemas,
    channels, metadata and attachments (a few per file) are parsed by ``mcap``'s record classes. The same runs
    as ``StreamReader``'s records give, in 4.0 us a message instead of 8.9 (780 logs of tests and a 20-seed
    protocol, 1.6 M messages: 6.4 s against 14.1 s)."""
    run = RunLog(path, messages=[], complete=False,
                 only_topics=None if only_topics is None else frozenset(only_topics))
    walk = _RecordWalk(run)
    try:
        if not data.startswith(_MAGIC):
            raise EndOfFile() if len(data) < len(_MAGIC) else InvalidMagic(tuple(data[:len(_MAGIC)]))
        walk.top_level(data, len(_MAGIC))
    except InvalidMagic:
        if not run.messages and not run.metadata:
            raise RunLogError(f"{path}: not an MCAP file (bad magic bytes)") from None
        run.problem = "bad magic bytes at the end"
    except Exception as err:  # noqa: BLE001  (a cut or damaged record surfaces as struct, EOF, MCAP... errors)
        if not walk.channels and not walk.schema_names and not run.metadata and not data.startswith(_MAGIC):
            raise RunLogError(f"{path}: not a readable MCAP file ({type(err).__name__})") from None
        # a run that has only just started has its magic bytes (and header) but nothing else yet
        run.problem = f"file ends early or is damaged ({type(err).__name__})"
    walk.resolve()
    run.messages.sort(key=lambda m: m.log_time)
    return run


_RECORD_HEAD = struct.Struct("<BQ")        # opcode, body length
_MESSAGE_HEAD = struct.Struct("<HIQQ")     # channel id, sequence, log time, publish time
_DATA_END = struct.Struct("<I")            # the data section's CRC-32
_CHUNK_HEAD = struct.Struct("<QQQI")      # first and last log time, uncompressed size, uncompressed CRC-32
_U16, _U32, _U64 = struct.Struct("<H"), struct.Struct("<I"), struct.Struct("<Q")
_ZSTD = zstandard.ZstdDecompressor()


class _RecordWalk:
    """The records of one MCAP file into a :class:`RunLog`: what ``_read_records`` walks with."""

    def __init__(self, run: RunLog) -> None:
        self.run = run
        self.only = run.only_topics
        self.schema_names: dict[int, str] = {}
        self.channels: dict[int, tuple[str, str]] = {}  # channel id -> (topic, schema name)
        self.chunks = 0
        self.skipped = 0  # chunks skipped unread (only_topics)
        # A damaged chunk takes the schemas and channels first written in it along: the channels whose schema is
        # not known yet, and the messages of channels not known yet, wait for the copies in the summary section.
        self.unresolved_channels: dict[int, tuple[str, int]] = {}  # channel id -> (topic, schema id)
        self.pending: list[tuple[int, int, bytes]] = []  # (channel id, log time, payload)

    def resolve(self) -> None:
        """Add the waiting messages whose channel (and its schema) the rest of the file defined."""
        for channel_id, (topic, schema_id) in self.unresolved_channels.items():
            if schema_id in self.schema_names:
                self.channels.setdefault(channel_id, (topic, self.schema_names[schema_id]))
        for channel_id, log_time, payload in self.pending:
            channel = self.channels.get(channel_id)
            if channel is not None and self._kept(channel):
                self.run.messages.append(LoggedMessage(channel[0], channel[1], log_time, payload))
        self.pending.clear()

    def top_level(self, data: bytes, position: int) -> None:
        """The records from ``position`` to the footer and the magic bytes after it (EndOfFile when cut short,
        InvalidMagic for bad closing magic); a data section that fails its CRC is described in the run's damage."""
        run = self.run
        while True:
            opcode, body, end = _record(data, position)
            if opcode == Opcode.MESSAGE:
                self._message(data, body, end, run.messages)
            elif opcode == Opcode.CHUNK:
                if self.only is not None and self._nothing_kept(data, end):
                    self.chunks += 1
                    self.skipped += 1
                else:
                    self._chunk(data, body, end)
            elif opcode == Opcode.METADATA:
                record = Metadata.read(_stream(data, body, end))
                run.metadata[record.name] = dict(record.metadata)
            elif opcode == Opcode.ATTACHMENT:
                record = Attachment.read(_stream(data, body, end))
                run.attachments[record.name] = bytes(record.data)
            elif opcode == Opcode.DATA_END:
                (crc,) = _DATA_END.unpack_from(data, body)
                actual = zlib.crc32(memoryview(data)[:position]) if crc != 0 else 0
                if actual != crc and not run.damage:  # (a damaged chunk fails it too, and is named already)
                    where = (f"one of the {self.skipped} chunks not read or " if self.skipped else "") + "a record " \
                        "outside the chunks (a schema, channel, metadata or attachment)"
                    run.damage.append(f"the data section fails its CRC-32 check: {where} is damaged")
                # on to the summary section: its schemas and channels repeat those of the data section
            elif opcode == Opcode.FOOTER:
                run.complete = True
                if data[end:end + len(_MAGIC)] != _MAGIC:
                    raise InvalidMagic(tuple(data[end:end + len(_MAGIC)]))
                return
            else:
                self._definition(opcode, data, body, end)
            position = end

    def _chunk(self, data: bytes, body: int, end: int) -> None:
        """A chunk's messages, schemas and channels; a chunk that fails its CRC or decompression is skipped and
        described in the run's damage."""
        self.chunks += 1
        logged, size, crc, compression, records = _chunk_fields(data, body, end)
        messages: list[LoggedMessage] = []
        try:
            inner = _decompress(compression, records, size)
            actual = zlib.crc32(inner) if crc != 0 else 0
            if actual != crc:
                raise CRCValidationError(expected=crc, actual=actual, record=None)
            position = 0
            while position < len(inner):
                opcode, record_body, record_end = _record(inner, position)
                if opcode == Opcode.MESSAGE:
                    self._message(inner, record_body, record_end, messages)
                else:
                    self._definition(opcode, inner, record_body, record_end)
                position = record_end
        except Exception as err:  # noqa: BLE001  (a bad CRC or a broken compression: skip the chunk)
            self.run.damage.append(_damaged_chunk(self.chunks, logged, err))
            return
        self.run.messages.extend(messages)

    def _kept(self, channel: tuple[str, str]) -> bool:
        return self.only is None or channel[0] in self.only

    def _nothing_kept(self, data: bytes, position: int) -> bool:
        """Whether the chunk ending at ``position`` holds no message to keep: the message indexes written right
        after it name only channels defined before it, of topics not kept (a channel not defined yet may be
        defined in the chunk itself, which is then read; so is a chunk without indexes)."""
        indexed = False
        while position + _RECORD_HEAD.size + _U16.size <= len(data):
            opcode, length = _RECORD_HEAD.unpack_from(data, position)
            if opcode != Opcode.MESSAGE_INDEX:
                break
            (channel_id,) = _U16.unpack_from(data, position + _RECORD_HEAD.size)
            channel = self.channels.get(channel_id)
            if channel is None or self._kept(channel):
                return False
            indexed = True
            position += _RECORD_HEAD.size + length
        return indexed

    def _message(self, data: bytes, body: int, end: int, into: list[LoggedMessage]) -> None:
        channel_id, _, log_time, _ = _MESSAGE_HEAD.unpack_from(data, body)
        channel = self.channels.get(channel_id)
        if channel is not None:
            if not self._kept(channel):
                return
            into.append(LoggedMessage(channel[0], channel[1], log_time, data[body + _MESSAGE_HEAD.size:end]))
        else:
            self.pending.append((channel_id, log_time, data[body + _MESSAGE_HEAD.size:end]))

    def _definition(self, opcode: int, data: bytes, body: int, end: int) -> None:
        """A schema or a channel (other records, indexes and statistics, carry nothing a run log keeps)."""
        if opcode == Opcode.SCHEMA:
            schema = Schema.read(_stream(data, body, end))
            self.schema_names[schema.id] = schema.name
        elif opcode == Opcode.CHANNEL:
            channel = Channel.read(_stream(data, body, end))
            if channel.schema_id == 0 or channel.schema_id in self.schema_names:
                self.channels[channel.id] = (channel.topic, self.schema_names.get(channel.schema_id, ""))
            else:
                self.unresolved_channels[channel.id] = (channel.topic, channel.schema_id)


def _record(data: bytes, position: int) -> tuple[int, int, int]:
    """``(opcode, body start, body end)`` of the record at ``position`` (EndOfFile where the data ends first)."""
    if position + _RECORD_HEAD.size > len(data):
        raise EndOfFile()
    opcode, length = _RECORD_HEAD.unpack_from(data, position)
    body = position + _RECORD_HEAD.size
    if body + length > len(data):
        raise EndOfFile()
    return opcode, body, body + length


def _chunk_fields(data: bytes, body: int, end: int) -> tuple[tuple[int, int], int, int, str, bytes]:
    """``((start, end) log times, uncompressed size, uncompressed CRC-32, compression, compressed records)`` of
    the chunk record whose body spans ``data[body:end]`` (MCAP's Chunk layout; EndOfFile if it overruns)."""
    start, stop, size, crc = _CHUNK_HEAD.unpack_from(data, body)
    position = body + _CHUNK_HEAD.size
    (length,) = _U32.unpack_from(data, position)
    compression = data[position + 4:position + 4 + length].decode()
    position += 4 + length
    (length,) = _U64.unpack_from(data, position)
    position += 8
    if position + length > end:
        raise EndOfFile()
    return (start, stop), size, crc, compression, data[position:position + length]


def _decompress(compression: str, records: bytes, size: int) -> bytes:
    """A chunk's records, decompressed (``zstd`` by one reused decompressor, ``lz4`` or none)."""
    if compression == "zstd":
        return _ZSTD.decompress(records, max_output_size=size)
    if compression == "lz4":
        import lz4.frame

        return lz4.frame.decompress(records)
    if compression:
        raise ValueError(f"unknown chunk compression {compression!r}")
    return records


def _stream(data: bytes, body: int, end: int) -> ReadDataStream:
    return ReadDataStream(BytesIO(data[body:end]))


_MAGIC = b"\x89MCAP0\r\n"


def _damaged_chunk(number: int, logged_ns: tuple[int, int], error: Exception) -> str:
    """``"chunk 3 (logged 09:40:01 -> 09:40:05) fails its CRC-32 check: its messages are skipped"``."""
    logged = " -> ".join(time.strftime("%Y-%m-%d %H:%M:%S", time.localtime(ns / 1e9)) for ns in logged_ns)
    what = ("fails its CRC-32 check" if isinstance(error, CRCValidationError)
            else f"cannot be decompressed ({type(error).__name__})")
    return f"chunk {number} (logged {logged}) {what}: its messages are skipped"


def find_runs(patterns: list[str]) -> list[Path]:
    """MCAP files named by ``patterns``: files, folders (searched recursively) or globs (``**`` allowed)."""
    found: list[Path] = []
    for pattern in patterns:
        matches = [Path(p) for p in sorted(glob.glob(pattern, recursive=True))] or [Path(pattern)]
        for match in matches:
            if match.is_dir():  # a run's later segments are read with its first one
                found.extend(p for p in sorted(match.rglob("*.mcap")) if not is_later_segment(p))
            elif match.exists():
                found.append(match)
            else:
                raise RunLogError(f"{pattern}: no such file, folder or glob match")
    if not found:
        raise RunLogError(f"no .mcap files under {patterns}")
    return list(dict.fromkeys(found))
