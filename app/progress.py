"""A long command's progress on stderr: what it is doing and for how long, every few seconds.

On a terminal one line is rewritten in place (``\\r``) every ``TTY_INTERVAL`` seconds and cleared at the end; in
a log (stderr not a terminal) a plain line is written every ``LOG_INTERVAL`` seconds. A command that ends within
the first interval prints nothing.
"""
from __future__ import annotations

import sys
import threading
import time

TTY_INTERVAL = 2.0
LOG_INTERVAL = 10.0


class Progress:
    """``with Progress("analyze") as p: p.phase("ranking the missing effects"); ...``"""

    def __init__(self, command: str, stream=None, interval: float | None = None):
        self.command = command
        self.stream = stream if stream is not None else sys.stderr
        self.tty = bool(getattr(self.stream, "isatty", lambda: False)())
        self.interval = interval if interval is not None else (TTY_INTERVAL if self.tty else LOG_INTERVAL)
        self._phase = "starting"
        self._start = time.monotonic()
        self._done = threading.Event()
        self._shown = False
        self._thread = threading.Thread(target=self._tick, daemon=True)

    def phase(self, what: str) -> None:
        self._phase = what

    def line(self) -> str:
        return f"{self.command}: {self._phase} ({time.monotonic() - self._start:.0f} s)"

    def _tick(self) -> None:
        while not self._done.wait(self.interval):
            if self.tty:
                self.stream.write("\r" + self.line() + "\033[K")
            else:
                self.stream.write(self.line() + "\n")
            self.stream.flush()
            self._shown = True

    def __enter__(self) -> "Progress":
        self._thread.start()
        return self

    def __exit__(self, *exc) -> None:
        self._done.set()
        self._thread.join()
        if self._shown and self.tty:
            self.stream.write("\r\033[K")                 # the report follows on a clean line
            self.stream.flush()
