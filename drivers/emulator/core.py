"""The emulated rig: one physics backend shared by an emulated shaker controller and DAQ.

The backend is any object with the rig simulator's interface::

    backend.sample_rate        Hz
    backend.channels           channel names, e.g. ["force", "acc:x1"]
    backend.units              one unit per channel, e.g. ["N", "m/s^2"]
    backend.lsb                per-channel ADC step in physical units
    backend.time               s of emulated time
    backend.set_sine(frequency_hz, amplitude_volts)
    backend.set_noise(rms_volts, band_hz)
    backend.set_output(on)
    backend.advance(n) -> ndarray (n, n_channels), physical units
    backend.restart_from_rest()   optional: after a failure, the structure at rest again (time runs on)

Time. In *paced* mode a clock thread advances the physics in step with the wall
clock, whether or not anyone listens (the specimen keeps moving). In *fast* mode
the physics advances only when the DAQ needs samples: as fast as the host reads
the stream, and not at all while nothing is acquired or while a host command
waits to be processed, so a fast run does not depend on the speed of the machine.
The physics advances in chunks of at most 10 ms (2 ms while the amplitude ramps;
in fast mode one DAQ frame); commands take effect between chunks.

Every emulated timer (the amplitude ramp, the watchdog) counts emulated time. The
watchdog also asks the wall clock, so that a host that feeds it in real time is
not starved by a rig running faster than real time (see :mod:`.shaker`).

A physics failure (the simulation raising) switches the output off, ends the
acquisition and queues -300 on both instruments; the next ``*RST``, ``OUTP ON``,
``INIT``, ``READ?`` or new connection restarts the physics from rest. In fast mode a
rig that every host has left comes to rest too (:meth:`EmulatedRig._come_to_rest`).
"""
from __future__ import annotations

import threading
import time
from dataclasses import dataclass
from typing import Any, Callable, Mapping

import numpy as np

from ..faults import ROLES, FaultInjector, LinkFaults, parse_faults
from .daq import DaqFirmware
from .link import IdleClock, InstrumentLink
from .scpi_server import ScpiError
from .generator import GeneratorFirmware
from .shaker import ShakerFirmware

SHAKER_MODELS = {"SC-1": ShakerFirmware, "33500B": GeneratorFirmware}
"""The shaker controllers the emulator can be: the SC-1, or a 33500B-series bench generator."""

CLOCK_TICK = 0.005
"""Period of the paced clock (s of wall time)."""
HOLD_POLL = 0.02
"""Longest a fast-mode read waits before it re-checks the host commands that hold the physics (s)."""
REQUIRED = ("sample_rate", "channels", "units", "lsb", "time", "set_sine", "set_noise", "set_output", "advance")


@dataclass(frozen=True)
class EmulatorEvent:
    """Something an emulated instrument did, stamped with emulated time (s)."""

    time: float
    instrument: str
    kind: str
    detail: str


class LinkBusy(ConnectionError):
    """The instrument already has a host connected."""


class EmulatedRig:
    """An emulated shaker controller and DAQ on one physics backend.

    Parameters
    ----------
    backend : object
        The physics (see module docstring).
    paced : bool
        Real time (True) or as fast as the DAQ's reader (False).
    name : str
        Rig name: the serial-number field of ``*IDN?`` and the ``sim://`` host name.
    faults : mapping, optional
        A ``[faults]`` table (:func:`drivers.faults.parse_faults`) applied to every link
        unless a link is opened with its own faults.
    fifo_seconds : float
        Capacity of the DAQ's output FIFO in seconds of stream.
    shaker_model : str
        A key of :data:`SHAKER_MODELS`: ``"SC-1"`` or ``"33500B"`` (a bench generator: no ramp, no watchdog).

    Notes
    -----
    Use as a context manager, or call :meth:`start` and :meth:`close`.
    """

    def __init__(self, backend: Any, *, paced: bool = True, name: str = "emulator",
                 faults: Mapping[str, Any] | None = None, fifo_seconds: float = 1.0, shaker_model: str = "SC-1"):
        if shaker_model not in SHAKER_MODELS:
            raise ValueError(f"shaker model must be one of {', '.join(SHAKER_MODELS)}, got {shaker_model!r}")
        missing = [attr for attr in REQUIRED if not hasattr(backend, attr)]
        if missing:
            raise TypeError(f"rig backend lacks {', '.join(missing)}")
        self.backend = backend
        self.paced = paced
        self.name = name
        self.sample_rate = float(backend.sample_rate)
        self.channels = tuple(str(c) for c in backend.channels)
        self.units = tuple(str(u) for u in backend.units)
        self.lsb = np.asarray(backend.lsb, dtype=float).reshape(-1)
        if not (len(self.channels) == len(self.units) == self.lsb.size) or not self.channels:
            raise ValueError("rig backend: channels, units and lsb must have one entry per channel")
        if not np.all(self.lsb > 0) or not self.sample_rate > 0:
            raise ValueError("rig backend: sample_rate and every lsb must be > 0")
        self.default_faults = parse_faults(faults)
        self.lock = threading.RLock()
        self.idle_clock = IdleClock()
        self.changed = threading.Condition(self.lock)
        self.events: list[EmulatorEvent] = []
        self.samples = 0
        self.running = False
        self.failure: Exception | None = None
        self.shaker = SHAKER_MODELS[shaker_model](self)
        self.daq = DaqFirmware(self, fifo_seconds)
        self.instruments = {"shaker": self.shaker, "daq": self.daq}
        self._links: dict[str, InstrumentLink] = {}
        self._close_hooks: list[Callable[["EmulatedRig"], None]] = []
        self._stop = threading.Event()
        self._clock = threading.Thread(target=self._run_clock, name=f"{name} clock", daemon=True) \
            if paced else None

    # ----- lifecycle ---------------------------------------------------------------------
    def start(self) -> "EmulatedRig":
        """Start the instruments and the clock (a rig runs once: it cannot restart after close)."""
        if self._stop.is_set():
            raise RuntimeError(f"emulated rig {self.name!r} was closed; build a new one")
        if not self.running:
            # a first call compiles the physics: do it now, not while a host waits for a reply
            self.backend.advance(0)
            self.running = True
            for firmware in self.instruments.values():
                firmware.start()
            if self._clock is not None:
                self._clock.start()
        return self

    def close(self) -> None:
        """Stop the clock and the instruments and drop every link."""
        if not self.running:
            return
        self.running = False
        self._stop.set()
        for hook in self._close_hooks:
            hook(self)
        for link in list(self._links.values()):
            link.close()
        for firmware in self.instruments.values():
            firmware.stop()
        if self._clock is not None and threading.current_thread() is not self._clock:
            self._clock.join(2.0)
        with self.lock:
            self.changed.notify_all()

    def __enter__(self) -> "EmulatedRig":
        return self.start()

    def __exit__(self, *exc) -> None:
        self.close()

    def on_close(self, hook: Callable[["EmulatedRig"], None]) -> None:
        """Call ``hook(rig)`` when the rig closes (e.g. to drop it from the ``sim://`` name table)."""
        self._close_hooks.append(hook)

    # ----- time ----------------------------------------------------------------------------
    @property
    def time(self) -> float:
        """Emulated time (s)."""
        return float(self.backend.time)

    def notify(self) -> None:
        """Wake whoever waits for the rig (a command was processed, a setting changed)."""
        with self.lock:
            self.changed.notify_all()

    def commands_pending(self) -> bool:
        """Whether an instrument has host commands not yet processed."""
        return any(firmware.pending for firmware in self.instruments.values())

    def advance(self, n: int) -> None:
        """Run the physics ``n`` samples forward and hand the samples to the DAQ (lock held).

        If the backend fails (e.g. the response diverges) the rig behaves like a
        faulted instrument pair: output off, acquisition ended, error -300 queued on
        both, and the physics stays stopped.
        """
        remaining = int(n)
        while remaining > 0 and self.failure is None:
            step = min(remaining, self.shaker.chunk_limit())
            try:
                self.shaker.before_chunk(step / self.sample_rate)
                # C order, float: the converter is compiled for that layout (another would compile anew)
                data = np.ascontiguousarray(self.backend.advance(step), dtype=float)
                if data.shape != (step, len(self.channels)):
                    raise ValueError(f"advance({step}) returned shape {data.shape}, "
                                     f"expected ({step}, {len(self.channels)})")
            except Exception as exc:  # any backend failure is reported through the instruments
                self._fail(exc)
                break
            self.samples += step
            self.daq.capture(data)
            remaining -= step
        self.changed.notify_all()

    def _fail(self, exc: Exception) -> None:
        self.failure = exc
        detail = f"physics stopped: {type(exc).__name__}: {exc}"
        self.log("rig", "failure", detail)
        self.shaker.switch_off("physics failure")
        self.daq.stop_acquisition()
        for firmware in self.instruments.values():
            firmware.scpi.errors.push(ScpiError(-300, detail[:200]))

    def recover(self) -> None:
        """After a physics failure: restart the physics from rest (lock held).

        ScpiError -300 if the backend cannot restart (it has no ``restart_from_rest``, or that fails)."""
        if self.failure is None:
            return
        restart = getattr(self.backend, "restart_from_rest", None)
        if restart is None:
            raise ScpiError(-300, "physics stopped and this rig cannot restart it")
        try:
            restart()
        except Exception as exc:  # reported like the failure itself
            raise ScpiError(-300, f"physics restart failed: {type(exc).__name__}: {exc}"[:200]) from None
        self.failure = None
        self.log("rig", "recovered", "physics restarted from rest")

    def _run_clock(self) -> None:
        start_wall = time.monotonic()
        start_samples = self.samples
        while not self._stop.wait(CLOCK_TICK):
            due = start_samples + int((time.monotonic() - start_wall) * self.sample_rate)
            while due > self.samples and not self._stop.is_set() and self.failure is None:
                with self.lock:
                    self.advance(min(due - self.samples, self.shaker.chunk_limit()))
            if self.failure is not None:   # a restarted physics goes on from now, not with a burst
                start_wall, start_samples = time.monotonic(), self.samples

    def hold_for_commands(self) -> None:
        """Fast mode: wait until the host's commands are processed (lock held), so that they take effect at
        the same point of the physics however the threads are scheduled."""
        while self.commands_pending() and self.running:
            self.changed.wait(HOLD_POLL)

    # ----- links ---------------------------------------------------------------------------
    def connect(self, role: str, faults: LinkFaults | None = None) -> InstrumentLink:
        """Open the host side of instrument ``role`` (``"shaker"`` or ``"daq"``).

        Parameters
        ----------
        role : str
            Which instrument.
        faults : LinkFaults, optional
            Faults on this link; default: the rig's ``faults`` for that role.

        Raises
        ------
        LinkBusy
            The instrument already has an open link.
        """
        if role not in self.instruments:
            raise ValueError(f"no instrument {role!r}; this rig has {', '.join(ROLES)}")
        if not self.running:
            raise ConnectionError(f"emulated rig {self.name!r} is not running")
        with self.lock:
            if role in self._links:
                raise LinkBusy(f"{self.name}/{role} is already open")
            firmware = self.instruments[role]
            injector = FaultInjector(faults or self.default_faults[role], ROLES.index(role))
            link = InstrumentLink(firmware, injector, None if self.paced else firmware.produce, self._closed)
            firmware.injector = injector
            firmware.device_clear()
            try:
                self.recover()
            except ScpiError as exc:    # still reported: the error stays queued
                firmware.scpi.errors.push(exc)
            self._links[role] = link
            return link

    def inject(self, role: str, faults: Mapping[str, Any]) -> FaultInjector:
        """Replace the faults of ``role``'s open link from now on (e.g. in the middle of a stream).

        Parameters
        ----------
        role : str
            ``"shaker"`` or ``"daq"``.
        faults : mapping
            :class:`~drivers.faults.LinkFaults` fields; ``{}`` clears every fault.

        Returns
        -------
        FaultInjector
            The new injector (its counters tell what was injected).
        """
        with self.lock:
            link = self._links.get(role)
            if link is None:
                raise ConnectionError(f"{self.name}/{role} has no open link")
            injector = FaultInjector(LinkFaults().updated(faults, where="faults"), ROLES.index(role),
                                     start=link.injector.position)
            link.injector = injector
            link.firmware.injector = injector
            return injector

    def _closed(self, link: InstrumentLink) -> None:
        with self.lock:
            role = link.firmware.role
            if self._links.get(role) is link:
                del self._links[role]
                link.firmware.injector = None
                link.firmware.device_clear()   # nothing of this host's survives it
            if not self._links and not self.paced:
                self._come_to_rest()

    def _come_to_rest(self) -> None:
        """Fast mode, every host gone: no time passes until the next one, so give it what the minutes between
        two sessions give a real rig -- output off and the structure at rest -- rather than a structure still
        ringing from the last drive (lock held)."""
        self.shaker.switch_off("no host")
        restart = getattr(self.backend, "restart_from_rest", None)
        if restart is not None and self.failure is None:
            restart()
            self.log("rig", "rest", "no host connected: structure at rest")

    def log(self, instrument: str, kind: str, detail: str) -> None:
        """Record an event at the current emulated time (lock held by the caller)."""
        self.events.append(EmulatorEvent(self.time, instrument, kind, detail))

    def output_events(self) -> list[EmulatorEvent]:
        """The shaker's output on/off events, oldest first."""
        return [e for e in self.events if e.instrument == "shaker" and e.kind == "output"]
