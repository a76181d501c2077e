"""A campaign: a plan turned into measured FRFs through the driver interfaces, written to a session.

The runner talks only to a ``ShakerController`` and a ``Daq`` (drivers/interfaces.py) and a
:class:`~app.session.writer.SessionWriter`. The whole campaign runs inside one :class:`drivers.OutputGuard`: the output
starts off, is armed explicitly for each run, and is switched off on every way out -- end of run, abort, limit
breach, lost link, exception, signal. Every completed line is in the session before the next one starts;
every fault and operator action is in the session's event log.

The caller (command line or GUI worker thread) calls :meth:`Campaign.run`; another thread may call
:meth:`Campaign.pause`, :meth:`Campaign.resume` and :meth:`Campaign.abort`. Progress reaches a
:class:`CampaignListener` (all methods optional).
"""
from __future__ import annotations

import queue
import sys
import threading
import time
from contextlib import contextmanager
from dataclasses import dataclass, field

import numpy as np

from analysis.signals.drive_prediction import predicted_gain
from analysis.common.errors import InputError
from analysis.signals.frf_estimation import FRFEstimator
from analysis.common.measurements import CONTROL_UNITS
from drivers import AbortLimits, InstrumentError, LimitExceeded, OutputGuard
from drivers.errors import describe_instrument_error
from drivers.interfaces import Block

from app.campaign.acquisition import RecordFeed
from app.campaign.phase_resonance import LockedPoint, PhaseTrack, lock
from app.campaign.plan import PhaseSpec, Plan, RandomSpec, ResponseLevel, SineSpec
from app.session import RunSpec, SessionWriteError, SessionWriter
from app.campaign.stepped_sine import N_HARMONICS, HeldLevel, LineMeasurement, LineMeter, frf_change, next_step
from app.campaign.transient_line import TransientLines

BLOCK_SECONDS = 0.5           # longest DAQ frame/block: the abort limits are checked at least this often
BLOCK_POINTS = (64, 256)      # ...within these sizes (small frames cost throughput, large ones latency)
START_DRIVE = 0.05            # V peak: the first line of every sine run starts at most here...
START_FRACTION = 0.5          # ...or at this fraction of the drive the last gain predicts, if less (of the
                              # drive that held the same level at the same line earlier in the campaign, if any)
MISSED_FORCE = 0.05           # a line this far (relative) from its target (force or response) fails its run
UNSETTLED_SHARE = 0.5         # ...and so does a run with at least this share of lines at the settling limit
RAMP_OUT_PERIODS = 10         # the drive ramps to zero over this many periods of the last line before OFF


class CampaignAborted(RuntimeError):
    """The operator (or the application) aborted the campaign."""


class CampaignIncomplete(RuntimeError):
    """A campaign ended aborted or with a failed run, where a caller needs it complete (the demo)."""


class CampaignListener:
    """Progress callbacks; override what you need. Called from the campaign's thread."""

    def run_started(self, name: str, spec: RunSpec) -> None: ...
    def block(self, block: Block) -> None: ...
    def line(self, run: str, index: int, m: LineMeasurement, target_force: float) -> None: ...
    def random_result(self, run: str, frequency: np.ndarray, frf: dict, coherence: dict) -> None: ...
    def run_ended(self, run: str, status: str) -> None: ...
    def event(self, kind: str, message: str) -> None: ...
    def progress(self, done: int, total: int, eta_s: float | None, run: str) -> None: ...
    def lines_added(self, planned: int, added: int) -> None: ...   # refinement: total = planned + added
    def phase_point(self, run: str, index: int, point) -> None: ...   # a phase-resonance level locked


@dataclass
class CampaignSummary:
    runs: dict[str, str] = field(default_factory=dict)          # name -> status
    lines: int = 0
    worst_force_error: float = 0.0                              # relative, over all lines (force or response)
    control_tolerance: float = 0.01                             # relative: what the control loop holds
    lines_off_target: int = 0                                   # lines whose held level is outside the tolerance
    response_lines: int = 0                                     # lines that held a response amplitude
    unsteady_lines: int = 0
    transient_lines: int = 0                                    # measured from their transient fit
    shaker_seconds: float = 0.0                                 # DAQ time spent driving
    faults: int = 0
    samples_lost: int = 0
    aborted: str = ""
    aborted_by_instrument: bool = False                         # a link or instrument failure ended it
    failed: dict[str, str] = field(default_factory=dict)        # run -> why its data missed the plan
    session: str = ""                                           # where the session file is, once closed
    replaced: str = ""                                          # why an existing file was not replaced

    @property
    def complete(self) -> bool:
        """Every run measured as planned: not aborted, none failed."""
        return not self.aborted and not self.failed and all(s == "complete" for s in self.runs.values())

    def force_text(self) -> str:
        tolerance = f"{100 * self.control_tolerance:g} %"
        held = "force" if not self.response_lines else "force or response"
        if not self.lines_off_target:
            return f"{held} within {tolerance} of target at every line (worst {100 * self.worst_force_error:.2f} %)"
        return (f"{held} OFF TARGET at {self.lines_off_target} of {self.lines} line(s) (worst "
                f"{100 * self.worst_force_error:.2f} % from target, tolerance {tolerance})")

    def text(self) -> str:
        lines = [f"{name}: {status}" + (f" ({self.failed[name]})" if name in self.failed else "")
                 for name, status in self.runs.items()]
        lines.append(f"{self.lines} lines; {self.force_text()}; "
                     f"{self.unsteady_lines} line(s) measured at the settling limit; "
                     + (f"{self.transient_lines} from their transients; " if self.transient_lines else "")
                     + f"{self.shaker_seconds:.1f} s on the shaker")
        if self.faults or self.samples_lost:
            lines.append(f"{self.faults} fault(s) logged, {self.samples_lost} samples lost in transit")
        if self.aborted:
            lines.append(f"aborted: {self.aborted}")
        elif self.failed:
            lines.append(f"INCOMPLETE: {len(self.failed)} run(s) failed: their data missed the plan")
        return "\n".join(lines)


class Campaign:
    """Run a plan on a shaker controller and DAQ, writing a session.

    Parameters
    ----------
    plan : Plan
    shaker, daq : opened drivers (any transport).
    writer : SessionWriter
    excitation_dof : str
        DOF of the force gauge.
    sensor_dofs : list of str
        Accelerometer DOFs; the DAQ must have channels ``force`` and ``acc:<dof>`` for each.
    listener : CampaignListener, optional
    """

    def __init__(self, plan: Plan, shaker, daq, writer: SessionWriter, excitation_dof: str,
                 sensor_dofs: list[str], listener: CampaignListener | None = None):
        self.plan = plan
        self.shaker = shaker
        self.daq = daq
        self.writer = writer
        self.excitation_dof = excitation_dof
        self.sensor_dofs = list(sensor_dofs)
        self.listener = listener or CampaignListener()
        self.channels = ["force"] + [f"acc:{d}" for d in self.sensor_dofs]
        missing = [c for c in self.channels if c not in daq.channels]
        if missing:
            raise ValueError(f"the DAQ at {daq.url} has no channel(s) {', '.join(missing)} "
                             f"(it has {', '.join(daq.channels)})")
        self._check_held_dofs()
        fs = daq.sample_rate
        self.block = int(np.clip(2 ** np.floor(np.log2(BLOCK_SECONDS * fs)), *BLOCK_POINTS))
        daq.configure(frame_points=self.block)
        self.summary = CampaignSummary(control_tolerance=plan.control_tolerance)
        self._abort = threading.Event()
        self._abort_reason = ""
        self._paused = threading.Event()
        self._resume = threading.Event()
        self._events: queue.SimpleQueue = queue.SimpleQueue()
        self._guard: OutputGuard | None = None
        self._gain = None              # N per V, learnt as the campaign runs
        self._held_drives: dict[tuple, float] = {}   # (Hz, what is held) -> the drive that held it on target
        self._transient = self._transient_lines()   # poles carry over from run to run
        self._run_lines = _RunLines()
        self._total_lines = plan.planned_lines()
        self._done_lines = 0
        self._added_lines = 0          # lines refinement added to the plan so far (runs before this one)
        self._t_start = 0.0

    def _check_held_dofs(self) -> None:
        """A response level or a phase lock at a DOF no accelerometer measures is refused before anything is
        armed, naming the plan's field."""
        held = [(f"[[stepped_sine]][{i}].dof", s.response.dof) for i, s in enumerate(self.plan.sine)
                if s.response is not None]
        held += [(f"[[phase_resonance]][{i}].dof", p.dof) for i, p in enumerate(self.plan.phase)]
        for where, dof in held:
            if dof not in self.sensor_dofs:
                raise InputError(f"DOF {dof!r} carries no accelerometer (sensors: {', '.join(self.sensor_dofs)})",
                                 self.plan.source, where)

    # ------------------------------------------------------------------ control (any thread)
    def abort(self, reason: str = "operator abort") -> None:
        """Stop at once: the output goes off now, the run in progress is closed as aborted."""
        self._abort_reason = reason
        self._abort.set()
        self._resume.set()
        guard = self._guard
        if guard is not None:
            guard.trip(reason)

    def pause(self) -> None:
        """Switch the output off at the next record and wait; the current line is measured again on resume."""
        self._resume.clear()
        self._paused.set()

    def resume(self) -> None:
        self._paused.clear()
        self._resume.set()

    @property
    def paused(self) -> bool:
        return self._paused.is_set()

    # ------------------------------------------------------------------ main
    def run(self) -> CampaignSummary:
        """Run every run of the plan; returns the summary (also when aborted)."""
        self._t_start = time.monotonic()
        limits = AbortLimits(max_force=self.plan.limits.max_force,
                             max_acceleration=self.plan.limits.max_acceleration)
        try:
            with OutputGuard(self.shaker, limits=limits, on_event=self._safety_event) as guard:
                self._guard = guard
                if self._abort.is_set():
                    guard.trip(self._abort_reason)
                    raise CampaignAborted(self._abort_reason)
                if self.plan.random is not None:
                    self._random_run(guard, self.plan.random)
                for spec, direction in self.plan.runs:
                    self._sine_run(guard, spec, direction)
                for phase in self.plan.phase:
                    self._phase_run(guard, phase)
        except (CampaignAborted, LimitExceeded, InstrumentError, SessionWriteError) as exc:
            # the guard has switched the output off; the lines measured so far are in the session
            self.summary.aborted = self._describe(exc)
            self.summary.aborted_by_instrument = isinstance(exc, InstrumentError)
        finally:
            self._guard = None
            self._drain_events()
        return self.summary

    def _describe(self, exc: BaseException) -> str:
        """An abort reason in plain words; an instrument's failure names the instrument and its port."""
        if isinstance(exc, InstrumentError):
            return describe_instrument_error(exc, {self.shaker.url: "shaker", self.daq.url: "DAQ"})
        return str(exc)

    # ------------------------------------------------------------------ events
    def _safety_event(self, event) -> None:
        # may come from the port thread or a signal handler: queue it for the campaign thread
        self._events.put(("safety", f"{event.kind}: {event.detail}"))

    def _log(self, kind: str, message: str) -> None:
        self.listener.event(kind, message)
        try:
            self.writer.log(kind, message)
        except SessionWriteError as exc:           # the session is failing: say so, keep switching off
            self.listener.event("fault", str(exc))

    def _drain_events(self) -> None:
        while True:
            try:
                kind, message = self._events.get_nowait()
            except queue.Empty:
                return
            if kind == "fault":
                self.summary.faults += 1
            self._log(kind, message)

    def _on_gap(self, gap) -> None:
        self.summary.samples_lost += gap.samples
        self._events.put(("fault", f"DAQ {gap}: record restarted"))

    def _check(self, guard: OutputGuard):
        def check(block: Block) -> None:
            guard.check(block)
            if block.overload:
                self._events.put(("fault", f"DAQ overload (a channel at its range limit) at sample "
                                           f"{block.first_sample}"))
        return check

    def _interrupt(self, guard: OutputGuard) -> None:
        """Called at every record: abort, or pause (output off until resumed)."""
        self._drain_events()
        if self._abort.is_set():
            raise CampaignAborted(self._abort_reason)
        if self._paused.is_set():
            self.shaker.disarm()
            self._log("operator", "paused: output off")
            self._resume.wait()
            if self._abort.is_set():
                raise CampaignAborted(self._abort_reason)
            self._log("operator", "resumed: output on, the current line is measured again")
            guard.arm()
            raise _Restart

    def _progress(self, run: str, added: int = 0) -> None:
        """One more line done; ``added`` is how many lines refinement has added to the plan so far."""
        self._done_lines += 1
        if added != self._added_lines:
            self._added_lines = added
            self.listener.lines_added(self._total_lines, added)
        total = self._total_lines + added
        elapsed = time.monotonic() - self._t_start
        eta = elapsed / self._done_lines * max(total - self._done_lines, 0)
        self.listener.progress(self._done_lines, total, eta, run)

    # ------------------------------------------------------------------ random run
    def _random_run(self, guard: OutputGuard, spec: RandomSpec) -> None:
        name = "random"
        fs = self.daq.sample_rate
        welch = spec.welch()
        segment = int(round(fs / welch.resolution))           # the plan's resolution (docs/campaigns.md)
        run_spec = RunSpec(name, "random", spec.force_rms, "none", self.excitation_dof, self.sensor_dofs, fs,
                           list(self.daq.channels), list(self.daq.units), self._random_extras(),
                           {"band": list(spec.band), "duration": spec.duration, "segment_length": segment})
        with self._run(run_spec):
            if welch.limited_by_duration:
                self._log("note", f"random: resolution {fs / segment:.4g} Hz, coarser than the {welch.wanted:.4g} Hz "
                                  f"damping {spec.expected_damping:g} asks for: a {spec.duration:g} s run holds "
                                  f"{welch.averages} averages at most at that resolution")
            drive = self._noise_calibrate(guard, spec, fs)
            est = FRFEstimator(fs, segment)
            n_total = int(spec.duration * fs)
            idx = [self.daq.channels.index(c) for c in self.channels]
            got = 0
            with self.daq.stream(self.block) as stream:
                feed = RecordFeed(stream, self._check(guard), self._on_gap, self.listener.block)
                feed.skip(int(2.0 * fs))                         # let the response to the new level settle
                while got < n_total:
                    self._interrupt_random(guard)
                    rec = feed.record(min(segment, n_total - got))
                    data = rec.data[:, idx]
                    est.add_data(data[:, 0], data[:, 1:])
                    self.writer.append_raw(rec.data.astype(np.float32))
                    got += len(rec.data)
            self.summary.shaker_seconds += got / fs + 2.0
            self.shaker.disarm()
            self._write_random(est, spec, drive)
        self._progress(name, self._added_lines)

    def _interrupt_random(self, guard: OutputGuard) -> None:
        try:
            self._interrupt(guard)
        except _Restart:
            pass                         # a paused random run simply continues averaging

    def _random_extras(self) -> dict:
        extras = {}
        for kind, units in (("h2", "m/N"), ("hv", "m/N")):
            for d in self.sensor_dofs:
                extras[f"{kind}/{d}"] = (units, (), "c16")
        for d in self.sensor_dofs:
            extras[f"coherence/{d}"] = ("1", (), "f8")
            extras[f"random_error/{d}"] = ("1", (), "f8")
        extras["force_psd"] = ("N^2/Hz", (), "f8")
        return extras

    def _noise_calibrate(self, guard: OutputGuard, spec: RandomSpec, fs: float) -> float:
        """Find the noise drive (V rms) that gives the plan's force rms, starting low."""
        drive = min(0.02, self.shaker.amplitude_range[1] / 100)
        self.shaker.set_noise(drive, spec.band)
        guard.arm()
        self._log("operator", f"armed: random noise {spec.band[0]:g}-{spec.band[1]:g} Hz")
        for _ in range(6):
            with self.daq.stream(self.block) as stream:
                feed = RecordFeed(stream, self._check(guard), self._on_gap, self.listener.block)
                feed.skip(int(0.5 * fs))
                rec = feed.record(int(2.0 * fs))
            rms = float(np.std(rec.data[:, self.daq.channels.index("force")]))
            self.summary.shaker_seconds += 2.5
            if abs(rms / spec.force_rms - 1) < 0.05:
                break
            drive = float(min(drive * np.clip(spec.force_rms / max(rms, 1e-12), 0.1, 10.0),
                              self.shaker.amplitude_range[1]))
            self.shaker.set_noise(drive, spec.band)
        self._gain = rms / drive if drive > 0 else None
        self._log("control", f"random drive {drive:.4g} V rms for {rms:.4g} N rms (target {spec.force_rms:g} N)")
        return drive

    def _write_random(self, est: FRFEstimator, spec: RandomSpec, drive: float) -> None:
        f = est.frequency
        band = (f >= spec.band[0]) & (f <= spec.band[1]) & (f > 0)
        to_receptance = (-(2 * np.pi * f[band]) ** 2)[:, None]
        H1, H2, Hv = (est.get_H1()[band] / to_receptance, est.get_H2()[band] / to_receptance,
                      est.get_Hv()[band] / to_receptance)
        coh, err = est.get_coherence()[band], est.get_random_error()[band]
        arrays = {"frequency": f[band], "force_psd": est.get_force_autospectrum()[band]}
        for p, d in enumerate(self.sensor_dofs):
            arrays[f"frf/{d}"] = H1[:, p]
            arrays[f"h2/{d}"] = H2[:, p]
            arrays[f"hv/{d}"] = Hv[:, p]
            arrays[f"coherence/{d}"] = coh[:, p]
            arrays[f"random_error/{d}"] = err[:, p]
        self.writer.write_arrays(arrays)
        self._log("run", f"random: {est.n_averages} averages, drive {drive:.4g} V rms")
        self.listener.random_result("random", f[band], {d: H1[:, p] for p, d in enumerate(self.sensor_dofs)},
                                    {d: coh[:, p] for p, d in enumerate(self.sensor_dofs)})

    # ------------------------------------------------------------------ stepped sine
    def _sine_extras(self, response: ResponseLevel | None = None) -> dict:
        extras = {"force_amplitude": ("N", (), "f8"), "force_target": ("N", (), "f8"),
                  "force_phasor": ("N", (), "c16"), "force_phase": ("rad", (), "f8"),
                  "measured_frequency": ("Hz", (), "f8"),
                  "drive": ("V", (), "f8"), "settle_time": ("s", (), "f8"), "settle_periods": ("1", (), "f8"),
                  "steady": ("bool", (), "?"), "control_steps": ("1", (), "i4"),
                  "force_on_target": ("bool", (), "?"), "transient": ("bool", (), "?"),
                  "transient_std": ("1", (), "f8")}
        for d in self.sensor_dofs:
            extras[f"frf_std/{d}"] = ("m/N", (), "f8")
        for c, u in zip(self.channels, ["N"] + ["m/s^2"] * len(self.sensor_dofs)):
            extras[f"harmonics/{c}"] = (u, (N_HARMONICS + 1,), "c16")
            extras[f"thd/{c}"] = ("1", (), "f8")
        if response is not None:
            units = CONTROL_UNITS[response.quantity]
            extras["response_amplitude"] = (units, (), "f8")
            extras["response_target"] = (units, (), "f8")
        return extras

    def _control_attrs(self, spec: SineSpec) -> dict:
        """The run's control in the session's vocabulary (docs/session-format.md)."""
        control = spec.control(self.excitation_dof)
        return {"control": control.mode, "control_dof": control.dof, "control_quantity": control.quantity,
                "control_target": float(control.target), "control_units": control.units}

    def _sine_run(self, guard: OutputGuard, spec: SineSpec, direction: str) -> None:
        name = spec.run_name(direction)
        fs = self.daq.sample_rate
        # a response level's force is not known before it is measured: the force limit until the run closes
        # with the median of its lines' forces (_RunLines.closing_attrs)
        run_spec = RunSpec(name, "stepped_sine", spec.force, direction, self.excitation_dof, self.sensor_dofs, fs,
                           self.channels, ["N"] + ["m/s^2"] * len(self.sensor_dofs), self._sine_extras(spec.response),
                           {"start": spec.start, "stop": spec.stop, "step": spec.step, "refine": spec.refine,
                            **self._control_attrs(spec)})
        with self._run(run_spec):
            planned = spec.lines(direction)
            f, stop = planned[0], planned[-1]
            sign = 1.0 if direction == "up" else -1.0
            drive = self._start_drive(spec.force, self._held_drives.get(_line_key(f, _held(spec, 0))))
            self.shaker.set_sine(f, drive)
            guard.arm()
            self._log("operator", f"armed: {name}")
            step, previous, index = spec.step, None, 0
            gains: list[tuple[float, float]] = []     # (Hz, N/V) of this run's lines
            lines_drive: list[tuple[float, float]] = []   # (Hz, V) of this run's lines on target
            added_before = self._added_lines
            with self.daq.stream(self.block) as stream:
                feed = RecordFeed(stream, self._check(guard), self._on_gap, self.listener.block)
                meter = LineMeter(self.shaker, feed, list(self.daq.channels), self.sensor_dofs, fs,
                                  self.plan.settle, self.plan.control_tolerance, lambda: self._interrupt(guard),
                                  self._transient)
                while True:
                    m = self._measure(meter, f, _held(spec, index), drive)
                    drive = self._carry_drive(m)
                    self._gain = abs(m.force) / m.drive
                    gains.append((m.frequency, self._gain))
                    if m.on_target:
                        lines_drive.append((m.frequency, m.drive))
                        self._held_drives[_line_key(f, m.held)] = m.drive
                    self._store_line(name, index, m)
                    index += 1
                    self._progress(name, added_before + _added(planned, f, sign, index))
                    if sign * (f - stop) >= -1e-9 * abs(stop):
                        break
                    if spec.refine and previous is not None:
                        step = next_step(step, spec.step, spec.min_step, frf_change(m.frf, previous.frf))
                    previous = m
                    f_next = f + sign * step
                    f = stop if sign * (f_next - stop) > 0 else f_next
                    drive = self._response_drive(lines_drive, f, drive) if spec.response is not None else \
                        self._predicted_drive(gains, f, spec.line_target(index), drive)
                meter.ramp_out(f, m.drive, RAMP_OUT_PERIODS)
            self.shaker.disarm()
            self._judge(name, spec)

    # ------------------------------------------------------------------ phase resonance
    def _phase_extras(self) -> dict:
        """A phase-resonance point's quantities: a stepped-sine line's, and the lock's (docs/session-format.md)."""
        return {**self._sine_extras(),
                "phase_lag": ("deg", (), "f8"), "phase_error": ("deg", (), "f8"),
                "lock_iterations": ("1", (), "i4"), "lock_converged": ("bool", (), "?"),
                "shaker_time": ("s", (), "f8")}

    def _phase_run(self, guard: OutputGuard, spec: PhaseSpec) -> None:
        """Lock each force level of ``spec`` to its phase (app/campaign/phase_resonance.py), one point a level,
        within the same guard, settling and force control as a stepped-sine run."""
        name = spec.run_name()
        fs = self.daq.sample_rate
        run_spec = RunSpec(name, "phase_resonance", spec.forces[0], "up", self.excitation_dof, self.sensor_dofs, fs,
                           self.channels, ["N"] + ["m/s^2"] * len(self.sensor_dofs), self._phase_extras(),
                           {"start": spec.start, "phase_dof": spec.dof, "target_phase": spec.phase,
                            "phase_tolerance": spec.tolerance, "forces": list(spec.forces),
                            "control": "force", "control_dof": self.excitation_dof, "control_quantity": "force",
                            "control_target": float(spec.forces[0]), "control_units": "N"})
        with self._run(run_spec):
            f, drive = spec.start, self._start_drive(spec.forces[0])
            self.shaker.set_sine(f, drive)
            guard.arm()
            self._log("operator", f"armed: {name}")
            with self.daq.stream(self.block) as stream:
                feed = RecordFeed(stream, self._check(guard), self._on_gap, self.listener.block)
                meter = LineMeter(self.shaker, feed, list(self.daq.channels), self.sensor_dofs, fs,
                                  self.plan.settle, self.plan.control_tolerance, lambda: self._interrupt(guard))
                track = PhaseTrack()
                for index, force in enumerate(spec.forces):
                    point = lock(meter, spec, track, force, f, drive)
                    self._store_point(name, index, point)
                    f, drive = point.line.frequency, self._carry_drive(point.line)
                    drive = min(drive * spec.forces[min(index + 1, len(spec.forces) - 1)] / force,
                                self.shaker.amplitude_range[1])      # the next level's force, at the same N/V
                    self._progress(name, self._added_lines)
                meter.ramp_out(f, point.line.drive, RAMP_OUT_PERIODS)
            self.shaker.disarm()
            self._judge_locks(spec)

    def _judge_locks(self, spec: PhaseSpec) -> None:
        """Fail a phase-resonance run whose lock did not converge at a level, or whose force missed its target
        (docs/campaigns.md, "Complete or failed")."""
        judge = self._run_lines
        reasons = []
        unlocked = [f for f, locked in zip(spec.forces, judge.locked) if not locked]
        if unlocked:
            reasons.append(f"the phase lock did not converge at {len(unlocked)} of {len(spec.forces)} force "
                           f"level(s) ({', '.join(f'{x:g}' for x in unlocked)} N)")
        if judge.missed:
            reasons.append(f"force missed its target by more than {100 * MISSED_FORCE:g} % at {judge.missed} of "
                           f"{judge.lines} level(s)")
        if reasons:
            raise RunFailed("; ".join(reasons))

    def _store_point(self, name: str, index: int, point: LockedPoint) -> None:
        """A locked point as a line of the run, with the lock's convergence and the shaker time it took."""
        m = point.line
        self._write_line(m, lock_extras(point))
        self.summary.lines += 1
        self.summary.shaker_seconds += point.shaker_seconds
        self._run_lines.add(m, abs(m.level / m.held.target - 1) > MISSED_FORCE)
        self._run_lines.locked.append(point.converged)
        self._log("lock", f"{name}: {m.target_force:g} N locked at {m.frequency:.5g} Hz, lag {point.lag:.2f} deg "
                          f"(error {point.error:+.2f}) after {point.iterations} line(s), {point.shaker_seconds:.1f} s"
                          + ("" if point.converged else " -- NOT CONVERGED"))
        self.listener.phase_point(name, index, point)
        self.listener.line(name, index, m, m.target_force)

    def _transient_lines(self) -> TransientLines | None:
        """The transient-aware path's state for the whole campaign (``[settle] method = "transient"``)."""
        if self.plan.settle.method != "transient":
            return None
        channels = list(self.daq.channels)
        return TransientLines(self.daq.sample_rate, N_HARMONICS, self.plan.settle.tolerance,
                              channels.index("force"), [channels.index(f"acc:{d}") for d in self.sensor_dofs])

    def _start_drive(self, force: float, held_before: float | None = None) -> float:
        """The drive of a run's first line: low. A gain learnt at another frequency or level says little
        here (an electrodynamic shaker's N/V varies several times across a sweep), so the loop approaches
        the target from a level that cannot reach the abort limits (docs/campaigns.md). ``held_before``: the
        drive that held the same level at the same line earlier in the campaign (the other direction of a
        sweep), which does say: the run starts at START_FRACTION of it, as safe as any line's start (a line
        starts from the drive its neighbour needed) without the approach's corrections."""
        if held_before is not None:
            return min(START_FRACTION * held_before, self.shaker.amplitude_range[1])
        drive = min(START_DRIVE, self.shaker.amplitude_range[1] / 10)
        if self._gain:
            drive = min(drive, START_FRACTION * force / self._gain)
        return drive

    def _carry_drive(self, m: LineMeasurement) -> float:
        """The next line starts from this line's drive, rescaled when its held level (force or response)
        ended off target (x0.5..x2; a response level within its force limit)."""
        if m.on_target or abs(m.force) == 0 or m.level == 0:
            return m.drive
        ratio = float(np.clip(m.held.target / m.level, 0.5, 2.0))
        ratio = min(ratio, m.held.force_limit / abs(m.force))
        return min(m.drive * ratio, self.shaker.amplitude_range[1])

    def _predicted_drive(self, gains: list[tuple[float, float]], f: float, force: float, carried: float) -> float:
        """The transient-aware path's start drive: the force per volt at ``f`` predicted from the run's lines so
        far and the free response's poles (analysis/signals/drive_prediction.py), within x0.5..2 of the last line's --
        no further than one correction of the force loop could move it. A line measured from its transient
        takes a record or two once its force is on target, while a drive correction costs the latency of the
        command-to-data path and a new transient; the waiting paths keep the carried drive."""
        if self._transient is None or not gains:
            return carried
        gain = predicted_gain([g[0] for g in gains], [g[1] for g in gains], self._transient.poles, f)
        if gain is None:                         # (also where a gain so far is not positive)
            return carried
        last = gains[-1][1]
        gain = float(np.clip(gain, 0.5 * last, 2.0 * last))
        return float(min(force / gain, self.shaker.amplitude_range[1]))

    def _response_drive(self, lines: list[tuple[float, float]], f: float, carried: float) -> float:
        """A response level's start drive at ``f``: extrapolated from the drives its last lines on target
        needed. At one response amplitude the structure is quasi-linear, so the force it needs is |Z(w)| times
        the amplitude, smooth in frequency: the square of the drive is taken as quadratic in frequency through
        the last three lines (linear through two). Starting from the last line's drive instead, a hardening
        structure past its resonance fell to the low branch, the loop doubled the drive, the response jumped
        to the high branch, and the loop swung between the two. Within x0.5..x2 of the carried drive."""
        if len(lines) < 2:
            return carried
        f_k, v_k = np.array(lines[-3:]).T
        squared = float(np.polyval(np.polyfit(f_k, v_k ** 2, len(f_k) - 1), f))
        if not np.isfinite(squared) or squared <= 0:
            return carried
        return float(min(np.clip(np.sqrt(squared), 0.5 * carried, 2.0 * carried), self.shaker.amplitude_range[1]))

    def _judge(self, name: str, spec: SineSpec) -> None:
        """Fail a run whose data missed the plan (docs/campaigns.md, "Complete or failed")."""
        judge = self._run_lines
        reasons = []
        if judge.missed:
            what = f"force missed its {spec.force:g} N" if spec.response is None else \
                f"response missed its {spec.response.text()}"
            reasons.append(f"{what} target by more than {100 * MISSED_FORCE:g} % at "
                           f"{judge.missed} of {judge.lines} line(s)")
        if judge.lines and judge.unsteady >= UNSETTLED_SHARE * judge.lines:
            reasons.append(f"{judge.unsteady} of {judge.lines} line(s) hit the settling limit")
        if reasons:
            raise RunFailed("; ".join(reasons))

    def _measure(self, meter: LineMeter, f: float, held: HeldLevel, drive: float) -> LineMeasurement:
        while True:
            try:
                return meter.measure(f, held, drive)
            except _Restart:
                continue

    def _write_line(self, m: LineMeasurement, more: dict | None = None) -> None:
        """A line into the session: frequency, FRFs, its per-line quantities (and ``more`` of them), raw samples."""
        extras = line_extras(m, m.target_force, list(self.daq.channels), self.channels, self.sensor_dofs)
        raw = m.raw[:, [self.daq.channels.index(c) for c in self.channels]].astype(np.float32)
        self.writer.append_line(m.frequency, stored_frf(m.frf), {**extras, **(more or {})}, raw)

    def _store_line(self, name: str, index: int, m: LineMeasurement) -> None:
        target = m.target_force
        self._write_line(m)
        error = abs(m.level / m.held.target - 1)
        self.summary.lines += 1
        self.summary.response_lines += int(m.held.response)
        self.summary.worst_force_error = max(self.summary.worst_force_error, error)
        self.summary.lines_off_target += int(not m.on_target)
        self.summary.unsteady_lines += int(not m.steady)
        self.summary.transient_lines += int(m.transient)
        self.summary.shaker_seconds += m.settle_time
        self._run_lines.add(m, error > MISSED_FORCE)
        if not m.steady:
            self._log("settle", f"{name}: {m.frequency:.4f} Hz measured at the settling limit "
                                f"({m.settle_periods:.0f} periods)")
        if m.transient_reason:
            self._log("settle", f"{name}: {m.frequency:.4f} Hz waited for the transient: {m.transient_reason}")
        if not m.on_target:
            self._log("control", f"{name}: {m.frequency:.4f} Hz: {_held_text(m)} "
                                 f"({100 * (m.level / m.held.target - 1):+.2f} %, tolerance "
                                 f"{100 * self.plan.control_tolerance:g} %)")
        for dof in unresolved(m.frf):
            self._log("settle", f"{name}: {m.frequency:.4f} Hz: no signal on acc:{dof} (below one count): "
                                f"its FRF is stored as NaN, not as 0")
        self.listener.line(name, index, m, target)

    # ------------------------------------------------------------------ runs
    @contextmanager
    def _run(self, spec: RunSpec):
        """Open the run in the session for the ``with`` body; close it as complete when the body finishes,
        else as aborted with the reason (abort message, or the exception's type and text), and re-raise."""
        self.writer.begin_run(spec)
        self.listener.run_started(spec.name, spec)
        self._run_lines = _RunLines()
        status, reason = "aborted", ""
        try:
            yield
            status = "complete"
        except RunFailed as exc:
            status, reason = "failed", str(exc)
            self.summary.failed[spec.name] = reason
        except CampaignAborted as exc:
            reason = str(exc)
            raise
        except Exception as exc:
            reason = self._describe(exc) if isinstance(exc, InstrumentError) else f"{type(exc).__name__}: {exc}"
            raise
        except BaseException as exc:
            reason = _stop_words(exc)
            raise
        finally:
            stop = sys.exc_info()[1]
            self._drain_events()
            try:
                self.writer.end_run(status, reason, self._run_lines.closing_attrs(spec))
            except SessionWriteError as exc:
                if not asked_to_stop(stop):
                    raise
                stop.add_note(f"the run could not be closed in the session: {exc}")
            self.summary.runs[spec.name] = status
            self.listener.run_ended(spec.name, status)


def _stop_words(exc: BaseException) -> str:
    """A stop asked for, as a run's end reason."""
    if isinstance(exc, KeyboardInterrupt):
        return "interrupted by Ctrl-C"
    if isinstance(exc, SystemExit):
        return f"stopped, exit status {exc.code}"
    return type(exc).__name__


def asked_to_stop(exc: BaseException | None) -> bool:
    """Whether ``exc`` is a stop the user or the system asked for (Ctrl-C, SIGTERM's SystemExit): it reaches the
    command as what it is (exit 130, 143) whatever its cleanup meets, which it carries as a note. An error's
    cleanup failing in the file is news of its own and replaces it (the campaign reports the session's failure)."""
    return exc is not None and not isinstance(exc, Exception)


def lock_extras(point: LockedPoint) -> dict:
    """What a phase-resonance point stores beside its line's quantities (docs/session-format.md); the GUI's live
    view records the same."""
    return {"phase_lag": point.lag, "phase_error": point.error, "lock_iterations": point.iterations,
            "lock_converged": point.converged, "shaker_time": point.shaker_seconds}


def _held_text(m: LineMeasurement) -> str:
    """A line's held level against its target, for the event log."""
    if not m.held.response:
        return f"force {abs(m.force):.4g} N, target {m.held.target:g} N"
    units = CONTROL_UNITS[m.held.quantity]
    limit = " (at the force limit)" if abs(m.force) >= 0.999 * m.held.force_limit else ""
    return (f"{m.held.quantity} at {m.held.dof} {m.level:.4g} {units}, target {m.held.target:g} {units}; "
            f"force {abs(m.force):.4g} N{limit}")


def _line_key(frequency: float, held: HeldLevel) -> tuple:
    """A line and what it holds, as a key: the same generator frequency (to 1e-9) and the same target."""
    return round(frequency, 9), held.quantity, held.dof, held.target


def _held(spec: SineSpec, index: int) -> HeldLevel:
    """What line ``index`` of a stepped-sine run holds: the force (drifting around its level where the plan asks,
    ``SineSpec.line_target``), or a response amplitude within a force limit."""
    if spec.response is None:
        return HeldLevel(spec.line_target(index))
    r = spec.response
    return HeldLevel(r.target, r.quantity, r.dof, r.force_limit)


def line_extras(m: LineMeasurement, target: float, daq_channels: list[str], channels: list[str],
                sensor_dofs: list[str]) -> dict:
    """The per-line quantities a stepped-sine line stores besides its frequency and FRF, by their names in the
    session (docs/session-format.md); ``daq_channels`` orders ``m.harmonics`` and ``m.thd``, ``channels`` are
    the ones recorded. The GUI's live view builds the same record from the listener's lines."""
    extras = {"force_amplitude": abs(m.force), "force_target": target, "force_phasor": m.force,
              "force_phase": float(np.angle(m.force)),
              "measured_frequency": m.measured_frequency, "drive": m.drive, "settle_time": m.settle_time,
              "settle_periods": m.settle_periods, "steady": m.steady, "control_steps": m.control_steps,
              "force_on_target": m.on_target, "transient": m.transient, "transient_std": m.transient_std}
    for d in sensor_dofs:
        extras[f"frf_std/{d}"] = m.frf_std[d] if m.frf[d] != 0 else np.nan
    for i, c in enumerate(daq_channels):
        if c in channels:
            extras[f"harmonics/{c}"] = m.harmonics[:, i]
            extras[f"thd/{c}"] = m.thd[i]
    if m.held.response:
        extras["response_amplitude"] = m.level
        extras["response_target"] = m.held.target
    return extras


def _added(planned: list[float], f: float, sign: float, measured: int) -> int:
    """Lines refinement added to a run: measured so far beyond the planned lines passed (up to ``f``)."""
    passed = sum(1 for p in planned if sign * (p - f) <= 1e-9 * abs(f))
    return max(measured - passed, 0)


def stored_frf(frf: dict) -> dict:
    """The FRFs as stored: a sensor that saw nothing (exactly 0, below one count) is NaN, never a value."""
    return {d: (complex(np.nan, np.nan) if h == 0 else h) for d, h in frf.items()}


def unresolved(frf: dict) -> list[str]:
    """Sensors whose fundamental is exactly 0: below the DAQ's resolution, nothing was measured."""
    return [d for d, h in frf.items() if h == 0]


@dataclass
class _RunLines:
    """What the lines of the run in progress say about it."""

    lines: int = 0
    missed: int = 0          # held level off target by more than MISSED_FORCE
    unsteady: int = 0        # at the settling limit
    forces: list[float] = field(default_factory=list)    # N, measured at each line
    locked: list[bool] = field(default_factory=list)     # phase resonance: whether each level's lock converged

    def add(self, m: LineMeasurement, missed: bool) -> None:
        self.lines += 1
        self.missed += int(missed)
        self.unsteady += int(not m.steady)
        self.forces.append(abs(m.force))

    def closing_attrs(self, spec: RunSpec) -> dict:
        """Run attributes set when the run closes: a response-controlled run's ``force`` becomes the median of
        its lines' measured forces (older readers get a sensible level)."""
        if spec.attrs.get("control") != "response" or not self.forces:
            return {}
        return {"force": float(np.median(self.forces))}


class RunFailed(Exception):
    """Internal: the run ended, but its data missed the plan (closed with status "failed")."""


class _Restart(Exception):
    """Internal: measure the current line again (after a pause)."""
