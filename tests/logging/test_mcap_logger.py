"""MCAPLogger: scalars, hparams, histograms, videos and text round-trip through the plain mcap reader."""

from __future__ import annotations

import json
import math
import signal
import time

import pytest
import torch
import yaml
from mcap.reader import make_reader
from omegaconf import OmegaConf

from aia.config.errors import Stopped, WriteFailed
from aia.logging import MCAPLogger, mcap_logger, read_run
from aia.logging.metadata import flatten


def _messages(path):
    with open(path, "rb") as f:
        reader = make_reader(f)
        return [(schema.name, channel.topic, message.log_time, json.loads(message.data))
                for schema, channel, message in reader.iter_messages(log_time_order=False)]


def test_scalars_round_trip_with_frames_and_wall_clock_times(tmp_path):
    logger = MCAPLogger("exp", tmp_path)
    values = [1.5, -2.25, 1e-30, 123456.789, float("nan")]
    for i, value in enumerate(values):
        logger.log_scalar("eval/score", value, step=10 * i)
    logger.log_scalar("train/loss", torch.tensor(0.125))
    logger.close()
    messages = _messages(tmp_path / "run.mcap")
    scores = [m for m in messages if m[1] == "eval/score"]
    assert [m[0] for m in scores] == ["aia.Scalar"] * 5
    assert [m[3]["frame"] for m in scores] == [0, 10, 20, 30, 40]
    assert [m[3]["value"] for m in scores[:4]] == values[:4]
    assert scores[4][3]["value"] is None  # JSON has no NaN
    times = [m[2] for m in messages]
    assert times == sorted(times) and abs(times[0] / 1e9 - time.time()) < 60
    assert [m[3] for m in messages if m[1] == "train/loss"] == [{"value": 0.125}]


def test_hparams_go_to_metadata_and_a_yaml_attachment(tmp_path):
    cfg = OmegaConf.create({"algo": {"name": "adfq", "noise": 1.0}, "seed": 3, "hidden": [128, 128],
                            "lr": "${algo.noise}"})
    logger = MCAPLogger("exp", tmp_path, run_metadata={"seed": 3})
    logger.log_hparams(cfg)
    logger.close()
    with open(tmp_path / "run.mcap", "rb") as f:
        reader = make_reader(f)
        metadata = {m.name: m.metadata for m in reader.iter_metadata()}
        attachments = {a.name: a.data for a in reader.iter_attachments()}
    assert metadata["config"] == {"algo.name": "adfq", "algo.noise": "1.0", "seed": "3", "hidden": "[128, 128]",
                                  "lr": "1.0"}
    assert yaml.safe_load(attachments["config.yaml"]) == {"algo": {"name": "adfq", "noise": 1.0}, "seed": 3,
                                                           "hidden": [128, 128], "lr": 1.0}
    run = metadata["run"]
    assert run["seed"] == "3" and run["exp_name"] == "exp"
    assert run["version.torch"] == torch.__version__
    assert run["git_commit"] == "unknown" or len(run["git_commit"]) == 40


def test_histogram_video_and_text(tmp_path):
    logger = MCAPLogger("exp", tmp_path)
    logger.log_histogram("q_values", torch.tensor([0.0, 1.0, 1.0, 2.0, 4.0]), step=7, bins=4)
    logger.log_video("camera", torch.zeros(2, 3, 8, 6, dtype=torch.uint8))
    logger.log_text("evaluation 1: score 12", level="warning")
    logger.close()
    messages = {m[1]: m for m in _messages(tmp_path / "run.mcap")}
    histogram = messages["q_values"]
    assert histogram[0] == "aia.Histogram"
    assert histogram[3]["counts"] == [1, 2, 1, 1] and histogram[3]["edges"] == [0.0, 1.0, 2.0, 3.0, 4.0]
    image = messages["camera"]
    assert image[0] == "foxglove.CompressedImage" and image[3]["format"] == "png"
    assert sum(1 for m in _messages(tmp_path / "run.mcap") if m[1] == "camera") == 2
    log = messages["/log"]
    assert log[0] == "foxglove.Log" and log[3]["level"] == 3 and log[3]["message"] == "evaluation 1: score 12"


def test_bad_arguments_name_the_value(tmp_path):
    with pytest.raises(ValueError, match="compression='gzip'"):
        MCAPLogger("exp", tmp_path, compression="gzip")
    logger = MCAPLogger("exp", tmp_path / "a")
    with pytest.raises(ValueError, match="level='loud'"):
        logger.log_text("x", level="loud")
    with pytest.raises(ValueError, match=r"\[2, 8, 8\]"):
        logger.log_video("v", torch.zeros(2, 8, 8))
    logger.close()
    logger.close()  # closing twice is harmless


def test_an_existing_log_is_never_overwritten(tmp_path):
    MCAPLogger("exp", tmp_path).close()
    before = (tmp_path / "run.mcap").read_bytes()
    with pytest.raises(FileExistsError, match="run.mcap"):
        MCAPLogger("exp", tmp_path)
    assert (tmp_path / "run.mcap").read_bytes() == before


def test_flush_makes_everything_logged_so_far_readable_without_a_footer(tmp_path):
    logger = MCAPLogger("exp", tmp_path, flush_interval_s=3600)
    for i in range(100):
        logger.log_scalar("eval/score", float(i), step=i)
    logger.flush()
    snapshot = (tmp_path / "run.mcap").read_bytes()  # what a SIGKILL now would leave on disk
    logger.log_scalar("eval/score", 100.0, step=100)
    logger.close()
    (tmp_path / "killed.mcap").write_bytes(snapshot)
    run = read_run(tmp_path / "killed.mcap")
    assert not run.complete
    assert run.scalars("eval/score").values.tolist() == [float(i) for i in range(100)]


def test_a_just_started_log_is_readable_with_its_config(tmp_path):
    logger = MCAPLogger("exp", tmp_path, run_metadata={"seed": 3}, flush_interval_s=3600)
    assert read_run(tmp_path / "run.mcap").messages == []  # header on disk at once, not an empty file
    logger.log_hparams(OmegaConf.create({"algo": {"name": "dqn"}}))
    run = read_run(tmp_path / "run.mcap")  # the logger still open: no footer yet
    assert not run.complete and run.config_value("algo.name") == "dqn"
    logger.close()


def test_time_based_flush_happens_while_logging(tmp_path):
    logger = MCAPLogger("exp", tmp_path, flush_interval_s=1e-9)
    logger.log_scalar("a", 1.0, step=1)
    logger.log_scalar("a", 2.0, step=2)  # the interval has passed: this write flushes
    size = (tmp_path / "run.mcap").stat().st_size
    logger.close()
    assert size > 100 and math.isfinite(size)


def test_flatten_nested_config():
    assert flatten({"a": {"b": 1, "c": {"d": None}}, "e": [1, 2], "f": {}}) == {
        "a.b": "1", "a.c.d": "null", "e": "[1, 2]", "f": "{}"}


def test_a_log_closed_by_an_exception_says_failed_and_why(tmp_path):
    logger = MCAPLogger("exp", tmp_path)
    with pytest.raises(ValueError):
        try:
            raise ValueError("bad start\nsecond line")
        finally:
            logger.close()
    run = read_run(tmp_path / "run.mcap")
    assert run.complete and run.failure == "failed: ValueError: bad start second line"


def test_an_interrupted_run_says_stopped_and_a_finished_one_has_no_status(tmp_path):
    logger = MCAPLogger("exp", tmp_path / "a")
    with pytest.raises(KeyboardInterrupt):
        try:
            raise KeyboardInterrupt
        finally:
            logger.close()
    assert read_run(tmp_path / "a" / "run.mcap").failure == "stopped: KeyboardInterrupt"
    logger = MCAPLogger("exp", tmp_path / "c")
    with pytest.raises(Stopped):
        try:
            raise Stopped(signal.SIGTERM)
        finally:
            logger.close()
    assert read_run(tmp_path / "c" / "run.mcap").failure == "stopped: SIGTERM"
    logger = MCAPLogger("exp", tmp_path / "b")
    logger.log_scalar("eval/score", 1.0, step=1)
    logger.close()
    run = read_run(tmp_path / "b" / "run.mcap")
    assert run.failure is None and "status" not in run.metadata


def test_mark_failed_is_explicit_and_the_first_mark_stays(tmp_path):
    logger = MCAPLogger("exp", tmp_path)
    logger.mark_failed("the env could not be built")
    with pytest.raises(RuntimeError):
        try:
            raise RuntimeError("later")
        finally:
            logger.close()
    assert read_run(tmp_path / "run.mcap").failure == "failed: the env could not be built"


def test_a_failed_write_cuts_the_log_back_to_its_last_flush_and_records_why(tmp_path, full_disk):
    """Out of space: WriteFailed names the file and the OS error; the log keeps every flushed message, says
    ``failed: <reason>``, and takes no more records."""
    full_disk(mcap_logger, room=6_000)
    logger = MCAPLogger("exp", tmp_path, flush_interval_s=3600, compression="none")
    flushed = 0
    with pytest.raises(WriteFailed) as failed:
        try:
            for i in range(10_000):
                logger.log_scalar("eval/score", float(i), step=i)
                if i % 20 == 19:
                    logger.flush()
                    flushed = i + 1
        finally:
            logger.close()
    reason = f"could not write {tmp_path / 'run.mcap'} ([Errno 28] No space left on device)"
    assert str(failed.value).startswith(reason) and flushed >= 20
    with pytest.raises(WriteFailed):
        logger.log_scalar("eval/score", 0.0, step=0)
    run = read_run(tmp_path / "run.mcap")
    assert run.failure.startswith(f"failed: {reason}") and not run.complete and not run.damage
    assert run.scalars("eval/score").values.tolist() == [float(i) for i in range(flushed)]
