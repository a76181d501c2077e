"""Steps that must not stop half way: SIGINT and SIGTERM held until a block's end.

Python raises KeyboardInterrupt (or a SIGTERM handler's SystemExit) in the main thread between any two bytecodes.
Some steps leave state behind them that is wrong if cut between two of theirs: a call to the session writer and
its reply over a pipe (half a call leaves both processes waiting on each other), a read of an in-process
instrument's port (it moves counts the instrument's threads share), a numba cache save (its index names a data file
written after it), a report plot (Qt calls the plot items' Python code from its own frames). Such a step runs in
:class:`signals_held`.

A signal held keeps its number only, never the frame it interrupted: a frame object that outlives its call keeps
every local of that call alive (Python 3.11 copies them into it), and a memoryview among them forbids the resize of
its buffer until the block's end -- the stream decoder's next frame then fails. The handler acting at the block's
end is handed ``None`` for the frame, which Python's signal handlers accept.

A process-wide handler may cooperate (:func:`cooperate`; the output guards' handler of :mod:`drivers.safety`): it
does what must be done at once (switch the shaker output off) and asks :func:`deferred` whether the rest waits for
the block's end. A block then costs a counter. Under any other handler the block puts a holding handler of its own
in place for its length.
"""
from __future__ import annotations

import signal
import threading
from dataclasses import dataclass
from typing import Any, Callable

_HANDLED = (signal.SIGINT, signal.SIGTERM)


@dataclass(frozen=True)
class Cooperating:
    """A process-wide handler that does at once what must be done and asks :func:`deferred` whether the rest
    waits: ``handler`` itself and that rest (``rest(signum, None)``), done at the held block's end."""

    handler: Callable[[int, Any], None]
    rest: Callable[[int, Any], None]


_cooperating: Cooperating | None = None   # in place for SIGINT and SIGTERM (main thread)
_holding = 0                               # how deep the main thread is in held blocks under it
_held: list[int] = []                      # the signal that came in them
_outer: "signals_held | None" = None       # under any other handler, the block whose holding handler is in place


def cooperate(handler: Cooperating | None) -> None:
    """Say that ``handler`` is SIGINT's and SIGTERM's handler from now on (None: it no longer is)."""
    global _cooperating
    _cooperating = handler


def deferred(signum: int) -> bool:
    """For the cooperating handler: whether this signal waits for the held block's end (the first in a block
    does; a second does not, and nothing is left waiting after it)."""
    global _held
    if _holding and not _held:
        _held = [signum]
        return True
    _held = []
    return False


class signals_held:
    """Within the block, SIGINT and SIGTERM act at its end; a second signal in the block acts at once, so that a
    step that does not end can still be interrupted. Outside the main thread, where Python runs no signal
    handler, the block runs as it is. Under the cooperating handler a block costs a counter (about 1 us); under
    any other it puts a holding handler in place for its length (some 15 us), and a block within it is part of
    its step: blocks nest (a compile within a compile, a cache save within it), and a second signal acts at once
    however deep they go."""

    __slots__ = ("_before", "_caught", "_inner")

    def __enter__(self) -> None:
        global _holding, _outer
        self._before, self._inner = None, False
        if threading.current_thread() is not threading.main_thread():
            return
        if _cooperating is not None:
            _holding += 1
            return
        if _outer is not None:
            self._inner = True
            return
        self._hold()
        _outer = self

    def __exit__(self, *exc) -> None:
        global _holding, _held, _outer
        if self._inner:
            return
        if self._before is not None:
            _outer = None
            self._release()
        elif threading.current_thread() is threading.main_thread() and _holding:
            _holding -= 1
            if not _holding and _held:
                signum, _held = _held[0], []
                if _cooperating is not None:
                    _cooperating.rest(signum, None)    # its immediate part was done when the signal came

    def _hold(self) -> None:
        # a handler installed outside Python (None) could not be put back: such a signal is left as it is
        self._before = {s: h for s in _HANDLED if (h := signal.getsignal(s)) is not None}
        self._caught: list[int] = []
        try:
            for signum in self._before:         # a signal between two of these still restores both
                signal.signal(signum, self._on_signal)
        except BaseException:
            self._restore()
            raise

    def _restore(self) -> None:
        for signum, handler in self._before.items():
            signal.signal(signum, handler)

    def _release(self) -> None:
        self._restore()
        if self._caught:
            self._act(self._caught[0], None)

    def _act(self, signum: int, frame: Any) -> None:
        handler = self._before[signum]
        if callable(handler):
            handler(signum, frame)
        else:
            signal.raise_signal(signum)         # the default action, or nothing for an ignored signal

    def _on_signal(self, signum: int, frame: Any) -> None:
        if self._caught:                        # the second: acts now
            self._caught = []
            self._restore()
            self._act(signum, frame)
        else:
            self._caught.append(signum)
