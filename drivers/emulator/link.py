"""The byte link between an emulated instrument and its host.

An :class:`InstrumentLink` is what a transport (the ``sim://`` port, a pseudo
terminal, a TCP connection) moves bytes through: ``write`` hands the host's bytes
to the firmware, ``read`` takes the instrument's output from its FIFO, passing it
through the link's fault injector. In fast mode a read that finds the FIFO empty
asks the firmware to produce (the DAQ acquires one more frame), so the physics
runs exactly as fast as the host consumes.
"""
from __future__ import annotations

import threading
import time
from contextlib import contextmanager
from typing import TYPE_CHECKING, Callable, Iterator

from ..faults import FaultInjector

if TYPE_CHECKING:
    from .firmware import Firmware

POLL = 0.02
"""Longest a waiting read sleeps before it re-checks stalls and production (s)."""


class IdleClock:
    """Wall time that passes while an emulated rig has nothing to do for its hosts (s, monotonic).

    The host's reply deadlines for an in-process instrument run on this clock: it stands still while a host
    command waits or executes and while the physics runs for a reader, so a machine busy with other work
    slows an emulated instrument's replies down but never makes them late. An instrument that really stays
    silent -- an injected stall or lost reply -- still times out after the host's timeout of idle time."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._busy = 0
        self._since = 0.0
        self._worked = 0.0

    def begin(self) -> None:
        """Some work for a host started."""
        with self._lock:
            if self._busy == 0:
                self._since = time.monotonic()
            self._busy += 1

    def end(self) -> None:
        """That work is done."""
        with self._lock:
            self._busy -= 1
            if self._busy == 0:
                self._worked += time.monotonic() - self._since

    @contextmanager
    def working(self) -> Iterator[None]:
        self.begin()
        try:
            yield
        finally:
            self.end()

    def __call__(self) -> float:
        with self._lock:
            now = time.monotonic()
            return now - self._worked - (now - self._since if self._busy else 0.0)


class LinkDropped(ConnectionError):
    """The emulated cable is unplugged (injected disconnect)."""


class OutputFifo:
    """The instrument's output queue of bytes, shared by its firmware and its link."""

    def __init__(self) -> None:
        self._buffer = bytearray()
        self._ready = threading.Condition()

    def put(self, data: bytes, limit: int | None = None) -> bool:
        """Append ``data``; False (nothing appended) if it would exceed ``limit`` bytes."""
        with self._ready:
            if limit is not None and len(self._buffer) + len(data) > limit:
                return False
            self._buffer += data
            self._ready.notify_all()
            return True

    def take(self, size: int) -> bytes:
        """Up to ``size`` bytes from the front, without waiting."""
        with self._ready:
            data = bytes(self._buffer[:size])
            del self._buffer[:size]
            return data

    def wait(self, timeout: float) -> None:
        """Sleep until bytes arrive, :meth:`wake` is called or ``timeout`` s pass."""
        with self._ready:
            if not self._buffer:
                self._ready.wait(timeout)

    def wake(self) -> None:
        """Wake waiting readers (the firmware's state changed, e.g. an acquisition started)."""
        with self._ready:
            self._ready.notify_all()

    def clear(self) -> None:
        with self._ready:
            self._buffer.clear()

    def __len__(self) -> int:
        return len(self._buffer)


class InstrumentLink:
    """One host connection to an emulated instrument.

    Parameters
    ----------
    firmware : Firmware
        The instrument.
    injector : FaultInjector
        The link's faults.
    produce : callable or None
        Called when a read finds the FIFO empty (fast mode); returns whether the
        instrument will have more output.
    on_close : callable
        Called once when the link closes.
    """

    def __init__(self, firmware: "Firmware", injector: FaultInjector,
                 produce: Callable[[], bool] | None, on_close: Callable[["InstrumentLink"], None]):
        self.firmware = firmware
        self.injector = injector
        self.closed = False
        self._produce = produce
        self._close_callbacks = [on_close]

    def _check(self) -> None:
        if self.injector.disconnected:
            raise LinkDropped(f"{self.firmware.role} link disconnected")
        if self.closed:
            raise LinkDropped(f"{self.firmware.role} link closed by the instrument")

    def write(self, data: bytes) -> None:
        """Bytes from the host to the instrument."""
        self._check()
        self.firmware.receive(data)

    def read(self, size: int, timeout: float | None) -> bytes:
        """Up to ``size`` bytes from the instrument; waits at most ``timeout`` s (None: until some)."""
        deadline = None if timeout is None else time.monotonic() + timeout
        fifo = self.firmware.output
        injector = self.injector
        while True:
            self._check()
            now = time.monotonic()
            if deadline is not None and now >= deadline and timeout != 0:
                return b""
            if injector.stalled_until > now:
                pause = injector.stalled_until - now
                if deadline is not None:
                    pause = min(pause, deadline - now)
                    if pause <= 0:
                        return b""
                time.sleep(min(pause, POLL))
                continue
            allowance = injector.allowance(size)
            if allowance <= 0:
                injector.strike()
                continue
            data = fifo.take(allowance)
            if not data and self._produce is not None and self._produce():
                data = fifo.take(allowance)
            if data:
                data = injector.corrupt(data)
                if data:
                    return data
                continue
            if timeout == 0:
                return b""
            wait = POLL if deadline is None else min(POLL, deadline - now)
            fifo.wait(wait)

    @property
    def on_demand(self) -> bool:
        """Whether the instrument produces its output only as the host reads it (fast mode)."""
        return self._produce is not None

    def clock(self) -> float:
        """The rig's :class:`IdleClock`: what the host's reply deadlines count on this link."""
        return self.firmware.rig.idle_clock()

    def available(self) -> int:
        """Bytes the instrument has queued for the host."""
        return len(self.firmware.output)

    def discard(self) -> None:
        """Drop the instrument's queued output (the host flushed its input buffer)."""
        self.firmware.output.clear()

    def on_close(self, callback: Callable[["InstrumentLink"], None]) -> None:
        """Also call ``callback(link)`` when the link closes."""
        self._close_callbacks.append(callback)

    def close(self) -> None:
        if not self.closed:
            self.closed = True
            for callback in self._close_callbacks:
                callback(self)
