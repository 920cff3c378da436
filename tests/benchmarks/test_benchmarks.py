"""The scripts of benchmarks/: each imports and prints its ``--help`` (a stale import once left
``log_throughput.py`` unrunnable unnoticed), bad input (the shared ``--device`` and ``--out`` too) is refused in
one line with exit status 2 before any measuring, and the population benchmark's model of a row's network is the
network its preset builds."""

from __future__ import annotations

import importlib
import sys
from pathlib import Path
from types import ModuleType

import pytest
import torch

BENCHMARKS = Path(__file__).resolve().parents[2] / "benchmarks"


def _script(name: str, monkeypatch: pytest.MonkeyPatch) -> ModuleType:
    """``benchmarks/<name>.py`` as a module, its siblings importable as when it runs as a script."""
    monkeypatch.syspath_prepend(str(BENCHMARKS))
    return importlib.import_module(name)


def _main(module: ModuleType, args: list[str], monkeypatch: pytest.MonkeyPatch) -> int:
    """The exit status of ``module.main()`` run with ``args`` (argparse exits on ``--help`` and on errors)."""
    monkeypatch.setattr(sys, "argv", [f"{module.__name__}.py", *args])
    with pytest.raises(SystemExit) as exit_:
        module.main()
    return exit_.value.code


@pytest.mark.parametrize("name", sorted(path.stem for path in BENCHMARKS.glob("*.py") if path.stem != "_cli"))
def test_a_benchmark_imports_and_prints_its_help(name, monkeypatch, capsys):
    assert _main(_script(name, monkeypatch), ["--help"], monkeypatch) == 0
    assert capsys.readouterr().out.startswith(f"usage: {name}.py")


@pytest.mark.parametrize("name, args, said", [
    ("env_throughput", ["--settings", "obstacles4"], ["--settings 'obstacles4'", "obstacles1, obstacles1_2019"]),
    ("env_throughput", ["--settings", "ttenv_v2:belief.filtr=particle"],
     ["--settings 'ttenv_v2:belief.filtr=particle': expected ttenv_v2's env fields after the colon",
      "(did you mean env.belief.filter?)"]),
    ("env_throughput", ["--batch-sizes", "16", "0"], ["--batch-sizes 0: expected an integer >= 1"]),
    ("map_generation", ["--batch-size", "0"], ["--batch-size 0: expected an integer >= 1"]),
    ("arvi", ["--quality-setting", "bar"], ["--quality-setting 'bar': expected an env setting among", "empty1"]),
    ("arvi", ["--only", "throughput", "--baseline-commit", "no-such-commit"],
     ["--baseline-commit no-such-commit: git has no aia/planners/arvi.py there"]),
    ("population", ["--algos", "dqn,foo"], ["--algos 'dqn,foo'", "dqn,adfq,conv"]),
    ("population", ["--members", "1,x"], ["--members '1,x': expected comma-separated population sizes >= 1"]),
    ("train_throughput", ["--loop-frames", "100"], ["--loop-frames 100: expected more than the 500 warm-up"]),
    ("env_throughput", ["--device", "nosuch"],
     ["--device 'nosuch': expected a torch device such as cpu, cuda or cuda:0"]),
    ("map_generation", ["--out", "/proc/nope/x.json"], ["--out /proc/nope/x.json: its folder cannot be made"]),
    ("log_throughput", ["--out", str(BENCHMARKS)], [f"--out {BENCHMARKS}: a folder, expected a file path"]),
] + ([("arvi", ["--device", "cuda"],
       ["--device 'cuda': expected a device this machine has: torch sees 0 CUDA device(s)"])]
     if not torch.cuda.is_available() else []))
def test_bad_input_is_refused_in_one_line(name, args, said, monkeypatch, capsys):
    assert _main(_script(name, monkeypatch), args, monkeypatch) == 2
    last = capsys.readouterr().err.strip().splitlines()[-1]
    assert last.startswith(f"{name}.py: error: ") and all(part in last for part in said), last


@pytest.mark.parametrize("name, args, said", [
    ("arvi", ["--worlds", "1", "0"], "--worlds 0: expected an integer >= 1"),
    ("arvi", ["--states", "0"], "--states 0: expected an integer >= 1"),
    ("arvi", ["--episodes", "-1"], "--episodes -1: expected an integer >= 0"),
    ("arvi", ["--threads", "x"], "--threads 'x': expected an integer >= 1"),
    ("arvi", ["--fast-budget", "0"], "--fast-budget 0: expected a number > 0"),
    ("env_throughput", ["--warmup", "-1"], "--warmup -1: expected an integer >= 0"),
    ("env_throughput", ["--baseline", "no-such-commit"], "--baseline 'no-such-commit': expected a commit of the git"),
    ("map_generation", ["--steps", "1.5"], "--steps 1.5: expected an integer >= 1"),
    ("log_throughput", ["--repeats", "-1"], "--repeats -1: expected an integer >= 1"),
    ("log_throughput", ["--messages", "0"], "--messages 0: expected an integer >= 1"),
    ("log_throughput", ["--train-overrides", "env.nope=1"],
     "--train-overrides: env.nope='1': expected one of env's keys: map, num_targets"),
    ("log_throughput", ["--train-overrides", "algo=zzz"],
     "--train-overrides: In 'train': Could not find 'algo/zzz' Available options in 'algo': adfq, ddqn, dqn"),
    ("log_throughput", ["--train-overrides", "frames=0"], "--train-overrides: frames=0: expected an integer >= 1"),
    ("population", ["--count-syncs", "-1"], "--count-syncs -1: expected an integer >= 0"),
    ("population", ["--warmup", "0"], "--warmup 0: expected an integer >= 1"),
    ("population", ["--modes", "eager,"], "--modes 'eager,': expected a comma-separated subset of eager,compiled"),
    ("step_profile", ["--frames", "0"], "--frames 0: expected an integer >= 10"),
    ("step_profile", ["--traces", __file__], f"--traces {__file__}: expected a folder, not a file"),
    ("train_throughput", ["--parts", "loop,x"], "--parts 'loop,x': expected a comma-separated subset of updates,loop"),
    ("train_throughput", ["--repeats", "0"], "--repeats 0: expected an integer >= 1"),
])
def test_a_bad_number_or_list_is_refused_in_one_line_naming_it(name, args, said, monkeypatch, capsys):
    assert _main(_script(name, monkeypatch), args, monkeypatch) == 2
    err = capsys.readouterr().err
    errors = [line for line in err.splitlines() if ": error: " in line]  # argparse's usage lines come first
    assert len(errors) == 1 and errors[0].startswith(f"{name}.py: error: {said}") and "Traceback" not in err, err


@pytest.mark.parametrize("name", sorted(path.stem for path in BENCHMARKS.glob("*.py") if path.stem != "_cli"))
def test_every_number_a_benchmark_reads_is_checked(name, monkeypatch):
    """No option of a benchmark reads a bare ``int`` or ``float`` (0 or -1 would pass, then fail or mislead in
    the middle of a run): each has a checked type of ``benchmarks/_cli.py``."""
    module = _script(name, monkeypatch)
    parsers = []

    def capture(parser):
        parsers.append(parser)
        raise SystemExit(0)

    monkeypatch.setattr(module, "parse_checked", capture)
    assert _main(module, [], monkeypatch) == 0
    bare = [action.option_strings[0] for action in parsers[0]._actions if action.type in (int, float)]
    assert not bare, f"{name}.py reads {bare} unchecked"


def test_the_population_rows_model_the_network_their_presets_build(monkeypatch):
    population = _script("population", monkeypatch)
    conv = population.network("conv")  # ttenv_v4: 8 belief features and the 28 x 28 local map, 3 x 128 heads
    assert conv == population.Network(8, (128, 128, 128), (1, 28, 28), ((4, 8, 4), (8, 4, 2)))
    # "SAME" padding: 28 -> 7 x 7 x 4 (8 x 8 kernels over 1 channel), -> 4 x 4 x 8 (4 x 4 kernels over 4)
    torso_macs = 7 * 7 * 4 * 8 * 8 + 4 * 4 * 8 * 4 * 4 * 4
    assert conv.torso() == (torso_macs, 128) and conv.name == "conv+128x128x128"
    head_macs = 136 * 128 + 2 * 128 * 128 + 128 * 12
    assert population.flops_per_member_frame("conv") == 2 * (torso_macs + head_macs) * (1 + 3 * 64 + 64)
    dqn = population.network("dqn")  # paper_empty1: the paper's 6N + 2 features, no map
    assert dqn == population.Network(8, (128, 128, 128), None, ((4, 8, 4), (8, 4, 2))) and dqn.torso() == (0, 0)
