"""One stepped-sine line: closed-loop force control, steady-state detection, harmonics and the FRF.

At each line the drive runs at the line's frequency and records of ``block_periods`` whole periods are taken
one after another. Each record gives, per channel, the harmonics by least squares at the frequency fitted on
the force channel (IEEE 1057 sine fit: it also absorbs a DAQ clock that differs from the generator's by some
ppm). Then:

- **steady state**: a line is steady when successive records agree -- every FRF and the force magnitude
  within ``tolerance`` relative -- and the decay seen over the last three records says the rest of the
  transient is within the tolerance too (or the change is down at the noise of the estimate); not after a
  fixed number of cycles. ``max_periods`` bounds the wait; a line measured at that bound is recorded with
  ``steady = False``.
- **transient-aware** (``[settle] method = "transient"``): app/transient_line.py may estimate the steady state
  from the records while they still hold the transient; an accepted estimate counts as a settled record for
  everything below, a refused one leaves the line to the steady-state check.
- **force control**: the drive voltage is scaled by target / measured (x0.5 .. x2 per step, within the
  generator's range) once the line is steady and its force is off by more than ``control_tolerance`` (1 %);
  before it settles when the force is more than COARSE_ERROR off and its level is known (the approach from
  a low start); and at the settling limit, LIMIT_RETRIES times. After each change the loop waits until the
  data show it (:meth:`LineMeter._await_change`): samples from before the change still arrive for a while
  (tens of seconds of them from a fast emulator over TCP), and records are measured -- counted by the
  fixed-count practice, corrected on by the loop -- only from after the one that shows it. A voltage-driven
  shaker loses force at resonance, and kbar only means something at a stated force. The instrument ramps the
  amplitude, so the drive never jumps.
- **response control** (a :class:`HeldLevel` of a response quantity): the same loop, settling and safety rules
  hold the fundamental amplitude of a displacement, velocity or acceleration at a sensor DOF. The drive is
  scaled by (target / measured)^(1/s), ``s`` the secant slope d log(response) / d log(drive) between the
  line's last two levels (1 before there are two: the response is proportional to the drive on a linear
  structure), which converges where the structure's |X/F| moves with the amplitude (a joint that softens),
  and never beyond the level's force limit (predicted from the measured N/V).

The FRF is the receptance ``h_p = A_p / (-(2 pi f)^2 F)`` from the accelerometer and force fundamentals; its
standard deviation combines the residual noise of the fit (a complex amplitude from N samples with white
noise of rms s has ``E|dY|^2 = 4 s^2 / N``) with what settling leaves: the last record-to-record change,
relative (without it a noise-free measurement would claim a precision its transient does not allow).
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from analysis.signals.harmonics import HarmonicProjector, harmonics_at, sine_fit, total_harmonic_distortion
from analysis.signals.phasor_sequence import fit_sequence

from analysis.common.measurements import response_amplitude

from app.campaign.acquisition import RecordFeed
from app.campaign.plan import SettleSpec
from app.campaign.transient_line import TransientEstimate, TransientLines

N_HARMONICS = 5
MAX_LATENCY_S = 10.0     # a generator change not seen in the data after this long (stream and wall time) is a
                         # fault of the set-up
FORCE_AGREEMENT = 0.05   # three records whose force magnitudes agree this well (relative) tell the force level
TONE_TOLERANCE = 1e-3    # ...if the force's fitted frequency is the line's within this (relative)
COARSE_ERROR = 0.2       # a force this far off target (relative) is corrected before the FRFs settle
LIMIT_RETRIES = 2        # corrections of a force still off target at the settling limit, per line
MIN_RAMP_RATE = 1e-3     # V/s: the slowest ramp asked of a generator (SCPI instruments' usual lower limit)
MAX_CONTROL_STEPS = 20   # drive corrections per line at most (a loop that cannot converge must still end)
CHANGE_MARGIN_PERIODS = 3.0   # skipped after an amplitude change has shown and its ramp, before a line waits
SECANT_SLOPES = (0.25, 4.0)   # d log(response) / d log(drive) the response loop believes (a noisy secant
                              # outside them would send the drive far off)


@dataclass(frozen=True)
class HeldLevel:
    """What the control loop holds at a line: the force amplitude (``quantity`` "force", N) or the fundamental
    amplitude of a response ``quantity`` at the sensor ``dof`` (m, m/s or m/s^2), with a force limit (N) the
    response loop never drives beyond."""

    target: float
    quantity: str = "force"
    dof: str = ""
    force_limit: float = float("inf")

    @property
    def response(self) -> bool:
        return self.quantity != "force"


@dataclass
class LineMeasurement:
    """Everything measured at one line.

    Attributes
    ----------
    frequency : float
        Generator frequency, Hz.
    measured_frequency : float
        Frequency fitted on the force channel, Hz (DAQ time base).
    force : complex
        Fundamental of the force, N (sine convention).
    frf, frf_std : dict dof -> complex / float
        Receptance and its standard deviation, m/N.
    harmonics : ndarray, shape (N_HARMONICS + 1, channels), complex
        Mean and harmonics of every channel, channel units.
    thd : ndarray, shape (channels,)
    drive : float
        Drive amplitude at the end of the line, V peak.
    settle_time, settle_periods : float
        Time (s, DAQ clock) and periods from the start of the line to the measurement.
    steady : bool
    control_steps : int
        Drive corrections made at this line.
    raw : ndarray, shape (n, channels)
        The samples of the two records that agreed (the measurement and the one before it).
    target_force : float
        N, the force the line was to hold (NaN where it held a response amplitude).
    on_target : bool
        Whether the held amplitude (force or response) is within the control tolerance of its target.
    transient : bool
        Measured by the transient-aware estimate (``[settle] method = "transient"``), not by waiting.
    transient_std : float
        Largest relative standard deviation of the FRFs by the line's last transient fit (NaN: none made).
    transient_reason : str
        Why a line of the transient-aware method waited ("" where it did not, or the method is "steady").
    held : HeldLevel or None
        What the loop held (None: the force ``target_force``).
    level : float
        The held amplitude as measured (the force's for force control), in the held quantity's units.
    """

    frequency: float
    measured_frequency: float
    force: complex
    frf: dict
    frf_std: dict
    harmonics: np.ndarray
    thd: np.ndarray
    drive: float
    settle_time: float
    settle_periods: float
    steady: bool
    control_steps: int
    raw: np.ndarray
    target_force: float
    on_target: bool
    transient: bool = False
    transient_std: float = float("nan")
    transient_reason: str = ""
    held: HeldLevel | None = None
    level: float = float("nan")

    def __post_init__(self):
        if self.held is None:
            self.held = HeldLevel(self.target_force)
        if np.isnan(self.level):
            self.level = abs(self.force)


class LineMeter:
    """Measures lines one after another on a running stream (the structure's state carries over)."""

    def __init__(self, shaker, feed: RecordFeed, channels: list[str], sensor_dofs: list[str], sample_rate: float,
                 settle: SettleSpec, control_tolerance: float, should_stop=lambda: None,
                 transient: TransientLines | None = None):
        self.shaker = shaker
        self.feed = feed
        self.force_index = channels.index("force")
        self.sensor_index = [channels.index(f"acc:{d}") for d in sensor_dofs]
        self.sensor_dofs = sensor_dofs
        self.sample_rate = sample_rate
        self.settle = settle
        self.control_tolerance = control_tolerance
        self.should_stop = should_stop         # raises to interrupt (pause/abort); called at every record
        self.v_max = shaker.amplitude_range[1]
        self.latency = 0                       # samples from a generator command to data that show it
        self._frequency: float | None = None   # generator frequency of the last line
        self._projector = None                 # ((frequency, n), HarmonicProjector) of the current line
        self.transient = transient             # the transient-aware path's state, None: wait (method "steady")
        self._channels = channels
        self._held = HeldLevel(0.0)            # what the line in progress holds
        self._levels: list[tuple[float, float]] = []   # (drive, held amplitude) of the line's known levels

    def _set_drive(self, frequency: float, drive: float, previous: float | None) -> None:
        """Change the generator amplitude, then drop the samples taken before it acted (the learnt latency of
        the command-to-data path) and those of its amplitude ramp."""
        self.feed.stream.sync()    # the samples before the change all in: the change lands at a known sample
        self.shaker.set_sine(frequency, drive)
        self.feed.flush()
        ramp_s = self._ramp_seconds(drive, previous)
        self.feed.skip(self.latency + int(np.ceil((ramp_s + 3.0 / frequency) * self.sample_rate)))

    def _await_level(self, frequency: float, n_rec: int, force: complex, drive: float, previous: float) -> None:
        """After the drive was scaled from ``previous`` to ``drive`` V at a level that gave ``force``, wait
        until the data show the change, as :meth:`_new_line` waits for a new frequency: records whose force is
        still the old one were sampled before the instrument acted (a socket or FIFO can hold seconds of them,
        a fast emulator over TCP tens of seconds), and a loop correcting on them doubles the drive again and
        again -- the first-line overshoots of the force limit. Then the instrument's ramp is skipped once more,
        counted from the record that showed the change: only records that provably follow it are measured."""
        def shows(data: np.ndarray) -> bool:
            now = abs(self._analyse(data, frequency, fit_frequency=False).force)
            return self._moved(abs(force), now, drive / previous)

        self._await_change(n_rec, shows)
        margin = self._margin_periods() / frequency
        self.feed.skip(int(np.ceil((self._ramp_seconds(drive, previous) + margin) * self.sample_rate)))

    def _margin_periods(self) -> float:
        """Periods skipped after an amplitude change and its ramp: CHANGE_MARGIN_PERIODS where the line will
        wait (its settling check starts clear of the change), none where the transient fit may take the
        records (poles known, no harmonics shown at this line): what follows the ramp is the new forced
        response plus a free response, the fit's model, and the ramp began before the end of the record that
        showed it. (A line whose fit is refused then waits as any other: its settling check needs records
        that agree.)"""
        fitting = self.transient is not None and self.transient.fitting
        return 0.0 if fitting else CHANGE_MARGIN_PERIODS

    def _await_change(self, n_rec: int, shows: Callable[[np.ndarray], bool]) -> None:
        """Read records until one shows the last generator change (``shows(data)``) and drop that one too: the
        change happened before it ends, but maybe in its middle. Records read before it were sampled before the
        instrument acted; their samples update the learnt latency.

        How many there are is for the path between converter and program to say, not for a clock: a fast
        emulator served over TCP runs ahead of the host by whatever the socket buffers hold (measured: 47 s of
        paper-2dof's stream), a real instrument by its FIFO. So the wait gives up only when both
        MAX_LATENCY_S of stream and MAX_LATENCY_S of wall time went by without the change (:class:`ChangeWait`);
        giving up after so much stream alone measured those stale records as the new state."""
        waited = ChangeWait(self.sample_rate)
        while not waited.expired():
            self.should_stop()
            rec = self.feed.record(n_rec)
            if shows(rec.data):
                break
            waited.add(len(rec.data))
        self.latency = max(self.latency, waited.samples)

    @staticmethod
    def _moved(before: float, now: float, ratio: float) -> bool:
        """Whether a force went at least half the way (in log) a drive change by ``ratio`` should take it, in
        the direction it should (a stale record that happens to read low is no sign of a larger drive)."""
        if before <= 0 or now <= 0:
            return now > 0 and ratio > 1
        return np.log(now / before) * np.sign(np.log(ratio)) >= 0.5 * abs(np.log(ratio))

    def _ramp_seconds(self, drive: float, previous: float | None) -> float:
        """How long the instrument ramps from ``previous`` to ``drive`` V (0 for one that does not ramp)."""
        return abs(drive - (previous or 0.0)) / max(getattr(self.shaker, "ramp_rate", np.inf), 1e-12)

    def ramp_out(self, frequency: float, drive: float, periods: float) -> None:
        """Ramp the drive to zero over ``periods`` periods (at least the instrument's own ramp time) and wait
        for it. Switching a steady sine off at once leaves a lightly damped structure ringing at its own
        frequencies for minutes -- the state the next run, or the next connection, would start from."""
        rate = getattr(self.shaker, "ramp_rate", None)
        slow = max(drive * frequency / periods, MIN_RAMP_RATE)
        if rate is not None and slow < rate:
            self.shaker.set_ramp_rate(slow)
        try:
            self._set_drive(frequency, 0.0, drive)
        finally:
            if rate is not None and slow < rate:
                self.shaker.set_ramp_rate(rate)

    def _new_line(self, frequency: float, drive: float, n_rec: int) -> None:
        """Move the generator to a new line and wait until the data show it.

        Samples taken before the instrument acted on the command still arrive for a while (queues and FIFOs
        between the DAQ's converter and this program): a record counts only once the frequency fitted on its
        force channel is the new one, and the line's records start after that one (:meth:`_await_change`).
        The samples that took is the path's latency, kept (largest seen) for the amplitude changes of the
        force loop, where no frequency tells old data from new.
        """
        self.feed.stream.sync()    # the samples before the change all in: the change lands at a known sample
        self.shaker.set_sine(frequency, drive)
        self.feed.flush()
        if self._frequency:
            tolerance = 1e-4 + 0.25 * abs(frequency - self._frequency) / frequency
            self._await_change(n_rec, lambda data: self._shows(data, frequency, tolerance))
        self._frequency = frequency
        self.feed.skip(int(np.ceil(3.0 / frequency * self.sample_rate)))

    def _fitted_frequency(self, data: np.ndarray, frequency: float) -> float | None:
        """The frequency of the force channel's tone near ``frequency``, or None where the record holds no
        tone there: the fit diverges, or explains less than half the record's power (a record of an older
        line: over a whole number of periods of both, a tone at 2 Hz projects to nothing at 2.5 Hz, and the
        fit then stays at its guess; or a ringing structure at a force too small to fit)."""
        try:
            fit = sine_fit(data[:, self.force_index], self.sample_rate, frequency)
        except ValueError:
            return None
        if not abs(fit.amplitude) / np.sqrt(2) > fit.residual_rms:
            return None
        return fit.frequency

    def _shows(self, data: np.ndarray, frequency: float, tolerance: float) -> bool:
        """Whether a record was taken after the generator moved to ``frequency``."""
        fitted = self._fitted_frequency(data, frequency)
        return fitted is not None and abs(fitted / frequency - 1) <= tolerance

    def measure(self, frequency: float, target: "float | HeldLevel", drive: float) -> LineMeasurement:
        """Hold ``target`` (a force in N, or a :class:`HeldLevel`) at ``frequency`` Hz starting from ``drive`` V
        and measure the line."""
        held = target if isinstance(target, HeldLevel) else HeldLevel(float(target))
        if held.response and f"acc:{held.dof}" not in self._channels:
            raise ValueError(f"the response to hold is at {held.dof}, which carries no accelerometer")
        self._held, self._levels = held, []
        target_force = float("nan") if held.response else held.target
        fs = self.sample_rate
        n_rec = max(int(round(self.settle.block_periods * fs / frequency)), 32)
        self._new_line(frequency, drive, n_rec)
        wait = LineWait(periods_per_record=n_rec * frequency / fs, drive=drive)
        history: list[RecordAnalysis] = []     # records since the drive last changed
        self._restart_transient()
        while True:
            self.should_stop()
            rec = self.feed.record(n_rec)
            wait.add_record(rec.first_sample)
            history.append(self._analyse(rec.data, frequency, fit_frequency=False))
            early = self._early(frequency, rec)
            if early is not None:
                history[-1] = early            # the force loop acts on the estimated steady force
            steady = early is not None or self._steady(history)
            at_limit = wait.at_limit(self.settle.max_periods)
            ratio = self._correction(frequency, history, steady, at_limit, held, wait)
            if ratio is not None:
                new_drive = float(min(wait.drive * ratio, self.v_max))
                if new_drive != wait.drive:
                    self._set_drive(frequency, new_drive, wait.drive)
                    self._await_level(frequency, n_rec, history[-1].force, new_drive, wait.drive)
                    wait.drive_changed(new_drive, limit_retry=at_limit)
                    history = []
                    self._restart_transient()
                    continue
            if not steady and not at_limit:
                continue
            before = history[-2].raw if len(history) > 1 else rec.data[:0]
            if early is not None:
                wait.steady = True
                return self._transient_line(self._line(frequency, target_force, early, wait, rec, before))
            out = self._analyse(rec.data, frequency, fit_frequency=True)
            self._learn_poles(out)
            # what is left of the transient is uncertain by about the last change: part of the FRF's std
            self._add_miss(out, self._change(history[-1], history[-2]) if len(history) > 1 else 1.0)
            wait.steady = steady
            return self._transient_line(self._line(frequency, target_force, out, wait, rec, before))

    # ----- force and response control: the decisions, one function each ----------------------------
    def _level(self, rec: "RecordAnalysis") -> float:
        """The held amplitude of a record: the force's, or the response quantity's at the held DOF."""
        if not self._held.response:
            return abs(rec.force)
        a = rec.harmonics[1, self._channels.index(f"acc:{self._held.dof}")]
        return float(response_amplitude(a, 2 * np.pi * rec.frequency, self._held.quantity))

    def _on_target(self, level: float, target: float) -> bool:
        return abs(level / target - 1.0) <= self.control_tolerance

    def _force_known(self, frequency: float, history: list["RecordAnalysis"]) -> bool:
        """The held level is known, although the FRFs may still be settling (a structure ringing from before
        moves the accelerations far more than the force): the last three records agree on the held amplitude
        within FORCE_AGREEMENT and the last one holds a tone at the line's frequency (samples taken before the
        generator moved, still in the queues, hold none there and would read as almost no force)."""
        if len(history) < 3:
            return False
        forces = [self._level(h) for h in history[-3:]]
        if min(forces) <= 0 or max(forces) / min(forces) - 1.0 > FORCE_AGREEMENT:
            return False
        if self._held.response and not self._ringing_out(history):
            return False
        return self._shows(history[-1].raw, frequency, TONE_TOLERANCE)

    @staticmethod
    def _ringing_out(history: list["RecordAnalysis"]) -> bool:
        """A response level is known only once the structure no longer rings from the last change: the FRFs
        of the last three records agree within FORCE_AGREEMENT. Near a lightly damped resonance the response
        builds up or decays over many records while three of them agree on its level (the force follows the
        drive at once), and correcting on it set the loop swinging between x0.5 and x2."""
        return all(frf_change(history[-k].frf, history[-k - 1].frf) <= FORCE_AGREEMENT for k in (1, 2))

    def _correction(self, frequency: float, history: list["RecordAnalysis"], steady: bool, at_limit: bool,
                    held: HeldLevel, wait: "LineWait") -> float | None:
        """The factor to scale the drive by now, or None.

        - force on target: none;
        - settled: target / measured (fine control);
        - far off target (more than COARSE_ERROR) with a known force level: target / measured, before the
          FRFs settle (the approach from the low starting level; waiting for a ringing structure to settle
          at a level the plan does not ask for wastes the settling limit and measures the wrong line);
        - at the settling limit with the force off target: target / measured, LIMIT_RETRIES times, so that a
          line which never settles is at least measured at its force.
        Correcting an unsettled force within COARSE_ERROR chases the transient (measured: 20 corrections per
        line and a limit breach), so that is left to the settled case. Every factor is clipped to
        x0.5 .. x2 per step: the force approaches its target from where it was measured, never by a jump.
        A response level scales by the secant (:meth:`_drive_ratio`) within its force limit.
        """
        level, force = self._level(history[-1]), abs(history[-1].force)
        if self._on_target(level, held.target) or force == 0.0 or wait.control_steps >= MAX_CONTROL_STEPS:
            return None
        if at_limit and wait.limit_retries >= LIMIT_RETRIES:
            return None
        if level == 0.0:
            return self._stuck(held, force, steady or at_limit)
        coarse = self._coarse(level, held) and self._force_known(frequency, history)
        if not (steady or coarse or at_limit):
            return None
        ratio = float(np.clip(self._drive_ratio(level, held.target, wait.drive), 0.5, 2.0))
        return self._within_force_limit(ratio, force, held.force_limit)

    @staticmethod
    def _stuck(held: HeldLevel, force: float, settled: bool) -> float | None:
        """A response level whose DOF does not move at all (below one count: a joint held by friction below its
        slip force) once the line settled: double the drive, within the force limit -- no ratio to the target
        exists. A force level with no force has nothing to scale."""
        if not held.response or not settled:
            return None
        return LineMeter._within_force_limit(2.0, force, held.force_limit)

    @staticmethod
    def _coarse(level: float, held: HeldLevel) -> bool:
        """Far enough off target to correct before the line settles: by more than COARSE_ERROR -- for a
        response level only from below (the approach from the low start). Near a lightly damped resonance a
        response that overshot decays for many records; lowering the drive on it undershot, raising it again
        overshot, and the loop swung between x0.5 and x2 without end."""
        error = level / held.target - 1.0
        return error < -COARSE_ERROR if held.response else abs(error) > COARSE_ERROR

    def _drive_ratio(self, level: float, target: float, drive: float) -> float:
        """The factor that takes the held amplitude to its target. Force: target / measured (the N/V holds over
        one correction). Response: (target / measured)^(1/s) with ``s`` the secant slope of log(response)
        over log(drive) between this and the line's previous level, 1 before there is one."""
        ratio = target / level
        if not self._held.response:
            return ratio
        slope = 1.0
        if self._levels:
            d0, y0 = self._levels[-1]
            if d0 > 0 and y0 > 0 and abs(np.log(drive / d0)) > 1e-3:
                slope = float(np.clip(np.log(level / y0) / np.log(drive / d0), *SECANT_SLOPES))
        self._levels.append((drive, level))
        return ratio ** (1.0 / slope)

    @staticmethod
    def _within_force_limit(ratio: float, force: float, limit: float) -> float | None:
        """The drive factor clipped so that the force (proportional to the drive over one correction) stays
        within ``limit``; None where the force already sits at the limit and the factor would raise it."""
        if force * ratio <= limit:
            return ratio
        capped = limit / force
        return capped if capped < 1.0 - 1e-3 or capped > 1.0 + 1e-3 else None

    def _steady(self, history: list["RecordAnalysis"]) -> bool:
        """Whether the last records show a settled response.

        The change between the last two records must be within the tolerance, and so must what is still to
        come: a transient decaying by a ratio r per record still moves the result by change * r / (1 - r),
        which for a lightly damped structure is many times the last change. r is the slower of the last two
        ratios of successive changes, and the changes must shrink monotonically over the last four records
        (a beat between the drive and a free vibration makes single ratios lie). Once only measurement noise
        is left the changes stop shrinking, so three successive changes all within the tolerance and within
        three times the estimated noise also count as settled (the noise estimate, the fit residual, is
        inflated while a transient lasts, hence three in a row).

        The transient-aware method (``[settle] method = "transient"``), which models transients, judges the
        rest by its model instead of a ratio (:meth:`_rest_within_noise`): where two modes beat, the changes
        fall for three records while the response is still far from its limit, and the ratio is fooled.
        """
        if self.settle.fixed_periods:
            return len(history) * self.settle.block_periods >= self.settle.fixed_periods
        if len(history) < max(self.settle.min_blocks, 4):
            return False
        c1, c2, c3 = (self._change(history[-k], history[-k - 1]) for k in (1, 2, 3))
        if c1 > self.settle.tolerance:
            return False
        if self.transient is not None:
            if self._rest_within_noise(history):
                return True
        elif c1 < c2 < c3:
            ratio = max(c1 / c2, c2 / c3)
            if c1 * ratio / (1.0 - ratio) <= self.settle.tolerance:
                return True
        noise = [max(history[-k].noise, history[-k - 1].noise) for k in (1, 2, 3)]
        return all(c <= min(3.0 * n, self.settle.tolerance) for c, n in zip((c1, c2, c3), noise))

    def _rest_within_noise(self, history: list["RecordAnalysis"]) -> bool:
        """Whether what is left of the transient is within the last record's own noise and, with the limit's
        three standard deviations, within the tolerance. The records' FRFs since the drive changed converge as
        ``H_n = H_inf + sum_k a_k mu_k^n`` (analysis/signals/phasor_sequence.py: a linear structure's modes, a
        nonlinear one's Floquet multipliers near its orbit; complex, so a beat is followed). The rest must be
        within the noise, not only the tolerance: it has one sign over the lines near a resonance, so above the
        noise the identification sees it across lines (a rest just within the tolerance read as a law in a
        trial). False where the sequence shows no converging limit."""
        H = np.array([[r.frf[d] for d in self.sensor_dofs] for r in history])
        noise = np.array([[r.frf_std[d] for d in self.sensor_dofs] for r in history])
        fit = fit_sequence(H, noise)
        if fit is None or not fit.converging:
            return False
        rest = np.abs(H[-1] - fit.limit)
        size = np.abs(fit.limit)
        with np.errstate(divide="ignore", invalid="ignore"):
            budget = np.where(size > 0, (rest + 3 * fit.std) / size, np.inf)
        held = (size == 0) & (H[-1] == 0)                               # a DOF held at exactly zero throughout
        return bool(np.all(held | ((budget <= self.settle.tolerance) & (rest <= noise[-1]))))

    def _change(self, a: "RecordAnalysis", b: "RecordAnalysis") -> float:
        # magnitudes for the force (its phase depends on where the record starts), ratios for the FRFs
        with np.errstate(divide="ignore", invalid="ignore"):   # a record without drive: an infinite change
            force = abs(abs(a.force) / abs(b.force) - 1)
        return max(float(force) if np.isfinite(force) else np.inf, frf_change(a.frf, b.frf))

    def _analyse(self, data: np.ndarray, frequency: float, fit_frequency: bool) -> "RecordAnalysis":
        """Harmonics of a record. While settling the generator frequency is good enough (a clock offset of
        some ppm moves both channels alike, so FRF ratios and the force magnitude do not see it); the record
        that is kept is analysed at the frequency fitted on the force channel."""
        fs = self.sample_rate
        f_meas = frequency
        if fit_frequency:
            fitted = self._fitted_frequency(data, frequency)
            if fitted is not None and abs(fitted / frequency - 1) < 1e-3:
                f_meas = fitted
            H = harmonics_at(data, fs, f_meas, N_HARMONICS)
        else:
            key = (frequency, data.shape[0])
            if self._projector is None or self._projector[0] != key:
                self._projector = (key, HarmonicProjector(frequency, fs, data.shape[0], N_HARMONICS))
            H = self._projector[1](data)
        amp_std = 2 * H.residual_rms / np.sqrt(data.shape[0])     # std of each complex amplitude
        return self._analysis(H.amplitudes, amp_std, f_meas, data)

    def _analysis(self, amplitudes: np.ndarray, amp_std: np.ndarray, f_meas: float,
                  data: np.ndarray) -> "RecordAnalysis":
        """FRFs, their noise and the THD from harmonic ``amplitudes`` (n_harmonics + 1, channels) whose
        fundamentals have the standard deviations ``amp_std``."""
        Y1 = amplitudes[1]
        F = Y1[self.force_index]
        w2 = (2 * np.pi * f_meas) ** 2
        frf, frf_std = {}, {}
        for d, i in zip(self.sensor_dofs, self.sensor_index):
            h = Y1[i] / (-w2 * F)
            frf[d] = h
            rel = np.hypot(amp_std[i] / max(abs(Y1[i]), 1e-300), amp_std[self.force_index] / max(abs(F), 1e-300))
            frf_std[d] = abs(h) * rel
        noise = max(frf_std[d] / max(abs(frf[d]), 1e-300) for d in self.sensor_dofs)
        return RecordAnalysis(F, frf, frf_std, amplitudes, noise, f_meas, data)

    # ----- transient-aware path ([settle] method = "transient"): app/transient_line.py decides -----
    def _restart_transient(self) -> None:
        if self.transient is not None:
            self.transient.restart()

    def _early(self, frequency: float, rec) -> "RecordAnalysis | None":
        """The line's steady state estimated from its records while they still hold the transient, where
        the fit says its model holds; None: wait."""
        estimate: TransientEstimate | None = self.transient.add(rec, frequency) if self.transient else None
        if estimate is None or not estimate.accepted:
            return None
        return self._add_miss(self._analysis(estimate.phasors, estimate.std[1], frequency, rec.data), estimate.miss)

    def _add_miss(self, out: "RecordAnalysis", miss: float) -> "RecordAnalysis":
        """``out`` with ``miss`` (relative, at most 1) of each FRF added to its standard deviation: what is left of
        the transient (a waiting line's last change) or what an estimate's model misses. The noise alone says how
        well the records determine the FRF, not how far it still is from the steady state."""
        for d in self.sensor_dofs:
            out.frf_std[d] = float(np.hypot(out.frf_std[d], abs(out.frf[d]) * min(miss, 1.0)))
        return out

    def _learn_poles(self, out: "RecordAnalysis") -> None:
        """A line that waited: its free response gives the poles for the lines after it."""
        if self.transient is not None:
            self.transient.learn(out.frequency, out.harmonics)

    def _transient_line(self, m: LineMeasurement) -> LineMeasurement:
        """The line with the path it took: by the transient fit, or by waiting (and why)."""
        if self.transient is not None:
            last = self.transient.last
            m.transient = last is not None and last.accepted
            m.transient_std = last.frf_std if last is not None else float("nan")
            m.transient_reason = "" if m.transient else self.transient.reason
        return m

    def _line(self, frequency: float, target: float, out: "RecordAnalysis", wait: "LineWait", rec,
              before: np.ndarray) -> LineMeasurement:
        level = self._level(out)
        return LineMeasurement(frequency, out.frequency, out.force, out.frf, out.frf_std, out.harmonics, out.thd,
                               wait.drive, (rec.first_sample + len(rec.data) - wait.first_sample) / self.sample_rate,
                               wait.periods, wait.steady, wait.control_steps, np.concatenate([before, rec.data]),
                               target, self._on_target(level, self._held.target), held=self._held, level=level)


@dataclass
class RecordAnalysis:
    """What one record says: force and accelerometer fundamentals as FRFs, harmonics, noise of the estimate.

    ``noise`` is the largest relative standard deviation of the FRFs (from the fit residual); ``frequency`` the
    frequency the harmonics were fitted at; ``raw`` the record's samples."""

    force: complex
    frf: dict
    frf_std: dict
    harmonics: np.ndarray
    noise: float
    frequency: float
    raw: np.ndarray

    @property
    def thd(self) -> np.ndarray:
        """Per channel; asked only of the record a line keeps, not of every record it waits through."""
        return total_harmonic_distortion(self.harmonics)


@dataclass
class ChangeWait:
    """How long the data have not shown a generator change, by both clocks: samples of stream and wall time.

    Expired only when both exceed MAX_LATENCY_S. Stream alone is no bound where the transport decides how
    far the instrument runs ahead (a fast emulator fills every buffer between it and the host); wall time
    alone would make a fast run depend on the speed of the machine. While the change shows in time -- always,
    on a working set-up -- neither clock decides anything."""

    sample_rate: float
    samples: int = 0
    began: float = field(default_factory=time.monotonic)

    def add(self, n: int) -> None:
        self.samples += n

    def expired(self) -> bool:
        return (self.samples >= self.sample_rate * MAX_LATENCY_S
                and time.monotonic() - self.began >= MAX_LATENCY_S)


@dataclass
class LineWait:
    """The wait at one line: where it began, how long it has lasted, what the force loop did."""

    periods_per_record: float
    drive: float                       # V peak now
    first_sample: int | None = None
    periods: float = 0.0               # since the line began
    since_change: float = 0.0          # since the drive last changed
    control_steps: int = 0
    limit_retries: int = 0             # corrections made at the settling limit
    steady: bool = False

    def add_record(self, first_sample: int) -> None:
        self.first_sample = first_sample if self.first_sample is None else self.first_sample
        self.periods += self.periods_per_record
        self.since_change += self.periods_per_record

    def at_limit(self, max_periods: float) -> bool:
        return self.since_change >= max_periods

    def drive_changed(self, drive: float, limit_retry: bool) -> None:
        self.drive = drive
        self.since_change = 0.0
        self.control_steps += 1
        self.limit_retries += int(limit_retry)


def frf_change(a: dict, b: dict) -> float:
    """Largest relative change between two lines' (or records') FRFs, amplitude and phase together. A sensor
    that reads exactly zero on both (a DOF held by friction) has not changed; zero on one only is an infinite
    change."""
    changes = []
    for d in a:
        if a[d] == 0 and b[d] == 0:
            changes.append(0.0)                       # held still on both lines: no change
        elif b[d] == 0:
            changes.append(np.inf)
        else:
            changes.append(abs(a[d] / b[d] - 1))
    return float(max(changes))


def next_step(step: float, plan_step: float, min_step: float, change: float, threshold: float = 0.25) -> float:
    """Adaptive refinement: halve the step after a line whose FRF changed by more than ``threshold``
    (relative, amplitude and phase together) from the previous one, grow it back toward the plan's step when
    the change is small."""
    if change > threshold:
        return max(step / 2, min_step)
    if change < threshold / 4:
        return min(step * 2, plan_step)
    return step
