"""Session-wide settings of the test run, the fault-injecting ``full_disk`` fixture, and two trained checkpoints
that the evaluation's and ``aia-eval``'s tests play (``checkpoint``, ``map_checkpoint``).

The suite runs in three pytest-xdist workers (``-n 3`` in pyproject's ``addopts``) on the 2-core machine: each
worker, and every process a test starts, computes on one thread (two workers at two threads each were slower than
one worker). The longest tests mostly wait (on SLURM's scheduler, on the processes of a sweep): two workers kept
the cores 1.55 busy on average, and a third fills the waits (the suite 387 -> 333 s in one clone, one run after
the other). While the workers start, the controller
compiles aia's numba kernels once into numba's cache (:mod:`tests.kernel_cache`); their first tests wait for it,
so that they load the kernels instead of each compiling its own.
"""

from __future__ import annotations

import contextlib
import errno
import io
import os
import shutil
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Callable
from pathlib import Path
from types import ModuleType

import pytest
import torch

if os.environ.get("PYTEST_XDIST_WORKER"):
    os.environ["OMP_NUM_THREADS"] = "1"  # inherited by the apps' subprocesses
    torch.set_num_threads(1)


# A folder of this run's own (its path in the workers' environment): the kernels' ready file, which the controller
# makes once the kernels' cache is made, and the SLURM_STARTED mark of a run whose tests started the local cluster.
TEST_RUN_DIR = "AIA_TEST_RUN_DIR"
KERNELS_READY = "kernels-ready"
SLURM_STARTED = "slurm-started"
KERNEL_CACHE_WAIT_S = 600  # how long a worker waits for the kernels' cache


def run_dir() -> Path | None:
    """This test run's own folder (:data:`TEST_RUN_DIR`), ``None`` outside a run that made one."""
    folder = os.environ.get(TEST_RUN_DIR)
    return Path(folder) if folder else None


def pytest_configure(config: pytest.Config) -> None:
    """In the run's controller (or its one process): make the run's own folder (:func:`run_dir`). With workers,
    also start making the kernels' cache (:mod:`tests.kernel_cache`, its two parts side by side) while the workers
    start and collect; each worker's first test waits for it (:func:`kernel_cache_made`). A part that fails is
    left to the tests that use its kernels to report."""
    if os.environ.get("PYTEST_XDIST_WORKER"):
        return
    folder = Path(tempfile.mkdtemp(prefix="aia-test-run-"))
    os.environ[TEST_RUN_DIR] = str(folder)  # the workers, started after this hook, inherit it
    if not getattr(config.option, "numprocesses", None):
        return
    from tests.kernel_cache import PARTS

    root = Path(__file__).resolve().parents[1]
    parts = [subprocess.Popen([sys.executable, "-m", "tests.kernel_cache", part], cwd=root,
                              stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL) for part in PARTS]

    def mark_ready() -> None:
        for part in parts:
            part.wait()
        with contextlib.suppress(FileNotFoundError):  # the session ended first (pytest_unconfigure)
            (folder / KERNELS_READY).touch()

    threading.Thread(target=mark_ready, daemon=True).start()


def pytest_unconfigure(config: pytest.Config) -> None:
    """In the run's controller: stop the local SLURM cluster if this run's tests started it (another run's cluster,
    or one that was up before, is left running), and remove the run's folder."""
    folder = run_dir()
    if os.environ.get("PYTEST_XDIST_WORKER") or folder is None:
        return
    if (folder / SLURM_STARTED).exists():
        from tests.cluster.conftest import script

        script("stop", timeout=120)
    shutil.rmtree(folder, ignore_errors=True)


# The modules of the suite's longest tests (the tiny protocol, the SLURM jobs, the launcher's signals, training
# runs: 10-50 s each), which the workers take first: started last, one of them would leave the other workers idle.
FIRST_MODULES = ("tests/scripts/test_reproduce.py", "tests/cluster/test_slurm.py", "tests/apps/test_search.py",
                 "tests/hydra_plugins/test_population_launcher.py", "tests/training/test_target_cache.py",
                 "tests/training/test_loop.py")


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    """The tests of :data:`FIRST_MODULES` first (in that order), then the others as collected (the workers hand
    out tests in this order)."""
    rank = {module: k for k, module in enumerate(FIRST_MODULES)}
    items.sort(key=lambda item: rank.get(item.nodeid.split("::")[0], len(rank)))


@pytest.fixture(scope="session", autouse=True)
def kernel_cache_made() -> None:
    """In a worker, before its first test: wait until the controller has made the kernels' cache."""
    folder = run_dir()
    if folder is None or not os.environ.get("PYTEST_XDIST_WORKER"):
        return
    deadline = time.monotonic() + KERNEL_CACHE_WAIT_S
    while not (folder / KERNELS_READY).exists() and time.monotonic() < deadline:
        time.sleep(0.1)


class FullDiskFile(io.FileIO):
    """A file on a disk with room for its first ``room`` bytes: a write past them writes what fits, then fails
    as on a full disk (``ENOSPC``)."""

    def __init__(self, path: str | os.PathLike, mode: str, room: int) -> None:
        super().__init__(path, mode)
        self.room = room

    def write(self, data) -> int:
        fits = max(0, self.room - self.tell())
        if len(data) > fits:
            super().write(bytes(data)[:fits])
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        return super().write(data)


@pytest.fixture
def full_disk(monkeypatch) -> Callable[..., None]:
    """``full_disk(module, room, after=0)``: the files ``module`` creates (``open`` with mode ``wb`` or ``xb``)
    after its first ``after`` ones hold ``room`` bytes each, then fail as on a full disk."""

    def install(module: ModuleType, room: int, after: int = 0) -> None:
        created = 0

        def faulty_open(path, mode="r", *args, **kwargs):
            nonlocal created
            if mode not in ("wb", "xb"):
                return open(path, mode, *args, **kwargs)
            created += 1
            if created <= after:
                return open(path, mode, *args, **kwargs)
            return io.BufferedWriter(FullDiskFile(path, mode, room))

        monkeypatch.setattr(module, "open", faulty_open, raising=False)

    return install


@pytest.fixture(scope="session")
def checkpoint(tmp_path_factory) -> Path:
    """The checkpoint of a short DQN run on the default setting (200 frames)."""
    from hydra import compose, initialize_config_module

    from aia.training import train

    out = tmp_path_factory.mktemp("run")
    with initialize_config_module(config_module="aia.conf", version_base="1.3"):
        cfg = compose(config_name="train", overrides=["frames=200", "env.max_steps=40", "warmup_frames=100",
                                                      "logger=none", "eval.episodes=2", "batch_size=16"])
    train(cfg, out)
    return out / "checkpoints" / "last.pt"


@pytest.fixture(scope="session")
def map_checkpoint(tmp_path_factory) -> Path:
    """The checkpoint of a policy trained on ttenv v4's map observation (8 x 8 images)."""
    from hydra import compose, initialize_config_module

    from aia.training import train
    from tests.training.test_population import MAP_OBSERVATION

    out = tmp_path_factory.mktemp("map_run")
    with initialize_config_module(config_module="aia.conf", version_base="1.3"):
        cfg = compose(config_name="train", overrides=[*MAP_OBSERVATION, "frames=60", "warmup_frames=40",
                                                      "eval.every_episodes=3"])
    train(cfg, out)
    return out / "checkpoints" / "last.pt"
