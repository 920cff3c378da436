"""The checks every benchmark's command line shares: a bad value is refused in one line, ``<script>.py: error:
<flag> <value>: expected <allowed>``, with exit status 2 before any measuring, instead of a traceback (or a
nonsense figure) after it.

:func:`parse_checked` checks ``--device`` and ``--out``; the ``type=`` callables here (:data:`POSITIVE_INT`,
:data:`NON_NEGATIVE_INT`, :data:`POSITIVE_NUMBER`, :func:`number`, :func:`comma_separated`, :func:`subset_of`,
:func:`env_setting`, :func:`env_case`, :func:`git_commit`, :func:`folder`) check the other options while argparse
reads them, and raise :class:`Refused`, which :func:`parse_checked` words as above."""

from __future__ import annotations

import argparse
import os
import subprocess
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import TypeVar

from aia.config.checks import Device, Number
from aia.config.errors import ConfigError, os_error_text

T = TypeVar("T")
REPO = Path(__file__).resolve().parents[1]


class Refused(argparse.ArgumentTypeError):
    """A value an option's ``type=`` refuses: its ``text`` (a number as written, anything else quoted) and what
    is ``allowed``."""

    def __init__(self, text: str, allowed: str, shown: str | None = None) -> None:
        self.text, self.allowed = text, allowed
        super().__init__(f"{_shown(text) if shown is None else shown}: expected {allowed}")


def _shown(text: str) -> str:
    """``0`` and ``-1.5`` as written; any other text quoted (``'abc'``, ``''``), as the apps' refusals show it."""
    try:
        float(text)
    except ValueError:
        return repr(text)
    return text


def number(check: Number) -> Callable[[str], int | float]:
    """A ``type=`` for a number within ``check`` (the apps' check of a config number, and its wording)."""
    def convert(text: str) -> int | float:
        try:
            value = int(text) if check.integer else float(text)
            check("", value)
        except ValueError:  # not a number, or a ConfigError (out of range)
            raise Refused(text, check.allowed) from None
        return value
    return convert


POSITIVE_INT = number(Number(ge=1, integer=True))
NON_NEGATIVE_INT = number(Number(ge=0, integer=True))
POSITIVE_NUMBER = number(Number(gt=0))


def comma_separated(item: Callable[[str], T], allowed: str, skip_empty: bool = False) -> Callable[[str], list[T]]:
    """A ``type=`` for a comma-separated list (``1,5,20``), each part read by ``item``; empty parts (and so ``''``,
    an empty list) are left out where ``skip_empty``, else refused."""
    def convert(text: str) -> list[T]:
        try:
            return [item(part) for part in text.split(",") if part or not skip_empty]
        except argparse.ArgumentTypeError:
            raise Refused(text, allowed) from None
    return convert


def subset_of(names: Sequence[str], skip_empty: bool = False) -> Callable[[str], list[str]]:
    """A ``type=`` for a comma-separated subset of ``names`` (``eager,compiled``), as a list."""
    allowed = f"a comma-separated subset of {','.join(names)}"

    def name(text: str) -> str:
        if text not in names:
            raise Refused(text, allowed)
        return text
    return comma_separated(name, allowed, skip_empty)


def env_setting(text: str) -> str:
    """A ``type=`` for the name of an env preset (``conf/env/<name>.yaml``)."""
    from aia.envs.factory import available_settings  # the env stack: imported only where a script asks for it

    if text not in available_settings():
        raise Refused(text, f"an env setting among {', '.join(available_settings())}")
    return text


def env_case(text: str) -> str:
    """A ``type=`` for an env case: a preset (:func:`env_setting`), optionally with comma-separated overrides of its
    env fields after a colon (``ttenv_v2:belief.filter=particle,belief.particles=256``), composed as the env
    composes them, so that a bad key or value is refused before anything is measured."""
    name, colon, overrides = text.partition(":")
    env_setting(name)
    if colon:
        from aia.envs.factory import load_env_config

        try:
            load_env_config(name, [item for item in overrides.split(",") if item])
        except ConfigError as err:
            raise Refused(text, f"{name}'s env fields after the colon, comma-separated, but {err}") from None
    return text


def git_commit(text: str) -> str:
    """A ``type=`` for a commit of this repository's git (a hash, a tag, a branch), as written."""
    try:
        known = not text.startswith("-") and subprocess.run(
            ["git", "rev-parse", "--verify", "--quiet", f"{text}^{{commit}}"], cwd=REPO, capture_output=True,
            check=False).returncode == 0
    except OSError as err:  # no git
        raise Refused(text, f"a git commit, but git cannot run ({os_error_text(err)})") from None
    if not known:
        raise Refused(text, f"a commit of the git repository at {REPO}")
    return text


def folder(text: str) -> Path:
    """A ``type=`` for a folder to write into: one that exists, or a path with nothing there yet."""
    path = Path(text)
    if path.exists() and not path.is_dir():
        raise Refused(text, "a folder, not a file", shown=text)
    return path


def parse_checked(parser: argparse.ArgumentParser) -> argparse.Namespace:
    """``parser.parse_args()`` with a value that a ``type=`` of this module refuses worded as ``<flag> <value>:
    expected <allowed>`` (argparse's own errors, such as an unknown option or choice, as argparse words them), and
    its ``--device`` (a device this machine has: the apps' check, :class:`aia.config.checks.Device`) and
    ``--out`` (a file path whose folder exists or can be made, not a folder) checked; the folder of ``--out`` is
    made here."""
    parser.exit_on_error = False  # an ArgumentError comes here, and is worded below
    try:
        args = parser.parse_args()
    except argparse.ArgumentError as err:
        refused = err.__context__  # argparse raises the ArgumentError while it handles the type's error
        parser.error(f"{err.argument_name} {refused}" if isinstance(refused, Refused) else str(err))
    device = getattr(args, "device", None)
    if device is not None:
        try:
            Device()("--device", device)  # the apps' check of device=
        except ConfigError as err:
            parser.error(f"--device {device!r}: expected {err.allowed}")
    out = getattr(args, "out", None)
    if out is not None:
        if out.is_dir() or str(out).endswith(os.sep):
            parser.error(f"--out {out}: a folder, expected a file path (e.g. {out / 'results.json'})")
        try:
            out.parent.mkdir(parents=True, exist_ok=True)
        except OSError as err:
            parser.error(f"--out {out}: its folder cannot be made ({os_error_text(err)})")
        if not os.access(out.parent, os.W_OK):
            parser.error(f"--out {out}: its folder {out.parent} is not writable")
    return args
