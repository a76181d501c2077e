"""What a running campaign tells the window, and how it crosses from the campaign's thread to the GUI thread.

- :class:`SignalRing`: the last seconds of every DAQ channel. The campaign thread writes each block into it
  (a copy under a lock, nothing else: the acquisition never waits for the window); the GUI reads the tail at
  its frame rate.
- :class:`CampaignFeed`: the campaign's listener. Blocks go to the ring; lines, runs, events and progress
  (a few per second at most) become Qt signals, queued to the GUI thread.
- :class:`LiveSession`: the lines received so far, kept in the GUI thread and readable like a session file
  (``runs()`` gives :class:`app.session.writer.RunData`), so the live identification goes through the same
  :func:`app.session.data.measurements_from_session` as a file does. The window never opens the file its own
  campaign is writing: HDF5 refuses the writer's reopen while a reader in the same process holds the file.
"""
from __future__ import annotations

import json
import threading
from dataclasses import dataclass, field

import numpy as np
from PySide6.QtCore import QObject, Signal

from drivers.interfaces import Block

from app.campaign import CampaignListener, LineMeasurement, line_extras, lock_extras
from app.session import RunData, RunSpec


ALARM_COLOR = "#d62728"
ALARM_SAFETY = ("trip", "fault", "unconfirmed", "emergency")


def is_alarm(kind: str, message: str) -> bool:
    """Whether a campaign event needs the operator's attention: a fault, or the safety guard tripping or
    failing to confirm the output off (its routine on/off records do not)."""
    return kind == "fault" or (kind == "safety" and message.startswith(ALARM_SAFETY))


@dataclass
class LinkCounters:
    """Stream health seen by the window since the campaign started (samples are per channel)."""

    blocks: int = 0
    samples: int = 0
    lost_samples: int = 0
    gaps: int = 0
    overloads: int = 0
    faults: int = 0


class SignalRing:
    """The last ``seconds`` of every channel of the DAQ stream.

    Parameters
    ----------
    channels, units : sequence of str
        DAQ channel names and units, in column order.
    sample_rate : float
        Hz.
    seconds : float
        Length kept, s.
    """

    def __init__(self, channels, units, sample_rate: float, seconds: float = 8.0):
        self.channels = tuple(channels)
        self.units = tuple(units)
        self.sample_rate = float(sample_rate)
        self.capacity = max(int(seconds * sample_rate), 16)
        self._data = np.full((self.capacity, len(self.channels)), np.nan)
        self._end = 0                     # index of the sample after the newest one, counted since the start
        self._lock = threading.Lock()
        self.counters = LinkCounters()

    def push(self, block: Block) -> None:
        """Copy a block in (campaign thread)."""
        n = len(block)
        data = block.data[-self.capacity:]
        with self._lock:
            c = self.counters
            c.blocks += 1
            c.samples += n
            c.lost_samples += block.lost_samples
            c.gaps += len(block.gaps)
            c.overloads += int(block.overload)
            first = block.first_sample
            if first < self._end or first - self._end >= self.capacity:
                self._data[:] = np.nan       # a new stream (its count restarts) or a gap longer than the ring
            elif first > self._end:
                self._data[np.arange(self._end, first) % self.capacity] = np.nan   # lost samples: a break
            end = first + n
            self._data[np.arange(end - len(data), end) % self.capacity] = data
            self._end = end

    def tail(self, n: int) -> tuple[np.ndarray, np.ndarray]:
        """The newest ``n`` samples (fewer at the start): times (s since the stream started), shape (m,), and
        data, shape (m, channels)."""
        with self._lock:
            end = self._end
            m = int(min(n, self.capacity, end))
            idx = np.arange(end - m, end) % self.capacity
            data = self._data[idx]
        return np.arange(end - m, end) / self.sample_rate, data

    @property
    def end(self) -> int:
        """Samples received so far (the stream's sample count of the newest one, plus one)."""
        with self._lock:
            return self._end

    def health(self) -> LinkCounters:
        with self._lock:
            c = self.counters
            return LinkCounters(c.blocks, c.samples, c.lost_samples, c.gaps, c.overloads, c.faults)

    def count_fault(self) -> None:
        with self._lock:
            self.counters.faults += 1


class FeedSignals(QObject):
    """The campaign's news as Qt signals (emitted in the campaign thread, delivered in the GUI thread)."""

    runStarted = Signal(str, object)                      # run name, RunSpec
    lineMeasured = Signal(str, int, object, float)        # run, index, LineMeasurement, target force N
    pointLocked = Signal(str, int, object)                # run, index, LockedPoint (phase resonance)
    randomMeasured = Signal(str, object, object, object)  # run, frequency Hz, {dof: H1}, {dof: coherence}
    runEnded = Signal(str, str)                           # run, status
    eventLogged = Signal(str, str)                        # kind, message
    progressed = Signal(int, int, object, str)            # lines done, total, ETA s or None, run


class CampaignFeed(CampaignListener):
    """The campaign listener of the window (see module docstring).

    Create it in the GUI thread: ``signals`` then belongs to the GUI thread and every emission from the
    campaign's thread is queued there.
    """

    def __init__(self, ring: SignalRing):
        self.ring = ring
        self.signals = FeedSignals()

    def run_started(self, name, spec):
        self.signals.runStarted.emit(name, spec)

    def block(self, block):
        self.ring.push(block)

    def line(self, run, index, m, target_force):
        self.signals.lineMeasured.emit(run, index, m, float(target_force))

    def phase_point(self, run, index, point):
        self.signals.pointLocked.emit(run, index, point)

    def random_result(self, run, frequency, frf, coherence):
        self.signals.randomMeasured.emit(run, frequency, frf, coherence)

    def run_ended(self, run, status):
        self.signals.runEnded.emit(run, status)

    def event(self, kind, message):
        if is_alarm(kind, message):
            self.ring.count_fault()
        self.signals.eventLogged.emit(kind, message)

    def progress(self, done, total, eta_s, run):
        self.signals.progressed.emit(int(done), int(total), eta_s, run)


@dataclass
class LiveRun:
    """The lines of one run received so far (GUI thread)."""

    spec: RunSpec
    status: str = "running"
    frequency: list[float] = field(default_factory=list)
    frf: dict[str, list[complex]] = field(default_factory=dict)
    arrays: dict[str, list] = field(default_factory=dict)

    def add(self, key: str, value) -> None:
        self.arrays.setdefault(key, []).append(value)


class LiveSession:
    """The campaign's runs as they arrive, readable like a session (``runs()``, ``run_names()``).

    Each line is recorded as the campaign stores it (:func:`app.campaign.engine.line_extras`), so the per-line
    quantities carry the session file's names (docs/session-format.md).

    Parameters
    ----------
    daq_channels : sequence of str
        The DAQ's channels, in the order of a line's harmonics and THD.
    """

    def __init__(self, daq_channels):
        self.daq_channels = list(daq_channels)
        self._runs: dict[str, LiveRun] = {}

    def begin(self, name: str, spec: RunSpec) -> None:
        self._runs[name] = LiveRun(spec, frf={d: [] for d in spec.sensor_dofs})

    def add_line(self, name: str, m: LineMeasurement, target_force: float) -> None:
        run = self._runs[name]
        run.frequency.append(m.frequency)
        for d in run.spec.sensor_dofs:
            run.frf[d].append(m.frf[d])
        for key, value in line_extras(m, target_force, self.daq_channels, run.spec.raw_channels,
                                      run.spec.sensor_dofs).items():
            run.add(key, value)

    def add_point(self, name: str, index: int, point) -> None:
        """A phase-resonance point's lock quantities (its line comes as any line, :meth:`add_line`)."""
        for key, value in lock_extras(point).items():
            self._runs[name].add(key, value)

    def add_random(self, name: str, frequency, frf: dict, coherence: dict) -> None:
        run = self._runs[name]
        run.frequency = list(frequency)
        run.frf = {d: list(h) for d, h in frf.items()}
        run.arrays = {f"coherence/{d}": list(c) for d, c in coherence.items()}

    def end(self, name: str, status: str) -> None:
        if name in self._runs:
            self._runs[name].status = status

    def run_names(self) -> list[str]:
        return list(self._runs)

    def run(self, name: str) -> RunData:
        live = self._runs[name]
        spec = live.spec
        attrs = {**spec.attrs, "kind": spec.kind, "force": float(spec.force), "direction": spec.direction,
                 "status": live.status, "excitation_dof": spec.excitation_dof,
                 "sensor_dofs": json.dumps(list(spec.sensor_dofs)), "sample_rate": float(spec.sample_rate)}
        return RunData(name, attrs, np.asarray(live.frequency, float),
                       {d: np.asarray(h, complex) for d, h in live.frf.items()},
                       {k: np.asarray(v) for k, v in live.arrays.items()}, {}, False)

    def runs(self) -> list[RunData]:
        return [self.run(n) for n in self._runs]

    @property
    def lines(self) -> int:
        """Stepped-sine lines received so far."""
        return sum(len(r.frequency) for r in self._runs.values() if r.spec.kind == "stepped_sine")

    def snapshot(self) -> "SessionSnapshot":
        """A frozen copy (arrays) that a worker thread may read while lines keep arriving."""
        return SessionSnapshot(self.runs())


class SessionSnapshot:
    """Runs frozen at one moment, with the ``runs()`` a session has."""

    def __init__(self, runs: list[RunData]):
        self._runs = list(runs)

    def runs(self) -> list[RunData]:
        return list(self._runs)
