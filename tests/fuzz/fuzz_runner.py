"""The fuzz corpus's runner: one hostile input, one command, run in process, checked against the contract.

A :class:`Case` is the files a command finds in a fresh folder (bytes, ``None`` for a sub-folder, or a function
making the bytes from the valid inputs the fixtures provide, such as a simulated session), the command line
(``{d}`` stands for that folder) and the exit statuses the contract allows. :func:`run_case` writes the files,
calls ``app.cli.main`` with the arguments and records what came out; :func:`check` asserts the
contract: no traceback, no hang (a case that takes HANG_SECONDS fails), an exit status allowed, a refusal (2) is
one line naming the file (or argparse's usage error), and no file in the folder changed, appeared or vanished.

To add a corpus (a file format, a command): build Cases -- mutations of a valid file, each paired with every
command that reads that kind of file -- and parametrize a test over them with :func:`params`, which keeps the
first FAST_PER_GROUP cases of each group in the fast set and marks the rest slow.
"""
from __future__ import annotations

import faulthandler
import hashlib
import io
import signal
from contextlib import redirect_stderr, redirect_stdout
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Iterable, Mapping, Union

import pytest

HANG_SECONDS = 60
"""A case still running after this long is a hang."""
FAST_PER_GROUP = 2
"""Cases of each group in the fast set (the rest are marked slow)."""


Content = Union[bytes, None, Callable[[Mapping[str, Any]], bytes]]


@dataclass(frozen=True)
class Case:
    group: str                              # the corpus it belongs to, e.g. "plan" or "session-edit"
    name: str                               # what was done to the input
    argv: tuple[str, ...]                   # the command line; "{d}" is the case's folder
    files: Mapping[str, Content]            # written into the folder first (None: a sub-folder)
    statuses: tuple[int, ...] = (2,)        # exit statuses the contract allows for it
    names: tuple[str, ...] = ()             # file names a refusal must mention (one of them)
    usage: bool = False                     # refused by the argument parser (usage line + error line)

    @property
    def id(self) -> str:
        return f"{self.group}:{self.name}:{self.argv[0]}"


@dataclass
class Outcome:
    status: int
    out: str
    err: str
    changed: list[str]


class Hang(BaseException):
    """Raised in the command when it ran too long (a BaseException: the CLI's own handlers let it through)."""


def _snapshot(folder: Path) -> dict[str, str]:
    return {str(p.relative_to(folder)): hashlib.sha256(p.read_bytes()).hexdigest() if p.is_file() else "dir"
            for p in sorted(folder.rglob("*"))}


def _alarm(signum, frame):
    raise Hang(f"no answer within {HANG_SECONDS} s")


def run_case(case: Case, folder: Path, inputs: Mapping[str, Any] | None = None) -> Outcome:
    """Write the case's files into ``folder`` (functions among them are given ``inputs``) and run its command
    in this process."""
    from app.cli import main

    for name, data in case.files.items():
        if callable(data):
            data = data(inputs or {})
        target = folder / name
        if data is None:
            target.mkdir(parents=True, exist_ok=True)
        else:
            target.parent.mkdir(parents=True, exist_ok=True)
            target.write_bytes(data)
    before = _snapshot(folder)
    argv = [a.replace("{d}", str(folder)) for a in case.argv]
    out, err = io.StringIO(), io.StringIO()
    previous = signal.signal(signal.SIGALRM, _alarm)
    signal.alarm(HANG_SECONDS)
    # a hang inside C code (HDF5) never returns to the alarm's handler: then the worker ends with a traceback
    faulthandler.dump_traceback_later(2 * HANG_SECONDS, exit=True)
    try:
        with redirect_stdout(out), redirect_stderr(err):
            try:
                status = main(argv)
            except SystemExit as exc:             # argparse's refusals
                status = exc.code if isinstance(exc.code, int) else 2
    finally:
        faulthandler.cancel_dump_traceback_later()
        signal.alarm(0)
        signal.signal(signal.SIGALRM, previous)
    after = _snapshot(folder)
    changed = sorted(k for k in before.keys() | after.keys() if before.get(k) != after.get(k))
    return Outcome(status, out.getvalue(), err.getvalue(), changed)


def check(case: Case, outcome: Outcome) -> None:
    """The contract for hostile input (module docstring)."""
    err = outcome.err.strip()
    assert "Traceback" not in outcome.err and "Error:" not in err.split(": error: ")[0], err
    assert outcome.status in case.statuses, f"exit {outcome.status}: {err}"
    assert not outcome.changed, f"files changed: {outcome.changed} ({err})"
    if outcome.status != 2:
        return
    lines = err.splitlines()
    if case.usage:
        assert lines and ": error: " in lines[-1], err
        return
    assert len(lines) == 1 and lines[0].startswith("contactid: error: "), err
    assert "(run with --debug" not in err, f"an internal error, not a refusal: {err}"
    if case.names:
        assert any(name in err for name in case.names), f"names none of {case.names}: {err}"


def params(cases: Iterable[Case]) -> list:
    """pytest parameters of ``cases``: the first FAST_PER_GROUP of each group fast, the others slow."""
    seen: dict[str, int] = {}
    out = []
    for case in cases:
        seen[case.group] = seen.get(case.group, 0) + 1
        marks = () if seen[case.group] <= FAST_PER_GROUP else (pytest.mark.slow,)
        out.append(pytest.param(case, id=case.id, marks=marks))
    return out
