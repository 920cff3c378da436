"""A steady training step asks the host for nothing: on CUDA each read-back (``.item()``, ``bool(tensor)``) and
each tensor made from host data (a copy to the device) would stall the loop until the GPU catches up."""

from __future__ import annotations

import collections
import traceback

import pytest
from hydra import compose, initialize_config_module
from torch.utils._python_dispatch import TorchDispatchMode

from aia.training import train_population

# the ops that read a device tensor on the host (_local_scalar_dense: item, bool, int) or lift host data into a
# tensor (lift_fresh: torch.tensor / as_tensor of Python values)
_HOST_OPS = ("_local_scalar_dense", "lift_fresh")
# the one read a step makes on purpose, on the CPU only (on CUDA the action check is a device-side assert)
_CPU_ONLY = "aia/envs/tracking.py", "_check_actions"


class _HostOps(TorchDispatchMode):
    """Counts the host ops by the innermost aia, TorchRL or tensordict line that asked."""

    def __init__(self) -> None:
        super().__init__()
        self.sites: collections.Counter[tuple[str, str, str]] = collections.Counter()

    def __torch_dispatch__(self, func, types, args=(), kwargs=None):
        name = func.__name__.split(".")[0]
        if name in _HOST_OPS:
            frame = next(f for f in reversed(traceback.extract_stack()) if any(
                f"/{package}/" in f.filename for package in ("aia", "torchrl", "tensordict")))
            path = frame.filename[frame.filename.rfind("/aia/") + 1:] if "/aia/" in frame.filename else frame.filename
            self.sites[(name, path, frame.name)] += 1
        return func(*args, **(kwargs or {}))


@pytest.mark.parametrize("experiment, algo, exploration", [("paper_empty1", "dqn", "egreedy"),
                                                           ("paper_small3", "adfq", "thompson")])
def test_no_host_read_or_host_tensor_recurs_every_step(tmp_path, experiment, algo, exploration):
    frames = 300
    with initialize_config_module(config_module="aia.conf", version_base="1.3"):
        cfgs = [compose(config_name="train", overrides=[
            f"experiment={experiment}", f"algo={algo}", f"exploration={exploration}", "logger=none",
            "compile.update=false", "compile.env=false", "compile.policy=false", "warmup_frames=100",
            f"frames={frames}", f"seed={seed}"]) for seed in (0, 1)]
    mode = _HostOps()
    with mode:
        train_population(cfgs, [tmp_path / str(seed) for seed in (0, 1)])
    steps = frames  # one world per member: a step is a frame
    assert mode.sites[("_local_scalar_dense", *_CPU_ONLY)] >= steps  # the count sees every step
    recurring = {site: count for site, count in mode.sites.items()
                 if count >= steps // 4 and site[1:] != _CPU_ONLY}
    assert recurring == {}
