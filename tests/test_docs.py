"""The code blocks of README.md and docs/*.md run as written: every ```python block (but those of
``PYTHON_IMPORTS_ONLY``, whose imports run, each with the reason), and the ```bash lines that are cheap. Every
other bash line must match one of ``EXCLUDED`` (a pattern and the reason it is not run here), so a new command
in the docs is either run or excluded with its reason. The commands not run are still checked where it is cheap: every
``aia-train``/``aia-eval``/``aia-rollout`` command is composed and validated as its app would, and every benchmark
command is parsed by its benchmark's own options, so that a renamed key or option fails here, not for a reader.

The python blocks of one page run in order in one namespace, in a scratch folder, seeded; their sizes are the
docs' own (small). The bash lines run in the same scratch folder, a run's log placeholder
(``outputs/<date>/<time>/run.mcap``) standing for the log that docs/logging.md's python block writes.
"""

from __future__ import annotations

import os
import re
import shlex
import subprocess
import sys
from pathlib import Path

import pytest
import torch

ROOT = Path(__file__).resolve().parents[1]
PAGES = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]
FENCE = re.compile(r"^( *)```(\w*)\n(.*?)^\1```", re.S | re.M)

# bash lines run as written (after the placeholder of a run's log is replaced): cheap, a few seconds in all
RUN = {
    "aia-log summary outputs/<date>/<time>/run.mcap",
    "aia-log scalars outputs/<date>/<time>/run.mcap --topic eval/score",
}
RUN_LOG = "outputs/<date>/<time>/run.mcap"

# every other bash line: (pattern, why it is not run here); the first that matches counts
EXCLUDED = [
    (r"^python3 -m venv ", "the quick start's install: CI (.ci/run) runs it in a fresh venv, and runs the "
                           "README's test command exactly"),
    (r"(^|\s)scripts/reproduce\.sh$", "the paper's protocol (minutes to half an hour); tests/scripts/"
                                      "test_reproduce.py runs a small call of the script"),
    (r"(^|\s)scripts/generalisation\.sh", "the generalisation protocol (minutes for its smoke run, hours in "
                                          "full); tests/scripts/test_generalisation.py checks its input"),
    (r"^scripts/slurm_local\.sh ", "installs and starts a local SLURM (root, apt-get); tests/cluster/ run it"),
    (r"^(sinfo|squeue|sacct|sbatch|scancel)\b", "a SLURM client: tests/cluster/ use them on the local cluster"),
    (r"^(#!|#SBATCH|exec )", "a batch script's lines, for sbatch"),
    (r"^aia-train .*(hydra/launcher=(slurm|population_slurm)|hydra/sweeper=)",
     "needs a SLURM cluster or runs a search: tests/cluster/, tests/apps/test_search.py"),
    (r"^aia-train --help$", "loads Hydra, TorchRL and the training stack (about 7 s): tests/apps/"
                            "test_bad_inputs.py runs every app's --help"),
    (r"^aia-train( |$)", "trains for a minute or more: tests/apps/test_train_app.py and tests/training/ run the "
                         "app and the loop on tiny configs"),
    (r"^aia-eval ", "evaluates a checkpoint or plans for seconds to minutes: tests/apps/test_evaluate.py runs "
                    "the app on tiny configs"),
    (r"^aia-rollout( |$)", "rolls out 64-256 worlds of 100-150 steps: tests/apps/test_rollout.py"),
    (r"^aia-log (plot|render|stats|scalars '|<command>)", "needs a sweep's logs, draws figures, or is a "
                                                          "placeholder: tests/apps/test_log_cli.py covers each "
                                                          "command"),
    (r"^python -m aia\.runtime\.timing$", "measures the matmul rate for seconds: tests/runtime/test_timing.py"),
    (r"^python benchmarks/", "a benchmark runs for minutes; its figures are in benchmarks/results/"),
]

# pages whose python blocks only have their imports run (the rest is compiled, not run), and why
PYTHON_IMPORTS_ONLY = {
    "planner.md": "its ARVI episodes first compile the planner's numba kernels, about 15 s in a fresh clone; "
                  "tests/planners/test_arvi.py plays ARVIPolicy episodes through run_episodes as the block does",
}


def blocks(page: Path, language: str) -> list[tuple[int, str]]:
    """(first line number, code) of each fenced block of ``language`` in ``page``."""
    text = page.read_text()
    found = []
    for match in FENCE.finditer(text):
        if match.group(2) == language:
            indent = len(match.group(1))
            code = "\n".join(line[indent:] for line in match.group(3).splitlines())
            found.append((text[: match.start()].count("\n") + 2, code))
    return found


def bash_lines(page: Path) -> list[tuple[int, str]]:
    """(line number, command) of each command of the page's bash blocks: continuations joined, comments and
    blank lines dropped (a batch script's ``#!``/``#SBATCH`` lines kept)."""
    lines = []
    for first, code in blocks(page, "bash"):
        pending, start = "", first
        for number, raw in enumerate(code.splitlines(), first):
            line = raw.strip()
            if not pending:
                start = number
            if line.startswith(("#!", "#SBATCH")):
                lines.append((number, line))
                continue
            line = re.sub(r"\s+#\s.*$", "", line) if not line.startswith("#") else ""
            if line.endswith("\\"):
                pending += line[:-1].strip() + " "
                continue
            command = (pending + line).strip()
            pending = ""
            if command:
                lines.append((start, command))
    return lines


def classify(command: str) -> str | None:
    """None for a line that runs; else the reason it does not."""
    if command in RUN:
        return None
    for pattern, reason in EXCLUDED:
        if re.search(pattern, command):
            return reason
    raise AssertionError(f"a bash line of the docs is neither run nor excluded: {command!r} (add it to RUN if it "
                         "is cheap, else a pattern and its reason to EXCLUDED in tests/test_docs.py)")


@pytest.fixture(scope="module")
def scratch(tmp_path_factory) -> Path:
    return tmp_path_factory.mktemp("docs")


def run_python_blocks(page: Path, folder: Path) -> None:
    namespace: dict = {"__name__": f"docs_{page.stem}"}
    cwd = Path.cwd()
    os.chdir(folder)
    try:
        torch.manual_seed(0)
        for first, code in blocks(page, "python"):
            compiled = compile(code, f"{page.relative_to(ROOT)}:{first}", "exec")
            if page.name in PYTHON_IMPORTS_ONLY:
                imports = [line for line in code.splitlines() if line.startswith(("from ", "import "))]
                compiled = compile("\n".join(imports), f"{page.relative_to(ROOT)}:{first}", "exec")
            exec(compiled, namespace)
    finally:
        os.chdir(cwd)


@pytest.fixture(scope="module")
def run_log(scratch) -> Path:
    """The log docs/logging.md's python block writes."""
    run_python_blocks(ROOT / "docs" / "logging.md", scratch)
    path = scratch / "demo" / "run.mcap"
    assert path.is_file()
    return path


PYTHON_PAGES = [page for page in PAGES if blocks(page, "python")]


@pytest.mark.parametrize("page", PYTHON_PAGES, ids=[page.name for page in PYTHON_PAGES])
def test_python_blocks_run_as_written(page, scratch, run_log):
    if page.name != "logging.md":  # run by the run_log fixture
        run_python_blocks(page, scratch)


def test_every_bash_line_is_run_or_excluded_with_a_reason():
    commands = [command for page in PAGES for _, command in bash_lines(page)]
    assert set(commands) >= RUN, f"RUN lists lines no page has: {RUN - set(commands)}"
    reasons = {classify(command) for command in commands}
    assert all(reason for reason in reasons - {None})


def test_cheap_bash_lines_run_as_written(scratch, run_log):
    env = dict(os.environ, PATH=f"{Path(sys.executable).parent}{os.pathsep}{os.environ.get('PATH', '')}")
    ran = set()
    for page in PAGES:
        for number, command in bash_lines(page):
            if classify(command) is not None or command in ran:
                continue
            ran.add(command)
            argv = [str(run_log) if word == RUN_LOG else word for word in shlex.split(command)]
            done = subprocess.run(argv, cwd=scratch, env=env, capture_output=True, text=True, timeout=120)
            assert done.returncode == 0, f"{page.name}:{number}: {command}\n{done.stdout}\n{done.stderr}"
    assert ran == RUN


BENCHMARK_COMMAND = re.compile(r"^python3? benchmarks/(\w+)\.py(?:\s|$)")


def page_commands(page: Path) -> list[str]:
    """The commands ``page`` gives: its bash lines and its inline code (``python benchmarks/population.py --frames
    600``, a command beside a figure), shell comments dropped."""
    inline = [code.replace("\n", " ") for code in re.findall(r"`([^`]+)`", FENCE.sub("", page.read_text()))]
    return [re.sub(r"\s+#\s.*$", "", command.strip()) for command in [c for _, c in bash_lines(page)] + inline]


def benchmark_commands() -> list[tuple[str, str, list[str]]]:
    """(page, benchmark, arguments) of every benchmark command of the pages (:func:`page_commands`), those with a
    placeholder (``<...>``) left out."""
    found = []
    for page in PAGES:
        for command in page_commands(page):
            match = BENCHMARK_COMMAND.match(command)
            if match and "<" not in command:
                found.append((page.name, match[1], shlex.split(command)[2:]))
    return found


def test_every_benchmark_command_of_the_docs_parses_with_its_options(monkeypatch):
    # the docs' bash lines of benchmarks are not run (EXCLUDED: minutes each); their options are checked here, in
    # process: --help last, argparse converts (and so checks) every option before it, then exits 0
    from tests.benchmarks.test_benchmarks import _main, _script

    commands = benchmark_commands()
    assert {name for _, name, _ in commands} >= {"env_throughput", "population", "arvi", "map_generation"}
    for page, name, args in commands:
        assert _main(_script(name, monkeypatch), [*args, "--help"], monkeypatch) == 0, (page, name, args)


APP_COMMAND = re.compile(r"^aia-(train|eval|rollout)(?:\s|$)")
# app commands of the docs that are not composed, and why: a placeholder or elision to fill in, a refusal shown on
# purpose (history.md), a file or device this machine lacks, a search space (an optuna sweeper's own syntax)
NOT_COMPOSED = r"<|\.\.\.|\[overrides\]|=k\b|--help|checkpoint=|resume=outputs|device=cuda|hydra/sweeper="


def app_commands() -> list[tuple[str, str, list[str]]]:
    """(page, app, overrides) of every ``aia-train``/``aia-eval``/``aia-rollout`` command with overrides of the
    pages (:func:`page_commands`, but history.md's, which shows refusals): ``-m`` dropped and each swept value's
    first (``seed=0,1,2`` -> ``seed=0``), Hydra's own settings (``hydra...``) left out."""
    found = []
    for page in PAGES:
        if page.name == "history.md":
            continue
        for command in page_commands(page):
            match = APP_COMMAND.match(command)
            if not match or re.search(NOT_COMPOSED, command):
                continue
            words = [word for word in shlex.split(command)[1:] if word != "-m" and not word.startswith("hydra")]
            overrides = [re.sub(r"^([^=\[]+=)([^,\[]*),.*$", r"\1\2", word) for word in words]
            if overrides:
                found.append((page.name, match[1], overrides))
    return found


def test_every_app_command_of_the_docs_composes_and_validates():
    # the docs' app commands train, plan or roll out for minutes (EXCLUDED); their overrides are composed and
    # validated here as the app would, so that a renamed key or a preset that moved fails a test, not a reader
    from aia.config.composing import compose_config
    from aia.config.validation import validate_eval_config, validate_rollout_config, validate_train_config

    validate = {"train": lambda cfg, o: validate_train_config(cfg), "eval": validate_eval_config,
                "rollout": lambda cfg, o: validate_rollout_config(cfg)}
    commands = app_commands()
    assert {app for _, app, _ in commands} == {"train", "eval", "rollout"} and len(commands) >= 30
    for page, app, overrides in commands:
        try:
            validate[app](compose_config(app, overrides), overrides)
        except Exception as err:
            raise AssertionError(f"{page}: aia-{app} {' '.join(overrides)}: {err}") from None


def test_links_between_the_pages_resolve():
    """Every relative link of README.md and docs/ names a file that exists, and its #anchor a heading there."""
    for page in PAGES:
        text = FENCE.sub("", page.read_text())
        for target in re.findall(r"\]\(([^)\s]+)\)", text):
            if re.match(r"[a-z]+:", target):
                continue
            path, _, anchor = target.partition("#")
            linked = (page.parent / path).resolve() if path else page
            assert linked.exists(), f"{page.name}: a link to {target}"
            if anchor and linked.suffix == ".md":
                headings = re.findall(r"^#+ (.+)$", FENCE.sub("", linked.read_text()), re.M)
                slugs = {re.sub(r"[^\w\- ]", "", h.strip().lower()).replace(" ", "-") for h in headings}
                assert anchor in slugs, f"{page.name}: a link to {target}: no such heading"


def test_the_readme_is_a_guide():
    """At most 150 lines, no dates, and the test command CI runs."""
    text = (ROOT / "README.md").read_text()
    assert len(text.splitlines()) <= 150
    assert not re.search(r"\b20\d\d-\d\d-\d\d\b", text)
    assert "python -m pytest -q" in text
