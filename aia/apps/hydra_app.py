"""How the Hydra apps (``aia-train``, ``aia-eval``, ``aia-rollout``) run: one-line errors, quiet libraries.

Libraries log at WARNING and above only (torchrl's INFO lines would break into the progress bar). An
invalid input (a :class:`~aia.config.errors.ConfigError` from the validation layer, or a command line Hydra
cannot compose: an unknown group option or key, a value of the wrong type for the app's typed schema, a
malformed override, a run folder Hydra cannot make or write) ends the app with one line on stderr,
``<prog>: error: <key>=<value>: expected <allowed>``, and exit status 2. A run that fails for a reason outside
its config (:class:`~aia.config.errors.RunFailed`: a file it could not write, a run folder in use, a sweep job whose
process died, this one after the other jobs) ends it with one line and exit status 1. A stop signal (Ctrl-C,
SIGTERM, SIGUSR1) ends a job at once with one line and exit status 128 + signal (:class:`~aia.config.errors.Stopped`;
its run log is marked stopped), except while aia-train's loop runs, which ends at its episode's end with its
checkpoints (:mod:`aia.runtime.stopping`). Any other exception is an
internal error and keeps its full traceback. ``--debug`` (taken off the command line) or ``HYDRA_FULL_ERROR=1`` keeps
the traceback of invalid input too.
"""

from __future__ import annotations

import functools
import logging
import os
import sys
from collections.abc import Callable, Sequence
from importlib import resources
from pathlib import Path
from typing import Any

import hydra
from hydra.core.hydra_config import HydraConfig
from hydra.errors import ConfigCompositionException, OverrideParseException
from omegaconf import DictConfig, OmegaConf
from omegaconf.errors import OmegaConfBaseException

from aia.config.composing import composition_error
from aia.config.errors import ConfigError, RunFailed, Stopped, one_line
from aia.config.schemas import SCHEMAS
from aia.runtime.process_exit import freeze_at_exit
from aia.runtime.stopping import interrupting

COMPOSITION_ERRORS = (ConfigCompositionException, OverrideParseException)
DEBUG_FLAG = "--debug"
QUIET_LIBRARIES = ("torchrl",)
EXIT_USAGE = 2
EXIT_FAILURE = 1  # a run failed for a reason outside its config (RunFailed)


def group_options(group: str) -> str:
    """The options of config group ``group`` (``conf/<group>/*.yaml``), comma-separated: the apps' ``--help``
    lists them with ``${aia.options:<group>}``."""
    folder = Path(str(resources.files("aia.conf"))) / group
    return ", ".join(sorted(p.stem for p in folder.glob("*.yaml")))


OmegaConf.register_new_resolver("aia.options", group_options, replace=True)


def run_valid_jobs(cfgs: Sequence[DictConfig], validate: Callable[[int, DictConfig], None],
                   run: Callable[[list[int]], Sequence[Any]]) -> list[Any]:
    """A population entry's results, one per job in order: a job whose config ``validate(k, cfg)`` refuses
    (a :class:`ConfigError`) fails alone, its error its result (the launcher reports it under the job's number
    in the sweep); ``run`` gets the valid jobs' indices (none: not called) and returns their results in that
    order."""
    outcomes: dict[int, Any] = {}
    valid = []
    for index, cfg in enumerate(cfgs):
        try:
            validate(index, cfg)
            valid.append(index)
        except ConfigError as err:
            outcomes[index] = err
    if valid:
        outcomes.update(zip(valid, run(valid), strict=True))
    return [outcomes[index] for index in range(len(cfgs))]


def hydra_app(prog: str, config_name: str, population: str | None = None
              ) -> Callable[[Callable[[DictConfig], Any]], Callable[..., Any]]:
    """``@hydra.main`` on ``pkg://aia.conf``/``config_name``, with invalid input ending the app with one line
    on stderr and ``SystemExit(2)``: a :class:`ConfigError` raised by the task, or a command line that Hydra
    cannot compose. ``population`` is the dotted path of the app's entry for a group of jobs, which
    ``hydra/launcher=population`` calls (kept on the task Hydra hands the launcher as ``population_task``)."""

    def decorate(task: Callable[[DictConfig], Any]) -> Callable[..., Any]:
        debug = False

        @functools.wraps(task)
        def guarded(cfg: DictConfig) -> Any:
            for library in QUIET_LIBRARIES:  # after Hydra has configured logging
                logging.getLogger(library).setLevel(logging.WARNING)
            try:
                with interrupting():  # aia-train's loop takes the signals over while it runs
                    return task(cfg)
            except ConfigError as err:  # caught inside the job: Hydra would print a line of its own
                if debug:
                    raise
                _exit_with(prog, err)
            except Stopped as stop:
                out_dir = HydraConfig.get().runtime.output_dir
                print(f"{prog}: stopped by {stop} before the end: the run in {out_dir} is unfinished (its log, if "
                      "it wrote one, is marked stopped)", file=sys.stderr)
                raise SystemExit(stop.exit_status) from None
            except RunFailed as err:
                if debug:
                    raise
                _exit_with(prog, err, EXIT_FAILURE)

        guarded.population_task = population
        entry = hydra.main(config_path="pkg://aia.conf", config_name=config_name, version_base="1.3")(guarded)

        @functools.wraps(task)
        def run(*args: Any, **kwargs: Any) -> Any:
            nonlocal debug
            freeze_at_exit()
            debug = DEBUG_FLAG in sys.argv[1:] or os.environ.get("HYDRA_FULL_ERROR") == "1"
            sys.argv = [sys.argv[0], *(a for a in sys.argv[1:] if a != DEBUG_FLAG)]
            previous = os.environ.get("HYDRA_FULL_ERROR")
            os.environ["HYDRA_FULL_ERROR"] = "1"  # Hydra re-raises instead of printing its own report
            try:
                return entry(*args, **kwargs)
            except COMPOSITION_ERRORS as err:
                if debug:
                    raise
                _exit_with(prog, composition_message(err, SCHEMAS[config_name]))
            except ConfigError as err:  # a sweep's failed job, raised by Hydra once the sweep has ended
                if debug:
                    raise
                _exit_with(prog, err)
            except RunFailed as err:  # a sweep's failed job (the others ran to their end)
                if debug:
                    raise
                _exit_with(prog, err, EXIT_FAILURE)
            except BrokenPipeError:  # stdout closed early (aia-train --help | head): end quietly
                os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
                raise SystemExit(EXIT_FAILURE) from None
            except OSError as err:  # Hydra's own setup (the run folder), before the task
                if debug or _raised_in(err, guarded) or not isinstance(err.filename, str):
                    raise  # the task's own: an internal error, with its traceback
                _exit_with(prog, run_folder_message(err))
            finally:
                if previous is None:
                    os.environ.pop("HYDRA_FULL_ERROR", None)
                else:
                    os.environ["HYDRA_FULL_ERROR"] = previous

        return run

    return decorate


def composition_message(err: Exception, schema: type) -> str:
    """A command line Hydra could not compose, in one line: :func:`~aia.config.composing.composition_error` where
    it names the key, otherwise Hydra's message without its config search path, with the first line of its
    OmegaConf cause (what the value should have been)."""
    error = composition_error(err, schema)
    if error is not None:
        return str(error)
    message = str(err).split("Config search path")[0]
    cause = err.__cause__
    if isinstance(cause, OmegaConfBaseException) and cause.msg:
        message += f" ({cause.msg.splitlines()[0]})"
    return message


def run_folder_message(err: OSError) -> str:
    """Hydra's failure to make or write a run's folder (``err``, before the task ran), in one line naming the
    setting that chose it: ``hydra.sweep.dir`` for a sweep (``-m``), ``hydra.run.dir`` otherwise."""
    sweep = any(a in ("-m", "--multirun") or a.replace(" ", "") == "hydra.mode=MULTIRUN" for a in sys.argv[1:])
    key = "hydra.sweep.dir" if sweep else "hydra.run.dir"
    return f"{key}: cannot make or write {err.filename!r} ({err.strerror}): expected a folder this user can make"


def _raised_in(err: BaseException, function: Callable[..., Any]) -> bool:
    """Whether ``function``'s frame is on ``err``'s traceback (``err`` went through it)."""
    tb = err.__traceback__
    while tb is not None:
        if tb.tb_frame.f_code is function.__code__:
            return True
        tb = tb.tb_next
    return False


def _exit_with(prog: str, err: Exception | str, status: int = EXIT_USAGE) -> None:
    print(f"{prog}: error: {one_line(err)}", file=sys.stderr)
    raise SystemExit(status) from None
