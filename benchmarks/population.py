"""Member-frames per second of a population, against one learner alone, and against the solo loop before populations.

1. Populations: ``aia.training.train_population`` in the paper's regime (one world per member, one update per
   frame, batch 64, evaluation after every episode or two as the presets say) for P = 1, 5, 20, 80 members,
   for the learner rows of ``ROWS`` (``--algos``): DQN on the 1-target network (``dqn``: ``paper_empty1``,
   3 x 128), ADFQ with Thompson sampling on the 3-target network (``adfq``: ``paper_small3``, 3 x 256) and DQN
   with the conv torso over ttenv v4's 28 x 28 map image (``conv``: ``ttenv_v4``, the env drawing each member's
   local map every step), eager and compiled (every ``compile.*`` switch on). The rate
   counts the updating frames of every member, from the loop's own phase clocks (``TrainingState.seconds``):
   per step, each phase's time in a job of ``warmup + frames`` frames minus its time in a warm-up-only job
   (compiled, after a first warm-up job that compiles what the later jobs of that size reuse), summed over
   the training phases (collect, buffer, update, targets, other; the first, compiling, update left out).
   ``member_frames_per_s_with_evaluation`` adds the longer job's evaluation time spread over all its frames
   (evaluations come in lumps: a short job plays a whole evaluation rollout for a point or two, a long run
   ``eval.per_rollout`` points per rollout, so this share depends on the job's length), and
   ``member_frames_per_s_wall_clock`` is the jobs' wall-clock difference, which also carries the set-up that
   differs between two jobs (twice it came out 1.7x off the phase sum). Each row also gives the
   arithmetic it does (the updates' and the acting's matmul FLOPs per member-frame) as a share of this
   machine's measured matmul rate (``sgemm_gflops``, all threads), the ceiling a batched program can reach,
   and the time one update's batched products take alone on their own shapes (``update_matmuls_ms``, the
   "products" column): the floor under the update phase, against which the update's other work shows.
   ``collect_alone_ms`` is the collection's time per step with no update between the steps (the warm-up frames
   of a warm-up-only job twice as long, net of the warm-up-only job), against the training phases' ``collect``:
   what the updates between the steps cost the collection (at P = 20 they evict its working set from the
   cores' caches).
2. The vmap alternative: one update of P members of the 3 x 128 DQN by ``torch.vmap`` over TorchRL's
   ``DQNLoss`` with the members' parameters stacked and entered with ``to_module``, against the stacked
   network inside one ``DQNLoss`` (what the loop uses), eager, P = 1 and 20.
3. The conv network alone (``--conv 1,20``, the default): the ``conv`` row's network (a 1 x 28 x 28 map image
   through the conv torso of ``conf/train.yaml``'s ``conv_layers``, with the 1-target belief features into the
   3 x 128 DQN head), member-frames per second of the network's share of a frame in the paper's regime: one
   greedy forward on the member's world, then one update of a batch of 64 (``aia.training.optimizer.Updater``:
   TorchRL's ``DQNLoss``, clipping, Adam, the target copy every 50 updates), on random maps and features,
   without the env, the replay and the evaluations of the population rows (whose share a population also
   shares among its members). ``--conv-alternatives`` times the ways of stacking the members' conv networks: grouped
   convolutions (``aia.modules.StackedConvQNetwork``), ``torch.vmap`` over the solo network with
   ``torch.func.stack_module_state``, and a loop over the members, for a batch of 64 per member (forward and
   backward) and for acting on 4,096 worlds split among the members (forward).
4. Before populations: ``--baseline REV`` runs ``benchmarks/train_throughput.py --parts loop`` of the commit
   ``REV`` (the solo loop before this change, extracted with ``git archive``) and of the working tree, in the
   same run, so that P = 1 of the new loop is compared with the old loop on the same machine the same hour.

On a GPU (``--device cuda``) the matmul rate is that GPU's (8,192-square float32 products), the products are
timed there, and part 2 is left out (the alternatives were weighed on the CPU). ``--count-syncs P`` first
trains a P-member job per learner and mode under ``torch.cuda.set_sync_debug_mode("warn")`` and prints every
host-device synchronisation by the line that asked (``count_syncs``): a site counted about once per frame
stalls every step.

``--inner-dtypes float32,bfloat16`` adds rows with the hidden-to-hidden matmuls in bfloat16 (``inner_dtype``,
``conf/train.yaml``), each against P = 1 of its own dtype; ``--algos adfq`` keeps one learner row.

``--repeats N`` measures every population size N times, round by round (each round's sizes one after another,
so that they meet the same VM): each row gives the median rate and the range, and the ratio to the P = 1 run of
the same round (median and range). A P = 1 job of a few hundred frames lasts seconds and swings with the VM's
speed (163-489 member-frames/s for the same DQN row in three runs of one day), so a ratio from one round says
little.

Prints a table and writes JSON (default ``benchmarks/results/population_<device>.json``); its ``meta`` names the
commit (and whether the checkout was dirty), the arguments, the start and end (UTC) and the matmul rate before
and after, so a row can be set beside the VM's hour and the code it measured.

    python benchmarks/population.py
    python benchmarks/population.py --members 1,5,20 --modes eager --baseline 54a9a5a
    python benchmarks/population.py --algos adfq --modes compiled --members 1,5 --inner-dtypes float32,bfloat16
    python benchmarks/population.py --algos dqn --modes compiled --members 1,20 --repeats 3 --frames 600
    python benchmarks/population.py --algos conv --modes compiled --members 1,20 --repeats 3 --conv ""
    python benchmarks/population.py --device cuda --modes eager --members 1,20,80,320 --count-syncs 4
    python benchmarks/population.py --algos "" --conv 1,20 --repeats 5 --conv-alternatives
"""

from __future__ import annotations

import argparse
import collections
import functools
import itertools
import json
import os
import platform
import statistics
import subprocess
import sys
import tempfile
import time
import traceback
import warnings
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import NamedTuple

import torch
from _cli import NON_NEGATIVE_INT, POSITIVE_INT, comma_separated, git_commit, parse_checked, subset_of
from hydra import compose, initialize_config_module
from tensordict import TensorDict
from torchrl.data import Categorical
from torchrl.objectives import DQNLoss, HardUpdate

from aia.envs import make_env
from aia.logging.mcap_logger import git_state
from aia.modules import StackedConvQNetwork, make_q_network
from aia.modules.q_networks import make_qvalue_actor, same_padding
from aia.runtime.timing import sgemm_gflops, synchronize, utc_now
from aia.training import train_population
from aia.training.components import make_loss, make_network, make_stacked_network, map_shape
from aia.training.optimizer import StackedAdam, Updater


class Row(NamedTuple):
    """A benchmarked learner: its experiment preset, learner and exploration (its network: :func:`network`)."""

    experiment: str
    algo: str
    exploration: str


ROWS = {"dqn": Row("paper_empty1", "dqn", "egreedy"), "adfq": Row("paper_small3", "adfq", "thompson"),
        "conv": Row("ttenv_v4", "dqn", "egreedy")}
NUM_ACTIONS, BATCH = 12, 64
ACTING_WORLDS = 4096  # the conv alternatives' acting forward
# the paper presets' replay buffer and target period (a copy every 50 updates: HardUpdate copies on the 51st)
BUFFER_SIZE, TARGET_PERIOD = 1000, 51
LOOP_SWITCHES = ("update", "env", "policy")
_SYNC_SITE_PACKAGES = ("aia", "torchrl", "tensordict")  # the packages whose lines name a host-device sync
HERE = Path(__file__).parent


def _config(*overrides: str):
    with initialize_config_module(config_module="aia.conf", version_base="1.3"):
        return compose(config_name="train", overrides=list(overrides))


class Network(NamedTuple):
    """A row's network as its preset builds it: the belief features' width, the hidden layers, and with a map
    observation the image ``(C, H, W)`` and the conv torso's ``(filters, kernel, stride)`` per layer."""

    features: int
    hidden: tuple[int, ...]
    image: tuple[int, int, int] | None
    conv_layers: tuple[tuple[int, ...], ...]

    @property
    def name(self) -> str:
        """The network in the tables: its hidden widths, ``conv+`` in front for a conv torso."""
        return ("conv+" if self.image else "") + "x".join(map(str, self.hidden))

    def torso(self) -> tuple[int, int]:
        """The conv torso's multiply-adds per image and features out (TensorFlow's "SAME" padding, as
        :class:`~aia.modules.q_networks.ConvTorso`); ``(0, 0)`` without a map image."""
        if self.image is None:
            return 0, 0
        channels, size, _ = self.image
        macs = 0
        for filters, kernel, stride in self.conv_layers:
            size = same_padding(size, kernel, stride)[2]
            macs += size * size * filters * channels * kernel * kernel
            channels = filters
        return macs, channels * size * size


@functools.cache
def network(name: str) -> Network:
    """Row ``name``'s network, read off its preset's config and a one-world env's observation spec."""
    cfg = member_configs(name, 1, False, 0, 1, "cpu")[0]
    spec = make_env(cfg.env, batch_size=1).observation_spec
    return Network(spec["observation"].shape[-1], tuple(cfg.hidden), map_shape(spec),
                   tuple(tuple(layer) for layer in cfg.conv_layers))


def _widths(name: str) -> list[int]:
    """The benchmarked heads' layer widths: input (belief features, and a conv row's torso features), hidden
    layers, outputs (ADFQ: a mean and a log-sd per action)."""
    net = network(name)
    return [net.features + net.torso()[1], *net.hidden, 2 * NUM_ACTIONS if ROWS[name].algo == "adfq" else NUM_ACTIONS]


def _ms_per_call(fn: Callable[[], object], repeats: int, warmup: int, device: str = "cpu") -> float:
    """Milliseconds per call of ``fn``, over ``repeats`` calls after ``warmup`` untimed ones (a GPU's queued
    kernels waited for at both ends)."""
    for _ in range(warmup):
        fn()
    synchronize(device)
    start = time.perf_counter()
    for _ in range(repeats):
        fn()
    synchronize(device)
    return 1e3 * (time.perf_counter() - start) / repeats


def flops_per_member_frame(name: str) -> float:
    """Matmul FLOPs of one member-frame of row ``name``: acting on one world, and one update of a batch of 64
    (forward of the online network and its backward, twice the forward; the target network's forward on s'),
    a conv row's convolutions counted as products. ADFQ's targets come from
    ``aia.training.target_cache.TargetCache``: the target network on s and s' of the buffer's 1,000 rows once per
    51-update target period, and of each written transition (computed among 4): 2 x (1,000 / 51 + 4) rows a
    frame instead of 2 x 64."""
    widths = _widths(name)
    per_sample = 2 * (network(name).torso()[0] + sum(a * b for a, b in zip(widths[:-1], widths[1:], strict=True)))
    target_rows = 2 * (BUFFER_SIZE / TARGET_PERIOD + 4) if ROWS[name].algo == "adfq" else BATCH
    return per_sample * (1 + 3 * BATCH + target_rows)


def member_configs(name: str, members: int, compile: bool, warmup: int, frames: int, device: str,
                   inner_dtype: str = "float32", extra: Sequence[str] = ()) -> list:
    """The configs of a benchmarked population's members (seeds 0 .. members - 1): row ``name``'s preset, learner
    and exploration, no logger, every ``compile.*`` switch of the loop set to ``compile``, then ``extra``
    overrides."""
    row = ROWS[name]
    switches = [f"compile.{switch}={str(compile).lower()}" for switch in LOOP_SWITCHES]
    return [_config(f"experiment={row.experiment}", f"algo={row.algo}", f"exploration={row.exploration}",
                    "logger=none", f"device={device}", f"warmup_frames={warmup}", f"inner_dtype={inner_dtype}",
                    *switches, f"frames={frames}", f"seed={seed}", *extra) for seed in range(members)]


def measure_population(name: str, members: int, compile: bool, warmup: int, frames: int, device: str,
                       inner_dtype: str = "float32") -> dict:
    """Member-frames per second of the updating frames of a ``members``-member population, and its collection's
    time per step without updates between the steps (``collect_alone_ms``)."""
    def job(length: int, warmup_frames: int = warmup) -> tuple[float, dict]:
        cfgs = member_configs(name, members, compile, warmup_frames, length, device, inner_dtype)
        with tempfile.TemporaryDirectory() as out:
            start = time.perf_counter()
            states = train_population(cfgs, [Path(out) / str(seed) for seed in range(members)])
            return time.perf_counter() - start, states[0].seconds

    if compile:
        job(warmup)  # compiles the env's, the transforms' and the evaluation's functions for this P (cached)
    warmup_s, warmup_phases = job(warmup)
    warmup_s -= warmup_phases.get("first_update", 0.0)
    job_s, phases = job(warmup + frames)
    # warm-up frames only, twice as many: the steps between the two jobs' ends collect with no update between them
    _, alone_phases = job(2 * warmup, 2 * warmup)
    collect_alone_ms = 1e3 * (alone_phases["collect"] - warmup_phases["collect"]) / warmup
    split = {phase: 1e3 * (t - warmup_phases.get(phase, 0.0)) / frames
             for phase, t in phases.items() if phase not in ("first_update", "evaluate")}
    training_ms = sum(ms for phase, ms in split.items() if phase != "checkpoint")
    # evaluations come in lumps (a rollout per eval.per_rollout points, and one at the end of every job), so
    # a difference of two jobs says little: their cost is spread over all frames of the longer job
    split["evaluate"] = 1e3 * phases.get("evaluate", 0.0) / (warmup + frames)
    return {"kind": "population", "row": name, "algo": ROWS[name].algo, "network": network(name).name,
            "members": members, "compiled": compile, "inner_dtype": inner_dtype, "device": device,
            "warmup_frames": warmup, "updating_frames": frames,
            "job_s": job_s, "first_update_s": phases["first_update"],
            "member_frames_per_s": 1e3 * members / training_ms,
            "member_frames_per_s_with_evaluation": 1e3 * members / (training_ms + split["evaluate"]),
            "member_frames_per_s_wall_clock": members * frames / (job_s - warmup_s - phases["first_update"]),
            "ms_per_step_by_phase": split, "collect_alone_ms": collect_alone_ms}


def count_syncs(name: str, members: int, compile: bool, warmup: int, frames: int, device: str) -> dict:
    """The host-device synchronisations of one ``warmup + frames``-frame population job on CUDA, by the line
    that asked for each (``torch.cuda.set_sync_debug_mode("warn")``: every synchronising call warns, and the
    warning's Python stack names the TorchRL, tensordict or aia line, and the innermost aia line under it). A
    site counted about once per frame syncs every step; the others sync per episode, evaluation or log."""
    cfgs = member_configs(name, members, compile, warmup, warmup + frames, device)
    sites: collections.Counter[str] = collections.Counter()

    def record(message, category, filename, lineno, file=None, line=None) -> None:
        if "synchroniz" not in str(message):
            return
        frames_ = [f for f in traceback.extract_stack()[:-1]
                   if any(f"/{package}/" in f.filename for package in _SYNC_SITE_PACKAGES)]
        if not frames_:
            sites["(outside aia, TorchRL and tensordict)"] += 1
            return
        ours = next((f for f in reversed(frames_) if "/aia/" in f.filename), None)
        site = _frame_name(frames_[-1])
        if ours is not None and ours is not frames_[-1]:
            site += f" <- {_frame_name(ours)}"
        sites[site] += 1

    with tempfile.TemporaryDirectory() as out, warnings.catch_warnings():
        warnings.simplefilter("always")
        warnings.showwarning = record
        torch.cuda.set_sync_debug_mode("warn")
        try:
            states = train_population(cfgs, [Path(out) / str(seed) for seed in range(members)])
        finally:
            torch.cuda.set_sync_debug_mode(0)
    state = states[0]
    return {"kind": "syncs", "row": name, "algo": ROWS[name].algo, "members": members, "compiled": compile,
            "device": device, "frames": state.frames, "updates": state.updates, "episodes": state.episodes,
            "evaluations": state.evaluations, "syncs": sum(sites.values()),
            "sites": [{"site": site, "count": count} for site, count in sites.most_common()]}


def _frame_name(frame: traceback.FrameSummary) -> str:
    """``package/module.py:line function`` of a stack frame in aia, TorchRL or tensordict."""
    path = frame.filename
    for package in _SYNC_SITE_PACKAGES:
        index = path.rfind(f"/{package}/")
        if index >= 0:
            path = path[index + 1:]
            break
    return f"{path}:{frame.lineno} {frame.name}"


def update_matmuls_ms(name: str, members: int, inner_dtype: str = "float32", repeats: int = 50,
                      device: str = "cpu") -> float:
    """ms of one update's batched products alone, ``members`` members of row ``name`` (eager ``torch.bmm`` on the
    loop's shapes, batch 64: the online network's forward, for DQN the target network's forward on s' (ADFQ's
    targets come from its cache), and the backward's weight and input gradients; the layers between two hidden
    layers in ``inner_dtype``; a conv row's heads, not its convolutions): the floor under the update phase,
    whatever the step's other work costs."""
    widths = _widths(name)
    generator = torch.Generator().manual_seed(0)
    layers = []
    for index, (fan_in, fan_out) in enumerate(zip(widths[:-1], widths[1:], strict=True)):
        inner = 0 < index < len(widths) - 2
        dtype = getattr(torch, inner_dtype) if inner else torch.float32
        layers.append(tuple(torch.randn(shape, generator=generator).to(dtype) for shape in
                            ((members, fan_in, fan_out), (members, BATCH, fan_in), (members, BATCH, fan_out))))
    layers = [tuple(tensor.to(device) for tensor in layer) for layer in layers]
    forwards = 2 if ROWS[name].algo == "dqn" else 1

    def products() -> None:
        for _ in range(forwards):
            for weight, inputs, _ in layers:
                torch.bmm(inputs, weight)
        for index, (weight, inputs, grad) in enumerate(layers):
            torch.bmm(inputs.transpose(1, 2), grad)
            if index:
                torch.bmm(grad, weight.transpose(1, 2))

    return _ms_per_call(products, repeats, warmup=10, device=device)


def _median_run(runs: list[dict], solo_runs: list[dict | None]) -> dict:
    """The run of median member-frames/s among ``runs`` (one per round; of an even number, the upper), with
    every round's rate (``member_frames_per_s_runs``), every round's ratio to its own P = 1 run
    (``speedup_over_p1_runs``, empty without P = 1 runs) and their median (``speedup_over_p1``)."""
    rates = [run["member_frames_per_s"] for run in runs]
    row = dict(sorted(runs, key=lambda run: run["member_frames_per_s"])[len(runs) // 2])
    ratios = [rate / solo["member_frames_per_s"] for rate, solo in zip(rates, solo_runs, strict=True) if solo]
    row["member_frames_per_s_runs"] = rates
    row["speedup_over_p1_runs"] = ratios
    row["speedup_over_p1"] = statistics.median(ratios) if ratios else None
    return row


def measure_vmap_update(members: int, repeats: int = 30) -> dict:
    """ms of one forward and backward of ``members`` 3 x 128 DQN losses: ``torch.vmap`` over ``DQNLoss`` with
    stacked parameters against the stacked network inside one ``DQNLoss`` (``reduction="none"``)."""
    cfg = _config("algo=dqn", "hidden=[128,128,128]")
    env = make_env("empty1", batch_size=BATCH, seed=0)
    batch = env.rollout(2)[:, -1]
    # vmap over TorchRL's own loss, parameters of each member entered with to_module
    torch.manual_seed(0)
    solo = DQNLoss(make_qvalue_actor(make_q_network(8, NUM_ACTIONS), env.action_spec), delay_value=True,
                   action_space="categorical")
    solo.make_value_estimator(gamma=cfg.gamma)
    online = torch.stack([solo.value_network_params.data.clone() for _ in range(members)]).requires_grad_(True)
    target = torch.stack([solo.target_value_network_params.data.clone() for _ in range(members)])
    batches = torch.stack([batch.clone() for _ in range(members)])

    def member_loss(params: TensorDict, target_params: TensorDict, member_batch: TensorDict):
        with params.to_module(solo.value_network_params), target_params.to_module(solo.target_value_network_params):
            return solo(member_batch)["loss"]

    def vmapped() -> None:
        torch.vmap(member_loss, randomness="different")(online, target, batches).sum().backward()

    stacked_network = make_stacked_network([cfg] * members, 8, NUM_ACTIONS)
    stacked = make_loss([cfg], make_qvalue_actor(stacked_network, env.action_spec))
    stacked_batch = batches.select(*stacked.in_keys)

    def stacked_update() -> None:
        stacked(stacked_batch.clone())["loss"].mean(-1).sum().backward()

    result = {"kind": "update_alternatives", "algo": "dqn", "network": "128x128x128", "members": members}
    for name, fn in (("vmap_dqn_loss_ms", vmapped), ("stacked_network_ms", stacked_update)):
        result[name] = _ms_per_call(fn, repeats, warmup=3)
    return result


def _conv_batch(members: int, rows: int, seed: int = 0) -> TensorDict:
    """``[members, rows]`` random transitions with ttenv v4's observation: belief features and a map image of
    -1 (free) and 1 (occupied) cells, as ttenv scales it."""
    generator = torch.Generator().manual_seed(seed)
    shape, conv = (members, rows), network("conv")

    def state() -> dict:
        occupied = torch.rand(*shape, *conv.image, generator=generator) < 0.2
        return {"observation": torch.randn(*shape, conv.features, generator=generator),
                "local_map": occupied.float() * 2 - 1}

    done = torch.zeros(*shape, 1, dtype=torch.bool)
    return TensorDict({**state(), "action": torch.randint(NUM_ACTIONS, shape, generator=generator),
                       "next": {**state(), "reward": torch.randn(*shape, 1, generator=generator), "done": done,
                                "terminated": done.clone()}}, batch_size=shape)


def measure_conv_network(members: int, compile: bool, steps: int, device: str = "cpu") -> dict:
    """Member-frames per second of the conv DQN's work per frame (a greedy forward on one world per member and one
    update of 64 transitions per member; part 3 of the module docstring), ``steps`` timed steps after 10 (the
    first update compiles when ``compile``)."""
    cfgs = member_configs("conv", members, compile, 0, steps, device)
    conv = network("conv")
    stacked = make_stacked_network(cfgs, conv.features, NUM_ACTIONS, conv.image)
    loss = make_loss(cfgs, make_qvalue_actor(stacked, Categorical(NUM_ACTIONS, device=device)))
    optimizer = StackedAdam(list(loss.value_network_params.values(True, True)), [c.lr for c in cfgs])
    update = Updater(loss, optimizer, HardUpdate(loss, value_network_update_interval=cfgs[0].target_update_interval),
                     cfgs[0].grad_clip, compile=compile)
    batch = _conv_batch(members, BATCH).to(device)
    acting = _conv_batch(members, 1, seed=1).to(device)
    seconds = {"act": 0.0, "update": 0.0}

    def step(timed: bool) -> None:
        start = time.perf_counter()
        with torch.no_grad():
            stacked(acting["observation"], acting["local_map"]).argmax(-1)
        synchronize(device)
        middle = time.perf_counter()
        update(batch.clone())
        synchronize(device)
        if timed:
            seconds["act"] += middle - start
            seconds["update"] += time.perf_counter() - middle

    for _ in range(10):
        step(False)
    for _ in range(steps):
        step(True)
    return {"kind": "conv_network", "row": "conv", "algo": ROWS["conv"].algo, "network": conv.name,
            "conv_layers": [list(layer) for layer in conv.conv_layers], "map": list(conv.image),
            "members": members, "compiled": compile, "device": device, "steps": steps,
            "member_frames_per_s": members * steps / sum(seconds.values()),
            "ms_per_step_by_phase": {phase: 1e3 * t / steps for phase, t in seconds.items()}}


def measure_conv_alternatives(members: int, repeats: int = 20) -> dict:
    """ms of the stacked conv DQN network of ``members`` members three ways: grouped convolutions
    (:class:`~aia.modules.StackedConvQNetwork`), ``torch.vmap`` over the solo network with the members' parameters
    from ``torch.func.stack_module_state``, and a loop over the solo networks; forward and backward of a batch of
    64 per member, and a forward on 4,096 worlds split among the members."""
    cfgs, conv = member_configs("conv", members, False, 0, 1, "cpu"), network("conv")
    solos = []
    for cfg in cfgs:
        torch.manual_seed(cfg.seed)
        solos.append(make_network(cfg, conv.features, NUM_ACTIONS, conv.image))
    grouped = StackedConvQNetwork.stack(solos)
    params, buffers = torch.func.stack_module_state(solos)
    template = solos[0]

    def member(member_params, member_buffers, observation, local_map):
        return torch.func.functional_call(template, (member_params, member_buffers), (observation, local_map))

    ways = {"grouped": grouped,
            "vmap": lambda observation, local_map: torch.vmap(member)(params, buffers, observation, local_map),
            "loop": lambda observation, local_map: torch.stack(
                [solo(observation[k], local_map[k]) for k, solo in enumerate(solos)])}
    update_batch, acting = _conv_batch(members, BATCH), _conv_batch(members, ACTING_WORLDS // members, seed=1)
    result = {"kind": "conv_alternatives", "algo": "dqn", "members": members, "batch": BATCH,
              "acting_worlds": members * (ACTING_WORLDS // members)}
    def update(forward: Callable) -> None:
        forward(update_batch["observation"], update_batch["local_map"]).square().sum().backward()

    def act(forward: Callable) -> None:
        with torch.no_grad():
            forward(acting["observation"], acting["local_map"])

    for name, forward in ways.items():
        result[f"{name}_update_ms"] = _ms_per_call(functools.partial(update, forward), repeats, warmup=3)
        result[f"{name}_act_ms"] = _ms_per_call(functools.partial(act, forward), max(1, repeats // 4), warmup=1)
    return result


def measure_solo_loops(baseline: str, frames: int, repeats: int) -> list[dict]:
    """``train_throughput.py --parts loop`` of commit ``baseline`` and of the working tree, one after the other."""
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        old = Path(tmp) / "old"
        old.mkdir()
        archive = subprocess.run(["git", "archive", baseline], cwd=HERE.parent, capture_output=True, check=True)
        subprocess.run(["tar", "-x", "-C", str(old)], input=archive.stdout, check=True)
        (old / "aia" / "conf").symlink_to(old / "conf")  # the old code's configs, as its install maps them
        for label, root, env in (("before", old, {"PYTHONPATH": str(old)}), ("now", HERE.parent, {})):
            out = Path(tmp) / f"{label}.json"
            subprocess.run([sys.executable, str(root / "benchmarks" / "train_throughput.py"), "--parts", "loop",
                            "--algos", "dqn,adfq", "--loop-frames", str(frames), "--repeats", str(repeats),
                            "--out", str(out)], cwd=tmp, env=os.environ | env, check=True)
            for row in json.loads(out.read_text())["results"]:
                rows.append(row | {"kind": "solo_loop", "code": label if label == "now" else baseline})
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--device", default="cpu")
    sizes = comma_separated(POSITIVE_INT, "comma-separated population sizes >= 1", skip_empty=True)
    parser.add_argument("--members", type=sizes, default="1,5,20,80", help="comma-separated population sizes")
    parser.add_argument("--modes", type=subset_of(("eager", "compiled")), default="eager,compiled",
                        help="comma-separated: eager, compiled")
    parser.add_argument("--algos", type=subset_of(tuple(ROWS), skip_empty=True), default=",".join(ROWS),
                        help="comma-separated learner rows: " + ", ".join(
                            f"{name} ({row.algo} on experiment={row.experiment})"
                            for name, row in ROWS.items()))
    parser.add_argument("--inner-dtypes", type=subset_of(("float32", "bfloat16")), default="float32",
                        help="comma-separated inner_dtype values to compare: float32, bfloat16")
    parser.add_argument("--warmup", type=POSITIVE_INT, default=200, help="warm-up frames of each job")
    parser.add_argument("--frames", type=POSITIVE_INT, default=300, help="updating frames of each job")
    parser.add_argument("--repeats", type=POSITIVE_INT, default=1,
                        help="rounds of every population size; rows give the median and the range, and the ratio "
                             "to P = 1 of the same round")
    parser.add_argument("--conv", type=sizes, default="1,20",
                        help="comma-separated population sizes of the conv network's rows "
                        "(part 3 of the description; empty: none)")
    parser.add_argument("--conv-steps", type=POSITIVE_INT, default=100, help="timed steps of each conv row")
    parser.add_argument("--conv-alternatives", action="store_true",
                        help="also time grouped convolutions, vmap and a loop over the members at P = 1 and 20")
    parser.add_argument("--baseline", type=git_commit, default=None,
                        help="git commit of the solo loop to compare P = 1 with")
    parser.add_argument("--count-syncs", type=NON_NEGATIVE_INT, default=0, metavar="P",
                        help="on CUDA: first count the host-device syncs of a P-member population's job, by site")
    parser.add_argument("--out", type=Path, default=None)
    args = parse_checked(parser)
    sizes, conv_sizes, modes, names, dtypes = args.members, args.conv, args.modes, args.algos, args.inner_dtypes
    on_gpu = torch.device(args.device).type == "cuda"
    if args.count_syncs and not on_gpu:
        parser.error(f"--count-syncs {args.count_syncs}: counts CUDA syncs, so it needs --device cuda "
                     f"(got {args.device!r})")

    out = args.out or HERE / "results" / f"population_{args.device.split(':')[0]}.json"
    out.parent.mkdir(parents=True, exist_ok=True)
    gflops_before = sgemm_gflops(device=args.device)
    meta = {"started_utc": utc_now(), **git_state(HERE), "argv": sys.argv[1:], "torch": torch.__version__,
            "threads": torch.get_num_threads(), "machine": platform.machine(),
            "gpu": torch.cuda.get_device_name(args.device) if on_gpu else None,
            "load_average_1_5_15min": os.getloadavg(), "sgemm_gflops_before": gflops_before,
            "flops_per_member_frame": {name: flops_per_member_frame(name) for name in ROWS}}
    rows = []

    def save() -> None:  # after every row: a run stopped half-way keeps what it measured
        out.write_text(json.dumps({"meta": meta, "results": rows}, indent=2))

    if args.count_syncs:
        for name, mode in itertools.product(names, modes):
            row = count_syncs(name, args.count_syncs, mode == "compiled", args.warmup, args.frames, args.device)
            rows.append(row)
            save()
            print(f"host-device syncs of {name} {mode} P={args.count_syncs}: {row['syncs']} in {row['frames']} "
                  f"frames ({row['updates']} updates, {row['episodes']} episodes, {row['evaluations']} "
                  "evaluations)", flush=True)
            for site in row["sites"]:
                print(f"  {site['count']:>6}  {site['site']}", flush=True)
    print(f"{'row':<6}{'network':<18}{'mode':<10}{'inner':<10}{'P':>4}{'member-frames/s':>17}{' (range)':<16}"
          f"{'x P=1 (range)':<16}{'with eval':>11}{'% of matmul peak':>18}{'products':>10}"
          f"  ms per step by phase")
    for name, mode, dtype in itertools.product(names, modes, dtypes):
        # rounds of every size, one after another, so that the sizes of one round meet the same VM
        rounds = [{members: measure_population(name, members, mode == "compiled", args.warmup, args.frames,
                                               args.device, dtype) for members in sizes}
                  for _ in range(args.repeats)]
        for members in sizes:
            row = _median_run([r[members] for r in rounds], [r.get(1) for r in rounds])
            row["share_of_sgemm_peak"] = row["member_frames_per_s"] * flops_per_member_frame(name) / (
                gflops_before * 1e9)
            row["update_matmuls_ms"] = update_matmuls_ms(name, members, dtype, device=args.device)
            rows.append(row)
            save()
            rates = row["member_frames_per_s_runs"]
            spread = f" ({min(rates):,.0f}-{max(rates):,.0f})" if len(rates) > 1 else ""
            ratios = row["speedup_over_p1_runs"]
            speedup = f"{row['speedup_over_p1']:.1f}" if ratios else "-"
            if len(ratios) > 1:
                speedup += f" ({min(ratios):.1f}-{max(ratios):.1f})"
            phases = ", ".join(f"{phase} {ms:.2f}" for phase, ms in
                               sorted(row["ms_per_step_by_phase"].items(), key=lambda item: -item[1]))
            print(f"{name:<6}{row['network']:<18}{mode:<10}{dtype:<10}{members:>4}"
                  f"{row['member_frames_per_s']:>17,.0f}{spread:<16}"
                  f"{speedup:<16}{row['member_frames_per_s_with_evaluation']:>11,.0f}"
                  f"{100 * row['share_of_sgemm_peak']:>17.1f}%{row['update_matmuls_ms']:>10.2f}  {phases}"
                  f" (collect alone {row['collect_alone_ms']:.2f})",
                  flush=True)
    if conv_sizes:
        print(f"\n{'row':<6}{'network':<18}{'mode':<10}{'P':>4}{'member-frames/s':>17}{' (range)':<16}"
              f"{'x P=1 (range)':<16}  ms per step by phase  (conv rows: the network's act and update alone)")
    for mode in modes if conv_sizes else ():
        rounds = [{members: measure_conv_network(members, mode == "compiled", args.conv_steps, args.device)
                   for members in conv_sizes} for _ in range(args.repeats)]
        for members in conv_sizes:
            row = _median_run([r[members] for r in rounds], [r.get(1) for r in rounds])
            rows.append(row)
            save()
            rates, ratios = row["member_frames_per_s_runs"], row["speedup_over_p1_runs"]
            spread = f" ({min(rates):,.0f}-{max(rates):,.0f})" if len(rates) > 1 else ""
            speedup = f"{row['speedup_over_p1']:.1f}" if ratios else "-"
            if len(ratios) > 1:
                speedup += f" ({min(ratios):.1f}-{max(ratios):.1f})"
            phases = ", ".join(f"{phase} {ms:.2f}" for phase, ms in row["ms_per_step_by_phase"].items())
            print(f"{row['row']:<6}{row['network']:<18}{mode:<10}{members:>4}{row['member_frames_per_s']:>17,.0f}"
                  f"{spread:<16}{speedup:<16}  {phases}", flush=True)
    if args.conv_alternatives:
        print(f"\n{'conv stacking alternatives (DQN, eager)':<42}{'P':>4}"
              f"{'update ms: grouped / vmap / loop':>36}{'act ms: grouped / vmap / loop':>34}")
        for members in (1, 20):
            row = measure_conv_alternatives(members)
            rows.append(row)
            save()
            times = {kind: " / ".join(f"{row[f'{way}_{kind}_ms']:.1f}" for way in ("grouped", "vmap", "loop"))
                     for kind in ("update", "act")}
            print(f"{'':<42}{members:>4}{times['update']:>36}{times['act']:>34}", flush=True)
    if not on_gpu:  # the alternatives were weighed on the CPU (a GPU runs the loop's choice)
        print(f"\n{'update alternatives (DQN 3x128, batch 64, eager)':<50}{'P':>4}{'vmap(DQNLoss) ms':>18}"
              f"{'stacked network ms':>20}")
        for members in (1, 20):
            row = measure_vmap_update(members)
            rows.append(row)
            print(f"{'':<50}{members:>4}{row['vmap_dqn_loss_ms']:>18.2f}{row['stacked_network_ms']:>20.2f}",
                  flush=True)
    if args.baseline:
        print(f"\nsolo loop before ({args.baseline}) and now, updating frames/s (train_throughput.py --parts loop)")
        for row in measure_solo_loops(args.baseline, 2000, 3):
            rows.append(row)
            mode = "compiled" if row["compiled"] else "eager"
            runs = "/".join(f"{rate:.0f}" for rate in row["updating_frames_per_s_runs"])
            print(f"  {row['code']:<10}{row['algo']:<6}{mode:<10}{row['updating_frames_per_s']:>8,.0f} ({runs})",
                  flush=True)

    meta["sgemm_gflops_after"] = sgemm_gflops(device=args.device)
    meta["finished_utc"] = utc_now()
    save()
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
