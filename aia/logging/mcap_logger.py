"""``MCAPLogger``: a TorchRL :class:`~torchrl.record.loggers.Logger` that writes one MCAP file per run.

What goes where
    * every scalar metric on its own topic (``train/loss``, ``eval/score``, ...), schema ``aia.Scalar``,
      payload ``{"frame": <step>, "value": <float>}`` (``null`` for a non-finite value);
    * ``log_histogram`` on its topic as ``aia.Histogram``; ``log_video`` frames as ``foxglove.CompressedImage``
      (PNG); ``log_text`` as ``foxglove.Log`` on ``/log``; recorded episodes as Foxglove scenes
      (:mod:`aia.logging.scenes`, written by :class:`aia.logging.SceneRecorder`);
    * metadata ``run`` (package versions, git commit, host, start time, and what the caller adds: seed,
      algorithm, env) at creation; ``log_hparams`` adds metadata ``config`` (the resolved config, flattened
      to dotted keys) and the attachment ``config.yaml``; a run that ends early (an exception, Ctrl-C, SIGTERM)
      adds metadata ``status`` (``failed`` or ``stopped``, and the reason) when it closes its log.
    One time base per file: the wall-clock time of the call is the message's log time (kept
    non-decreasing); the frame counter, and for scenes the simulation time, live in the payload.

Why plain ``mcap`` with JSON rather than ``foxglove-sdk``
    ``foxglove-sdk`` (protobuf, a 54 MB native wheel) is 2-4x faster than ``json.dumps``, but writing the
    payloads from byte templates closes most of that gap: ``benchmarks/log_throughput.py`` measures what
    this module sustains against the targets of 100,000 scalars/s and 4,000 scene frames/s. JSON keeps the
    dependency small, needs no schema compiler, and is what ``aia-log`` decodes with the standard library.

Crash safety
    Messages go into zstd-compressed chunks (1 MiB by default). :meth:`flush` closes the chunk in progress
    and flushes the file; it runs at least every ``flush_interval_s`` seconds (checked on every write) and
    whenever the caller asks (``aia-train`` flushes after every evaluation). A process killed with SIGKILL
    keeps every message before its last flush: ``aia-log`` recovers the complete chunks of a file without
    a footer. :meth:`close` (also the TorchRL ``shutdown``) writes the summary and the footer; it is safe to
    call twice. Every chunk carries the CRC-32 of its records and the data section the CRC-32 of all its bytes;
    ``aia-log`` checks both (:mod:`aia.logging.reader`).

Write errors
    A failed write (a full disk, a lost mount) raises :class:`~aia.config.errors.WriteFailed` naming the file and the
    OS error; the log then takes no more records. Closing it cuts the file back to its last flush (a torn chunk
    would hide what follows it) and appends the status record there if the disk takes it: the file reads as a
    log cut after its last flush, with ``failed: <reason>``.
"""

from __future__ import annotations

import base64
import contextlib
import getpass
import io
import json
import math
import platform
import socket
import subprocess
import sys
import time
from collections.abc import Iterator, Mapping, Sequence
from importlib import metadata as package_metadata
from pathlib import Path
from typing import Any

import numpy as np
import torch
import yaml
from mcap.data_stream import RecordBuilder
from mcap.records import Metadata
from mcap.writer import Writer
from omegaconf import DictConfig, OmegaConf
from PIL import Image
from torch import Tensor
from torchrl.record.loggers import Logger

from aia.config.errors import RunFailed, Stopped, WriteFailed, one_line, os_error_text
from aia.logging import schemas
from aia.logging.metadata import COMPRESSIONS, RUN_LOG, STATUS_METADATA, flatten
from aia.runtime.timing import utc_now

LOG_TOPIC = "/log"
_PACKAGES = ("aia", "torch", "torchrl", "tensordict", "hydra-core", "mcap", "numpy")


class MCAPRun:
    """The open MCAP file of a run: its writer, its schemas and channels, and the flush clock."""

    def __init__(self, path: Path, compression: str, chunk_size: int, flush_interval_s: float) -> None:
        if compression not in COMPRESSIONS:
            raise ValueError(f"compression={compression!r} is not one of {sorted(COMPRESSIONS)}")
        if chunk_size < 1:
            raise ValueError(f"chunk_size={chunk_size} must be >= 1 byte")
        if not flush_interval_s > 0:
            raise ValueError(f"flush_interval_s={flush_interval_s} must be > 0")
        if path.exists():
            raise FileExistsError(f"{path} exists already: a run log is never overwritten")
        self.path = path
        self.failure: WriteFailed | None = None  # the failed write, after which the log takes no more records
        self.status: dict[str, str] | None = None  # the status record, written again when the log is cut back
        self._flushed_size = 0  # the file's size at its last flush: where a failed log is cut back to
        self.closed = False
        with self._writing():
            path.parent.mkdir(parents=True, exist_ok=True)
            self._file = open(path, "xb")  # noqa: SIM115  (closed by finish())
        self._writer = Writer(self._file, chunk_size=chunk_size, compression=COMPRESSIONS[compression],
                              enable_crcs=True, enable_data_crcs=True)
        self._schemas: dict[str, int] = {}
        self._channels: dict[str, int] = {}
        self._flush_interval_ns = int(flush_interval_s * 1e9)
        self._last_flush = self._last_time = time.time_ns()
        with self._writing():
            self._writer.start(profile="", library="aia")
        self.flush()  # the header on disk at once: a just-started run's log is readable, never an empty file

    @contextlib.contextmanager
    def _writing(self) -> Iterator[None]:
        """Around every write: an OSError becomes :class:`WriteFailed` (kept in ``failure``); a failed log takes no
        more records."""
        if self.failure is not None:
            raise self.failure
        try:
            yield
        except OSError as err:
            self.failure = WriteFailed(self.path, os_error_text(err))
            raise self.failure from None

    def channel(self, topic: str, schema: str) -> int:
        """The channel id of ``topic`` (registered with ``schema`` on first use)."""
        channel = self._channels.get(topic)
        if channel is None:
            with self._writing():
                if schema not in self._schemas:
                    self._schemas[schema] = self._writer.register_schema(
                        schema, schemas.SCHEMA_ENCODING, schemas.schema_bytes(schema))
                channel = self._writer.register_channel(topic, schemas.MESSAGE_ENCODING, self._schemas[schema])
            self._channels[topic] = channel
        return channel

    def now(self) -> int:
        """The log time of the next message: wall-clock nanoseconds, never before the previous message."""
        self._last_time = max(time.time_ns(), self._last_time)
        return self._last_time

    def write(self, channel: int, data: bytes, log_time: int) -> None:
        """Add one message; flush when the last flush is more than ``flush_interval_s`` old."""
        with self._writing():
            self._writer.add_message(channel, log_time, data, log_time)
        if log_time - self._last_flush > self._flush_interval_ns:
            self.flush()

    def metadata(self, name: str, values: Mapping[str, Any]) -> None:
        """A metadata record (string keys and values)."""
        with self._writing():
            self._writer.add_metadata(name, {str(k): str(v) for k, v in values.items()})

    def attachment(self, name: str, media_type: str, data: bytes) -> None:
        """A file attached to the log."""
        stamp = self.now()
        with self._writing():
            self._writer.add_attachment(stamp, stamp, name, media_type, data)

    def flush(self) -> None:
        """Close the chunk in progress and flush the file: what is written survives a SIGKILL."""
        if not self.closed:
            with self._writing():
                self._writer.flush()
                self._flushed_size = self._file.tell()
            self._last_flush = time.time_ns()

    def mark(self, status: Mapping[str, str]) -> None:
        """The status record (why the run ended early), flushed at once; kept for :meth:`finish` should the log
        have failed (then it is written where the log is cut back to)."""
        self.status = dict(status)
        self.metadata(STATUS_METADATA, self.status)
        self.flush()

    def finish(self) -> None:
        """Write the summary and the footer and close the file (idempotent); a failed log is cut back instead
        (see the module docstring). Raises :class:`WriteFailed` if this is the write that fails."""
        if self.closed:
            return
        self.closed = True
        try:
            with self._writing():
                self._writer.finish()
                self._file.close()
        finally:
            if self.failure is not None:
                self._cut_back()

    def _cut_back(self) -> None:
        """After a failed write: the file cut back to its last flush, with the status record appended if the disk
        takes it (best effort: the OS errors of a full disk are expected here)."""
        with contextlib.suppress(OSError):
            self._file.close()  # flushes what it buffers once more (and fails again, most likely): closed anyway
        with contextlib.suppress(OSError), open(self.path, "r+b") as file:
            file.truncate(self._flushed_size)
            if self.status is not None:
                record = RecordBuilder()
                Metadata(STATUS_METADATA, self.status).write(record)
                file.seek(self._flushed_size)
                try:
                    file.write(record.end())
                    file.flush()
                except OSError:
                    file.truncate(self._flushed_size)


class MCAPLogger(Logger):
    """TorchRL logger writing ``<log_dir>/<file_name>`` (see the module docstring for the layout).

    Args:
        exp_name: the run's name (metadata ``run.exp_name``).
        log_dir: folder of the file (created if missing).
        file_name: the MCAP file; an existing file is never overwritten.
        compression: ``"zstd"`` (default), ``"lz4"`` or ``"none"``.
        chunk_size: uncompressed bytes per chunk.
        flush_interval_s: the longest time between flushes while messages arrive.
        run_metadata: extra entries of metadata ``run`` (seed, algorithm, env, ...).
    """

    def __init__(self, exp_name: str, log_dir: str | Path, file_name: str = RUN_LOG, compression: str = "zstd",
                 chunk_size: int = 1 << 20, flush_interval_s: float = 5.0,
                 run_metadata: Mapping[str, Any] | None = None) -> None:
        self._options = (Path(log_dir) / file_name, compression, chunk_size, flush_interval_s)
        self._run_metadata = dict(run_metadata or {})
        self._scalar_channels: dict[str, int] = {}
        self._status_written = False
        super().__init__(exp_name=exp_name, log_dir=str(log_dir))

    def _create_experiment(self) -> MCAPRun:
        run = MCAPRun(*self._options)
        run.metadata("run", {**run_description(self.exp_name), **self._run_metadata})
        return run

    @property
    def path(self) -> Path:
        """The MCAP file of this run."""
        return self.experiment.path

    def log_scalar(self, name: str, value: float | Tensor, step: int | None = None) -> None:
        """One message on topic ``name``: ``{"frame": step, "value": value}``."""
        channel = self._scalar_channels.get(name)
        if channel is None:
            channel = self._scalar_channels[name] = self.experiment.channel(name, schemas.SCALAR)
        value = float(value)
        number = b"%r" % value if math.isfinite(value) else b"null"
        data = b'{"frame":%d,"value":%s}' % (step, number) if step is not None else b'{"value":%s}' % number
        self.experiment.write(channel, data, self.experiment.now())

    def mark_failed(self, reason: str, status: str = "failed") -> None:
        """Record why the run ended early: metadata ``status`` with ``status`` (``failed``, or ``stopped`` for an
        interrupted run) and a one-line ``reason``; ``aia-log summary`` shows it. Flushed at once."""
        self._status_written = True
        self.experiment.mark({"status": status, "reason": one_line(reason)})

    def shutdown(self, timeout: float | None = None) -> None:
        """Write the summary and the footer, close the file (idempotent). Called while an exception propagates
        (``finally: logger.close()``) on a run not yet marked, it first marks the run: ``stopped`` for Ctrl-C or
        SIGTERM (``KeyboardInterrupt``, ``SystemExit``, or :class:`~aia.config.errors.Stopped` with the signal's
        name), ``failed`` with the error otherwise (a
        :class:`~aia.config.errors.RunFailed` as its one line, others as ``<type>: <message>``)."""
        if self._service_shutdown:
            return
        error = sys.exc_info()[1]
        if error is not None and not self._status_written:
            stopped = isinstance(error, (KeyboardInterrupt, SystemExit, Stopped))
            reason = (str(error) if isinstance(error, (RunFailed, Stopped)) else
                      f"{type(error).__name__}: {error}" if str(error) else type(error).__name__)
            with contextlib.suppress(WriteFailed):  # a failed log: the status is written as it is cut back
                self.mark_failed(reason, status="stopped" if stopped else "failed")
        self._service_shutdown = True
        self.experiment.finish()  # the chunk in progress, the summary and the footer

    def log_hparams(self, cfg: DictConfig | Mapping[str, Any]) -> None:
        """The resolved config as metadata ``config`` (dotted keys) and as the attachment ``config.yaml``."""
        container = OmegaConf.to_container(cfg, resolve=True) if isinstance(cfg, DictConfig) else dict(cfg)
        self.experiment.metadata("config", flatten(container))
        self.experiment.attachment("config.yaml", "application/yaml",
                                   yaml.safe_dump(container, sort_keys=False).encode())
        self.experiment.flush()  # a running job's config is readable before its first evaluation

    def log_histogram(self, name: str, data: Sequence | Tensor | np.ndarray, step: int | None = None,
                      bins: int = 30, **kwargs) -> None:
        """The histogram of ``data`` (``bins`` equal bins) on topic ``name`` as ``aia.Histogram``."""
        values = np.asarray(data.detach().cpu() if isinstance(data, Tensor) else data, dtype=np.float64).ravel()
        counts, edges = np.histogram(values[np.isfinite(values)], bins=bins)
        message = {"frame": step, "edges": edges.tolist(), "counts": counts.tolist()}
        self._write_json(name, schemas.HISTOGRAM, message)

    def log_video(self, name: str, video: Tensor, step: int | None = None, **kwargs) -> None:
        """Frames of ``video`` (``[T, C, H, W]`` or ``[N, T, C, H, W]``, C = 1 or 3, uint8 or floats in
        [0, 1]) as PNG ``foxglove.CompressedImage`` messages on topic ``name``."""
        if video.dim() == 5:
            video = video.flatten(0, 1)
        if video.dim() != 4 or video.shape[1] not in (1, 3):
            raise ValueError(f"video must be [T, C, H, W] or [N, T, C, H, W] with C in (1, 3), got "
                             f"{list(video.shape)}")
        frames = video.detach().cpu()
        if frames.is_floating_point():
            frames = (frames.clamp(0, 1) * 255).round()
        frames = frames.to(dtype=torch.uint8).permute(0, 2, 3, 1).numpy()
        channel = self.experiment.channel(name, schemas.COMPRESSED_IMAGE)
        for frame in frames:
            buffer = io.BytesIO()
            Image.fromarray(frame.squeeze(-1) if frame.shape[-1] == 1 else frame).save(buffer, format="png")
            stamp = self.experiment.now()
            message = {"timestamp": _time(stamp), "frame_id": name, "format": "png",
                       "data": base64.b64encode(buffer.getvalue()).decode()}
            self.experiment.write(channel, _json(message), stamp)

    def log_text(self, message: str, level: str = "info", name: str = "aia") -> None:
        """A ``foxglove.Log`` line on ``/log`` (level: debug, info, warning, error, fatal)."""
        if level not in schemas.LOG_LEVELS:
            raise ValueError(f"level={level!r} is not one of {list(schemas.LOG_LEVELS)}")
        stamp = self.experiment.now()
        payload = {"timestamp": _time(stamp), "level": schemas.LOG_LEVELS[level], "message": message,
                   "name": name, "file": "", "line": 0}
        self.experiment.write(self.experiment.channel(LOG_TOPIC, schemas.LOG), _json(payload), stamp)

    def _write_json(self, topic: str, schema: str, message: Mapping[str, Any]) -> None:
        self.experiment.write(self.experiment.channel(topic, schema), _json(message), self.experiment.now())

    def __repr__(self) -> str:
        return f"MCAPLogger(exp_name={self.exp_name!r}, path={str(self.path)!r})"


def _json(message: Mapping[str, Any]) -> bytes:
    return json.dumps(message, separators=(",", ":"), allow_nan=False).encode()


def _time(ns: int) -> dict[str, int]:
    sec, nsec = divmod(ns, 1_000_000_000)
    return {"sec": sec, "nsec": nsec}


def run_description(exp_name: str) -> dict[str, str]:
    """Who ran what where: package versions, git commit of the aia source, host, user, start time."""
    description = {
        "exp_name": exp_name,
        "created": utc_now(),
        "host": socket.gethostname(),
        "user": getpass.getuser(),
        "python": platform.python_version(),
        **git_state(Path(__file__).resolve().parents[2]),
    }
    for package in _PACKAGES:
        try:
            description[f"version.{package}"] = package_metadata.version(package)
        except package_metadata.PackageNotFoundError:
            description[f"version.{package}"] = "not installed"
    return description


def git_state(folder: Path) -> dict[str, str]:
    """``git_commit`` and ``git_dirty`` of the checkout holding ``folder`` (``unknown`` outside git)."""
    def git(*args: str) -> str | None:
        try:
            result = subprocess.run(["git", "-C", str(folder), *args], capture_output=True, text=True, timeout=5)
        except (OSError, subprocess.TimeoutExpired):
            return None
        return result.stdout.strip() if result.returncode == 0 else None

    commit = git("rev-parse", "HEAD")
    if commit is None:
        return {"git_commit": "unknown", "git_dirty": "unknown"}
    status = git("status", "--porcelain", "--untracked-files=no")
    return {"git_commit": commit, "git_dirty": "unknown" if status is None else str(bool(status)).lower()}
