"""Bad input to aia-train, aia-eval and aia-rollout: exit status 2, one stderr line naming the key and the
value, no run log left behind; ``--debug`` keeps the traceback; internal errors keep theirs. The apps run
in-process (``main()`` with ``sys.argv`` patched)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

import aia.training
from aia.apps import evaluate, rollout, train
from aia.config.errors import ConfigError

HYDRA_QUIET = ["hydra.output_subdir=null", "hydra/job_logging=disabled", "hydra/hydra_logging=disabled"]


@pytest.fixture
def bad_map(tmp_path):
    path = tmp_path / "room.yaml"
    path.write_text("size: [10.0, 10.0]\nresolution: 0.5\nboxes: [[20.0, 20.0, 25.0, 25.0]]\n")
    return path


@pytest.fixture
def malformed_map(tmp_path):
    path = tmp_path / "broken.yaml"
    path.write_text("size: [10.0, 10.0\nresolution: 0.5\n")
    return path


def run_app(main, argv: list[str], tmp_path, monkeypatch, capsys) -> tuple[int, str]:
    """Exit status and stderr of ``main`` run with ``argv`` in a Hydra run dir under ``tmp_path``."""
    monkeypatch.setattr(sys, "argv", ["app", f"hydra.run.dir={tmp_path / 'run'}", *HYDRA_QUIET, *argv])
    capsys.readouterr()
    with pytest.raises(SystemExit) as info:
        main()
    return info.value.code, capsys.readouterr().err


def _assert_one_line(code: int, err: str, prog: str, *words: str) -> None:
    assert code == 2, err
    assert err.count("\n") == 1 and err.startswith(f"{prog}: error: "), err
    for word in words:
        assert word in err, (word, err)


TRAIN_CASES = [
    (["lr=-1"], ["lr=-1", "> 0"]),
    (["algo=sarsa"], ["sarsa", "adfq"]),
    (["lr=abc"], ["lr='abc'", "a number"]),
    (["grad_clip=0"], ["grad_clip=0", "> 0"]),
    (["gamma=1.5"], ["gamma=1.5", "<= 1"]),
    (["batch_size=2000"], ["batch_size=2000", "buffer_size=1000"]),
    (["frames=0"], ["frames=0", ">= 1"]),
    (["hidden=[]"], ["hidden=[]", "layer widths"]),
    (["inner_dtype=float16"], ["inner_dtype='float16'", "bfloat16"]),
    (["device=cuda:7"], ["device='cuda:7'", "CUDA device"]),
    (["device=gpu"], ["device='gpu'", "cpu"]),
    (["exploration=thompson"], ["exploration='thompson'", "algo=dqn", "adfq"]),
    (["eval.per_rollout=20"], ["eval.per_rollout=20", "record_every_evaluations=10"]),
    (["resume=/nonexistent/last.pt"], ["resume='/nonexistent/last.pt'", "existing checkpoint"]),
    (["env.sensor.range=-3"], ["env.sensor.range=-3", "> 0"]),
    (["env=schema"], ["env/schema", "empty1"]),
    (["env=variant_2019"], ["env/variant_2019", "small3_2019"]),
    # a key the config lacks: the keys it has there, the close one first, not Hydra's advice to add it with +
    (["lr2=1"], ["lr2='1'", "the config's keys (did you mean lr?): seed, lr,"]),
    (["+lr2=1"], ["lr2=1", "did you mean lr?"]),  # added with +: a run would ignore it
    (["+env.sensor.rang=3"], ["env.sensor.rang=3", "env.sensor's keys (did you mean env.sensor.range?)"]),
    (["algo=adfq", "+algo.foo=1"], ["algo.foo=1", "algo's keys: name, loss_function, noise"]),
    (["+algo.sd_max=1"], ["algo.sd_max=1", "algo's keys: name, loss_function"]),  # algo=dqn's keys
    (["algo.sd_max=1"], ["algo.sd_max='1'", "algo's keys: name, loss_function"]),
    (["env=ttenv_v4", "env.features.local_map.im_size=0"],
     ["env.features.local_map.im_size='0'", "env.features.local_map is a value", "im_size"]),
    (["env.sensor.range=abc"], ["env.sensor.range='abc': expected a number"]),
    (["env.belief=3"], ["env.belief=3: expected keys under env.belief (env.belief.<key>=<value>), not a value"]),
]


@pytest.mark.parametrize("argv, words", TRAIN_CASES, ids=[" ".join(a) for a, _ in TRAIN_CASES])
def test_train_rejects_bad_input_in_one_line(argv, words, tmp_path, monkeypatch, capsys):
    code, err = run_app(train.main, argv, tmp_path, monkeypatch, capsys)
    _assert_one_line(code, err, "aia-train", *words)
    assert not list(tmp_path.rglob("*.mcap"))  # a run refused before its first step leaves no log


def test_train_rejects_a_bad_map_file_naming_it(bad_map, malformed_map, tmp_path, monkeypatch, capsys):
    code, err = run_app(train.main, [f"env.map={bad_map}"], tmp_path, monkeypatch, capsys)
    _assert_one_line(code, err, "aia-train", str(bad_map), "boxes[0]=[20.0, 20.0, 25.0, 25.0]", "[0, 10.0]")
    code, err = run_app(train.main, [f"env.map={malformed_map}"], tmp_path, monkeypatch, capsys)
    _assert_one_line(code, err, "aia-train", str(malformed_map), "YAML", "line")


def test_debug_keeps_the_traceback(tmp_path, monkeypatch):
    monkeypatch.setattr(sys, "argv", ["app", f"hydra.run.dir={tmp_path}", *HYDRA_QUIET, "lr=-1", "--debug"])
    with pytest.raises(ConfigError, match="lr=-1"):
        train.main()


def test_internal_errors_keep_their_traceback(tmp_path, monkeypatch):
    def broken(cfgs, out_dirs, stop=None, validated=False):
        raise RuntimeError("internal")

    monkeypatch.setattr(aia.training, "train_population", broken)  # aia-train imports it once the config is valid
    monkeypatch.setattr(sys, "argv", ["app", f"hydra.run.dir={tmp_path}", *HYDRA_QUIET, "logger=none"])
    with pytest.raises(RuntimeError, match="internal"):
        train.main()


@pytest.fixture
def not_a_checkpoint(tmp_path):
    path = tmp_path / "notes.pt"
    path.write_text("not a checkpoint")
    return path


def test_eval_rejects_bad_input_in_one_line(not_a_checkpoint, tmp_path, monkeypatch, capsys):
    cases = [
        ([], ["checkpoint='???'", "aia-train"]),
        (["checkpoint=/nonexistent.pt"], ["checkpoint='/nonexistent.pt'", "existing"]),
        ([f"checkpoint={not_a_checkpoint}"], [f"checkpoint='{not_a_checkpoint}'", "torch checkpoint"]),
        ([f"checkpoint={not_a_checkpoint}", "planner.horizon=3"], ["planner.horizon='3'", "policy=arvi"]),
        (["policy=psychic"], ["policy='psychic'", "arvi"]),
        (["policy=arvi", "episodes=0"], ["episodes=0", ">= 1"]),
        (["epsilon=1.5", "policy=arvi"], ["epsilon=1.5", "<= 1"]),
        (["policy=arvi", "device=cuda:7"], ["device='cuda:7'", "CUDA"]),
        (["policy=arvi", "planner.horizon=0"], ["planner.horizon=0: expected an integer >= 1"]),
        (["policy=arvi", "planner.horizon=abc"], ["planner.horizon='abc': expected an integer >= 1"]),
        (["policy=arvi", "planner.min_range=-2"], ["planner.min_range=-2.0: expected a number >= 0"]),
        (["policy=arvi", "env.num_targets=0"], ["env.num_targets=0", ">= 1"]),
        (["policy=arvi", "planner=psychic"], ["planner/psychic", "arvi"]),
        (["policy=pursuit", "planner.horizon=3"], ["planner.horizon='3'", "policy=pursuit"]),
        (["policy=pursuit", "pursuit_standoff=2"], ["pursuit_standoff=2", "<= 1"]),
        (["policy=arvi", "planner.nodes=3"], ["planner.nodes='3'", "did you mean planner.max_nodes?"]),
        (["policy=arvi", "+planner.nodes=3"],
         ["planner.nodes=3", "planner's keys (did you mean planner.max_nodes?): horizon,"]),
    ]
    for argv, words in cases:
        code, err = run_app(evaluate.main, argv, tmp_path, monkeypatch, capsys)
        _assert_one_line(code, err, "aia-eval", *words)
    assert not list(tmp_path.rglob("*.mcap"))


def test_eval_refuses_a_folder_with_a_run_log_in_one_line_and_keeps_it(tmp_path, monkeypatch, capsys):
    (tmp_path / "run").mkdir()
    (tmp_path / "run" / "run.mcap").write_bytes(b"an earlier run's log")
    code, err = run_app(evaluate.main, ["policy=pursuit", "episodes=1"], tmp_path, monkeypatch, capsys)
    _assert_one_line(code, err, "aia-eval", f"output folder='{tmp_path / 'run'}'", "never overwritten")
    assert (tmp_path / "run" / "run.mcap").read_bytes() == b"an earlier run's log"


def test_rollout_rejects_bad_input_in_one_line(bad_map, tmp_path, monkeypatch, capsys):
    cases = [
        (["policies=[random,psychic]"], ["policies=['random', 'psychic']", "pursuit"]),
        (["num_worlds=0"], ["num_worlds=0", ">= 1"]),
        (["seed=-1"], ["seed=-1", ">= 0"]),
        (["compile=maybe"], ["compile='maybe'", "true or false"]),
        (["env.num_targetz=2"], ["env.num_targetz='2'", "did you mean env.num_targets?"]),
        (["+env.features.im_sz=3"], ["env.features.im_sz=3", "did you mean env.features.im_size?"]),
        (["env=nowhere"], ["env/nowhere", "obstacles1"]),
        ([f"env.map={bad_map}"], [str(bad_map), "boxes[0]"]),
        (["env.map=atlantis"], ["env.map='atlantis'", "obstacles4"]),
    ]
    for argv, words in cases:
        code, err = run_app(rollout.main, argv, tmp_path, monkeypatch, capsys)
        _assert_one_line(code, err, "aia-rollout", *words)


def test_a_run_folder_that_cannot_be_made_is_named_in_one_line(tmp_path, monkeypatch, capsys):
    blocker = tmp_path / "a_file"
    blocker.write_text("")
    for main, prog, argv, key in ((rollout.main, "aia-rollout", [f"hydra.run.dir={blocker / 'run'}"], "hydra.run.dir"),
                                  (train.main, "aia-train", ["-m", f"hydra.sweep.dir={blocker / 'sweep'}", "seed=0,1"],
                                   "hydra.sweep.dir")):
        monkeypatch.setattr(sys, "argv", ["app", *argv, *HYDRA_QUIET])
        with pytest.raises(SystemExit) as info:
            main()
        _assert_one_line(info.value.code, capsys.readouterr().err, prog, f"{key}: cannot make or write",
                         str(blocker), "Not a directory")
    assert blocker.read_text() == ""


def test_help_lists_only_what_can_be_set(tmp_path, monkeypatch, capsys):
    for main, groups, absent in ((train.main, ("env:", "algo:", "exploration:", "method:", "experiment:"),
                                  ("maps", "planner", "schema", "variant_2019")),
                                 (rollout.main, ("env:",), ("maps", "planner", "algo:", "schema", "variant_2019")),
                                 (evaluate.main, ("env:", "planner: arvi", "hydra/launcher: local, population"),
                                  ("maps", "algo:", "schema", "variant_2019"))):
        monkeypatch.setattr(sys, "argv", ["app", "--help"])
        with pytest.raises(SystemExit) as info:
            main()
        assert info.value.code == 0
        out = capsys.readouterr().out
        assert all(group in out for group in groups) and not any(word in out for word in absent), out
        assert "sensor:" in out and "exit" in out  # every field, and what invalid input does


def test_help_into_a_closed_pipe_ends_without_a_traceback():
    app = Path(sys.executable).with_name("aia-train")
    process = subprocess.Popen([str(app), "--help"], stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    process.stdout.close()  # the reader is gone before the app writes (aia-train --help | head -0)
    _, err = process.communicate(timeout=120)
    assert process.returncode == 1 and err == b""


@pytest.mark.parametrize("app, argv", [("train", ["--help"]), ("train", ["lr=-1"]), ("train", ["env.num_targets=0"]),
                                       ("train", ["env.belief.filter=nope"]),
                                       ("evaluate", ["--help"]), ("evaluate", ["checkpoint=none.pt"]),
                                       ("rollout", ["num_worlds=0"])])
def test_help_and_a_refusal_answer_without_loading_torch(tmp_path, app, argv):
    # the training and evaluation stacks load only once a config is valid: --help and a refusal take about a second
    code = (f"import sys; from aia.apps.{app} import main; sys.argv = ['app', *{argv!r}]\n"
            "try:\n    main()\nexcept SystemExit as end:\n    print(end.code, 'torch' in sys.modules)")
    result = subprocess.run([sys.executable, "-c", code], cwd=tmp_path, capture_output=True, text=True, timeout=120)
    assert result.stdout.splitlines()[-1] == ("0 False" if argv == ["--help"] else "2 False"), result.stderr[-2000:]
    assert argv == ["--help"] or result.stderr.count("\n") == 1, result.stderr
