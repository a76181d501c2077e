"""Keeping the shaker output off unless a healthy, supervised test wants it on.

The output starts OFF, and arming is explicit: :meth:`SerialShaker.arm` refuses
unless an :class:`OutputGuard` is active, and the guard switches the output off on
entry. From then on every way out switches it off:

- leaving the ``with`` block, normally or by any exception (``finally``);
- :meth:`OutputGuard.trip` (an abort button, a closed window, a lost DAQ link);
- :meth:`OutputGuard.check` finding an abort limit exceeded in a block, or a fault
  the shaker's heartbeat found (tripped output, lost link);
- SIGINT / SIGTERM: a handler sends output-off ahead of anything queued on the
  port, then chains to the previous handler (default SIGINT: KeyboardInterrupt;
  default SIGTERM: SystemExit(143), so ``finally`` blocks and atexit still run);
  within :func:`analysis.common.held_signals.signals_held` the output goes off at once and the rest waits
  for the block's end;
- interpreter exit (atexit), e.g. when the guard lives in a daemon thread.

If the host dies without any of these (power cut, SIGKILL, unplugged cable) the
instrument's own watchdog switches the output off once the heartbeats stop.

Signal handlers can only be installed from the main thread; a guard entered in a
worker thread relies on :func:`install_signal_handlers` having been called from
the main thread at start-up (the guard installs them itself when it can).
"""
from __future__ import annotations

import atexit
import math
import signal
import threading
from dataclasses import dataclass
from datetime import datetime, timezone
from typing import Any, Callable, Mapping, Sequence

import numpy as np

from analysis.common.errors import InputError
from analysis.common.held_signals import Cooperating, cooperate, deferred

from .errors import InstrumentError, LinkLost
from .interfaces import Block, ShakerController

FORCE_UNITS = frozenset({"N"})
ACCELERATION_UNITS = frozenset({"m/s^2", "m/s2", "m/s**2", "m s^-2", "m/s²"})
EMERGENCY_TIMEOUT = 0.25
"""Longest a signal handler waits for each output-off to be written (s)."""


def now_iso() -> str:
    """Local time, ISO 8601 with zone, millisecond resolution."""
    return datetime.now(timezone.utc).astimezone().isoformat(timespec="milliseconds")


@dataclass(frozen=True)
class AbortLimits:
    """Abort limits on peak values in a block (None: no limit).

    Attributes
    ----------
    max_force : float or None
        N, on every channel whose unit is N.
    max_acceleration : float or None
        m/s^2, on every channel whose unit is an acceleration.
    """

    max_force: float | None = None
    max_acceleration: float | None = None

    @classmethod
    def from_table(cls, table: Mapping[str, Any] | None, source: str | None = None) -> "AbortLimits":
        """From a plan's ``[limits]`` table (InputError naming the field on a bad value)."""
        table = dict(table or {})
        values = {}
        for key in ("max_force", "max_acceleration"):
            if key not in table:
                continue
            value = table.pop(key)
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value) \
                    or value <= 0:
                raise InputError(f"must be a positive number, got {value!r}", source, f"[limits].{key}")
            values[key] = float(value)
        if table:
            raise InputError("unknown key (allowed here: max_acceleration, max_force)", source,
                             f"[limits].{sorted(table)[0]}")
        return cls(**values)


@dataclass(frozen=True)
class LimitBreach:
    """The first channel in a block whose peak exceeds its limit."""

    channel: str
    unit: str
    peak: float
    limit: float
    sample: int

    def __str__(self) -> str:
        return (f"{self.channel} reached {self.peak:.4g} {self.unit} at sample {self.sample}, "
                f"limit {self.limit:.4g} {self.unit}")


class LimitExceeded(RuntimeError):
    """An abort limit was exceeded; the output has been switched off."""

    def __init__(self, breach: LimitBreach):
        self.breach = breach
        super().__init__(f"abort limit exceeded: {breach}")


def check_limits(block: Block, limits: AbortLimits) -> LimitBreach | None:
    """The first limit breach in ``block`` (channels in column order), or None.

    Channels are matched to limits by unit: :data:`FORCE_UNITS` to ``max_force``,
    :data:`ACCELERATION_UNITS` to ``max_acceleration``.
    """
    if len(block) and block.data.ndim == 2:
        # every block is checked, almost all are within the limits: one pass over the peaks says so, and only
        # a block with a peak beyond a limit is searched for its first breach. fmax passes NaNs over, as the search
        # does: a NaN sample beside a breach must not hide it
        peaks = np.fmax.reduce(np.abs(block.data), axis=0)
        if not (peaks > _limit_row(block.units, limits)).any():
            return None
    for column, (name, unit) in enumerate(zip(block.channels, block.units)):
        if unit in FORCE_UNITS:
            limit = limits.max_force
        elif unit in ACCELERATION_UNITS:
            limit = limits.max_acceleration
        else:
            continue
        if limit is None or len(block) == 0:
            continue
        magnitude = np.abs(block.data[:, column])
        over = np.flatnonzero(magnitude > limit)
        if over.size:
            return LimitBreach(name, unit, float(magnitude.max()), limit, block.first_sample + int(over[0]))
    return None


def _limit_row(units: Sequence[str], limits: AbortLimits) -> np.ndarray:
    """Each column's limit by its unit (infinite where none applies), as :func:`check_limits` matches them."""
    key = (tuple(units), limits.max_force, limits.max_acceleration)
    row = _LIMIT_ROWS.get(key)
    if row is None:
        def limit(unit: str) -> float | None:
            if unit in FORCE_UNITS:
                return limits.max_force
            return limits.max_acceleration if unit in ACCELERATION_UNITS else None
        row = _LIMIT_ROWS[key] = np.array([np.inf if limit(u) is None else limit(u) for u in units])
    return row


_LIMIT_ROWS: dict[tuple, np.ndarray] = {}


@dataclass(frozen=True)
class SafetyEvent:
    """Something the guard did or saw, with the local time (ISO 8601)."""

    time: str
    kind: str
    detail: str


# ----- process-wide handlers ----------------------------------------------------------------
_active: tuple["OutputGuard", ...] = ()          # replaced, never mutated: read lock-free by handlers
_registry_lock = threading.Lock()
_previous: dict[int, Any] = {}
_HANDLED = (signal.SIGINT, signal.SIGTERM)


def _handle_signal(signum: int, frame: Any) -> None:
    _emergency_stops(signum)
    if not deferred(signum):                       # else it acts at a held block's end (signals_held)
        _chain(signum, frame)


def _emergency_stops(signum: int) -> None:
    name = signal.Signals(signum).name
    for guard in _active:
        guard.emergency_stop(f"signal {name}")


def _chain(signum: int, frame: Any) -> None:
    """What the signal did before :func:`install_signal_handlers`: KeyboardInterrupt, SystemExit or a handler."""
    previous = _previous.get(signum, signal.SIG_DFL)
    if callable(previous):
        previous(signum, frame)
    elif previous == signal.SIG_IGN:
        return
    elif signum == signal.SIGINT:
        raise KeyboardInterrupt
    else:
        raise SystemExit(128 + signum)


#: The handler as :mod:`analysis.common.held_signals` knows it: in a held block its emergency stop is made at
#: once, the rest at the block's end
_HANDLER = Cooperating(_handle_signal, _chain)


def install_signal_handlers() -> bool:
    """Install the SIGINT/SIGTERM handlers (main thread only); True if they are in place."""
    if threading.current_thread() is not threading.main_thread():
        return all(signal.getsignal(s) is _handle_signal for s in _HANDLED)
    for signum in _HANDLED:
        current = signal.getsignal(signum)
        if current is not _handle_signal:
            _previous[signum] = current
            signal.signal(signum, _handle_signal)
    cooperate(_HANDLER)
    return True


def _restore_signal_handlers() -> None:
    if threading.current_thread() is not threading.main_thread():
        return
    cooperate(None)
    for signum, previous in list(_previous.items()):
        if signal.getsignal(signum) is _handle_signal:
            signal.signal(signum, previous if previous is not None else signal.SIG_DFL)
        del _previous[signum]


@atexit.register
def _at_exit() -> None:
    for guard in _active:
        guard.trip("interpreter exit")


def _activate(guard: "OutputGuard") -> None:
    global _active
    with _registry_lock:
        _active = _active + (guard,)


def _deactivate(guard: "OutputGuard") -> None:
    global _active
    with _registry_lock:
        _active = tuple(g for g in _active if g is not guard)
        if not _active:
            _restore_signal_handlers()


class OutputGuard:
    """Supervise one or more shaker outputs for the duration of a ``with`` block.

    Parameters
    ----------
    *shakers : ShakerController
        The outputs to guard (switched off on entry).
    limits : AbortLimits, optional
        Checked by :meth:`check` on every block.
    on_event : callable, optional
        ``on_event(SafetyEvent)`` for each event (e.g. to log it in the session);
        may be called from the port's thread or a signal handler.

    Examples
    --------
    >>> with OutputGuard(shaker, limits=AbortLimits(5.0, 50.0)) as guard:  # doctest: +SKIP
    ...     shaker.set_sine(12.0, 0.2)
    ...     guard.arm()
    ...     with daq.stream(4096) as stream:
    ...         for block in stream:
    ...             guard.check(block)
    """

    def __init__(self, *shakers: ShakerController, limits: AbortLimits | None = None,
                 on_event: Callable[[SafetyEvent], None] | None = None):
        if not shakers:
            raise ValueError("OutputGuard needs at least one shaker")
        self.shakers = shakers
        self.limits = limits or AbortLimits()
        self.events: list[SafetyEvent] = []
        self.tripped = False
        self._on_event = on_event

    def _record(self, kind: str, detail: str) -> None:
        event = SafetyEvent(now_iso(), kind, detail)
        self.events.append(event)
        if self._on_event is not None:
            self._on_event(event)

    def __enter__(self) -> "OutputGuard":
        for shaker in self.shakers:
            shaker.disarm()
        install_signal_handlers()
        for shaker in self.shakers:
            shaker.attach_guard(self)
            shaker.add_fault_listener(self._fault)
        _activate(self)
        self._record("guard", "output off, guard active")
        return self

    def arm(self) -> None:
        """Switch every guarded output on (the instrument ramps the amplitude up)."""
        if self.tripped:
            raise InstrumentError(self.shakers[0].url, "guard has tripped; open a new guard to arm again")
        for shaker in self.shakers:
            shaker.arm()
        self._record("armed", "output on")

    def check(self, block: Block | None = None) -> None:
        """Raise if a shaker reported a fault or ``block`` exceeds a limit (after switching off)."""
        for shaker in self.shakers:
            try:
                shaker.check()
            except InstrumentError as exc:
                self.trip(f"shaker fault: {exc}")
                raise
        if block is not None:
            breach = check_limits(block, self.limits)
            if breach is not None:
                self.trip(f"limit: {breach}")
                raise LimitExceeded(breach)

    def trip(self, reason: str) -> None:
        """Switch every output off now (abort button, window closed, ...); logs ``reason``."""
        self.tripped = True
        self._record("trip", reason)
        for shaker in self.shakers:
            self._switch_off(shaker)

    def emergency_stop(self, reason: str) -> None:
        """Output-off ahead of queued traffic, without locks: for signal handlers."""
        self.tripped = True
        for shaker in self.shakers:
            sent = shaker.emergency_off(EMERGENCY_TIMEOUT)
            self.events.append(SafetyEvent(now_iso(), "emergency",
                                           f"{reason}: output off {'sent' if sent else 'NOT sent'} to {shaker.url}"))

    def _switch_off(self, shaker: ShakerController) -> None:
        try:
            shaker.disarm()
        except LinkLost as exc:
            self._record("unconfirmed", f"{exc}; the instrument watchdog switches the output off")
        except InstrumentError as exc:
            sent = shaker.emergency_off(EMERGENCY_TIMEOUT)
            self._record("unconfirmed", f"{exc}; output off {'sent again' if sent else 'could not be sent'}")

    def _fault(self, error: InstrumentError) -> None:
        self._record("fault", str(error))

    def __exit__(self, exc_type, exc, tb) -> bool:
        try:
            if exc_type is None:
                self._record("end", "guarded block finished")
            else:
                self._record("end", f"{exc_type.__name__}: {exc}")
            for shaker in self.shakers:
                self._switch_off(shaker)
        finally:
            for shaker in self.shakers:
                shaker.remove_fault_listener(self._fault)
                shaker.attach_guard(None)
            _deactivate(self)
        return False
