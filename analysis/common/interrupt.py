"""Stop inside a long computation: a fit, a harmonic-balance prediction, a discovery.

A loop asked to stop between its steps can make a user wait for minutes: one discovery fits a hundred sets of
laws, one fit of a contact placed in its structure solves thousands of balances. So the caller hands a question
(``stop() -> bool``) to :func:`stoppable`, and the numerics ask it through :func:`check_stop` where one pass of
their innermost loop ends (a fit's residual, a line of a prediction): well under a second apart. An answer of
True raises :class:`Interrupted`, which unwinds to the caller; the caller, not the numerics, restores what the
step had changed (analysis.loop.auto keeps the steps already taken).

The question lives in a context variable, so it is the thread's that set it: a computation run elsewhere at the
same time is not stopped by it, and numerics called with no :func:`stoppable` around them never stop.
"""
from __future__ import annotations

from contextlib import contextmanager
from contextvars import ContextVar
from typing import Callable, Iterator

_STOP: ContextVar[Callable[[], bool] | None] = ContextVar("contactid_stop", default=None)


class Interrupted(Exception):
    """The computation was asked to stop (:func:`check_stop`); what it had computed is dropped."""


@contextmanager
def stoppable(stop: Callable[[], bool] | None) -> Iterator[None]:
    """Within the block, :func:`check_stop` raises :class:`Interrupted` once ``stop()`` answers True."""
    token = _STOP.set(stop)
    try:
        yield
    finally:
        _STOP.reset(token)


def stop_when(stop: Callable[[], bool]) -> None:
    """From now on in this thread, :func:`check_stop` raises once ``stop()`` answers True (a process's own
    question, for the whole of its life: :mod:`analysis.common.parallel`'s workers)."""
    _STOP.set(stop)


def check_stop() -> None:
    """Raise :class:`Interrupted` if the question set by :func:`stoppable` answers True (cheap otherwise)."""
    stop = _STOP.get()
    if stop is not None and stop():
        raise Interrupted("stopped by the user")
