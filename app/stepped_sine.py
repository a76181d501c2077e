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
- **force control**: once steady, if the fundamental force differs from the target by more than the
  tolerance (1 %), the drive voltage is scaled by target / measured (by x0.5 .. x2 per step, within the
  generator's range) and the line settles again -- a voltage-driven shaker loses force at resonance, and kbar
  only means something at a stated force. Correcting an unsettled force would chase the transient. The
  instrument ramps the amplitude, so the drive never jumps.

The FRF is the receptance ``h_p = A_p / (-(2 pi f)^2 F)`` from the accelerometer and force fundamentals; its
standard deviation combines the residual noise of the fit (a complex amplitude from N samples with white
noise of rms s has ``E|dY|^2 = 4 s^2 / N``) with what settling leaves: the last record-to-record change,
relative (without it a noise-free measurement would claim a precision its transient does not allow).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from analysis.harmonics import HarmonicProjector, harmonics_at, sine_fit, total_harmonic_distortion

from .acquisition import RecordFeed
from .plan import SettleSpec

N_HARMONICS = 5
MAX_LATENCY_S = 10.0     # a generator change not seen in the data after this long is a fault of the set-up


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


class LineMeter:
    """Measures lines one after another on a running stream (the structure's state carries over)."""

    def __init__(self, shaker, feed: RecordFeed, channels: list[str], sensor_dofs: list[str], sample_rate: float,
                 settle: SettleSpec, control_tolerance: float, should_stop=lambda: None):
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

    def _set_drive(self, frequency: float, drive: float, previous: float | None) -> None:
        """Change the generator amplitude, then drop the samples taken before it acted (the learnt latency of
        the command-to-data path) and those of its amplitude ramp."""
        self.feed.stream.sync()    # the samples before the change all in: the change lands at a known sample
        self.shaker.set_sine(frequency, drive)
        self.feed.flush()
        ramp_s = abs(drive - (previous or 0.0)) / max(getattr(self.shaker, "ramp_rate", np.inf), 1e-12)
        self.feed.skip(self.latency + int(np.ceil((ramp_s + 3.0 / frequency) * self.sample_rate)))

    def _new_line(self, frequency: float, drive: float, n_rec: int) -> None:
        """Move the generator to a new line and wait until the data show it.

        Samples taken before the instrument acted on the command still arrive for a while (queues and FIFOs
        between the DAQ's converter and this program): a record counts only once the frequency fitted on its
        force channel is the new one. The samples that took is the path's latency, kept (largest seen) for
        the amplitude changes of the force loop, where no frequency tells old data from new.
        """
        self.feed.stream.sync()    # the samples before the change all in: the change lands at a known sample
        self.shaker.set_sine(frequency, drive)
        self.feed.flush()
        stale = 0
        tolerance = 1e-4 + 0.25 * abs(frequency - self._frequency) / frequency if self._frequency else np.inf
        while self._frequency and stale < self.sample_rate * MAX_LATENCY_S:
            self.should_stop()
            rec = self.feed.record(n_rec)
            fit = sine_fit(rec.data[:, self.force_index], self.sample_rate, frequency)
            if abs(fit.frequency / frequency - 1) <= tolerance:
                self.feed.unread(rec)
                break
            stale += len(rec.data)
        self.latency = max(self.latency, stale)
        self._frequency = frequency
        self.feed.skip(int(np.ceil(3.0 / frequency * self.sample_rate)))

    def measure(self, frequency: float, target_force: float, drive: float) -> LineMeasurement:
        """Hold ``target_force`` N at ``frequency`` Hz starting from ``drive`` V and measure the line."""
        fs = self.sample_rate
        n_rec = max(int(round(self.settle.block_periods * fs / frequency)), 32)
        periods_per_record = n_rec * frequency / fs
        self._new_line(frequency, drive, n_rec)
        start = None
        history: list[dict] = []     # records since the drive last changed
        waited = 0.0
        steps = 0
        while True:
            self.should_stop()
            rec = self.feed.record(n_rec)
            start = rec.first_sample if start is None else start
            waited += periods_per_record
            out = self._analyse(rec.data, frequency, fit_frequency=False)
            history.append(out)
            at_limit = waited >= self.settle.max_periods
            steady = self._steady(history)
            if not steady and not at_limit:
                continue
            force_error = abs(out["force"]) / target_force - 1.0
            if steady and abs(force_error) > self.control_tolerance and not at_limit:
                # correct only a settled force: a transient would make the loop chase itself
                ratio = np.clip(target_force / max(abs(out["force"]), 1e-12), 0.5, 2.0)
                new_drive = float(min(drive * ratio, self.v_max))
                if new_drive != drive:
                    steps += 1
                    self._set_drive(frequency, new_drive, drive)
                    drive = new_drive
                    history = []
                    continue
            before = history[-2]["raw"] if len(history) > 1 else rec.data[:0]
            out = self._analyse(rec.data, frequency, fit_frequency=True)
            # what is left of the transient is uncertain by about the last change: part of the FRF's std
            settling = self._change(history[-1], history[-2]) if len(history) > 1 else 1.0
            for d in self.sensor_dofs:
                out["frf_std"][d] = float(np.hypot(out["frf_std"][d], abs(out["frf"][d]) * min(settling, 1.0)))
            return self._line(frequency, out, drive, rec, start, waited, steady, steps, before)

    def _steady(self, history: list[dict]) -> bool:
        """Whether the last records show a settled response.

        The change between the last two records must be within the tolerance, and so must what is still to
        come: a transient decaying by a ratio r per record still moves the result by change * r / (1 - r),
        which for a lightly damped structure is many times the last change. r is the slower of the last two
        ratios of successive changes, and the changes must shrink monotonically over the last four records
        (a beat between the drive and a free vibration makes single ratios lie). Once only measurement noise
        is left the changes stop shrinking, so three successive changes all within the tolerance and within
        three times the estimated noise also count as settled (the noise estimate, the fit residual, is
        inflated while a transient lasts, hence three in a row).
        """
        if self.settle.fixed_periods:
            return len(history) * self.settle.block_periods >= self.settle.fixed_periods
        if len(history) < max(self.settle.min_blocks, 4):
            return False
        c1, c2, c3 = (self._change(history[-k], history[-k - 1]) for k in (1, 2, 3))
        if c1 > self.settle.tolerance:
            return False
        if c1 < c2 < c3:
            ratio = max(c1 / c2, c2 / c3)
            if c1 * ratio / (1.0 - ratio) <= self.settle.tolerance:
                return True
        noise = [max(history[-k]["noise"], history[-k - 1]["noise"]) for k in (1, 2, 3)]
        return all(c <= min(3.0 * n, self.settle.tolerance) for c, n in zip((c1, c2, c3), noise))

    def _change(self, a: dict, b: dict) -> float:
        # magnitudes for the force (its phase depends on where the record starts), ratios for the FRFs
        with np.errstate(divide="ignore", invalid="ignore"):   # a record without drive: an infinite change
            force = abs(abs(a["force"]) / abs(b["force"]) - 1)
        return max(float(force) if np.isfinite(force) else np.inf, frf_change(a["frf"], b["frf"]))

    def _analyse(self, data: np.ndarray, frequency: float, fit_frequency: bool) -> dict:
        """Harmonics of a record. While settling the generator frequency is good enough (a clock offset of
        some ppm moves both channels alike, so FRF ratios and the force magnitude do not see it); the record
        that is kept is analysed at the frequency fitted on the force channel."""
        fs = self.sample_rate
        f_meas = frequency
        if fit_frequency:
            fit = sine_fit(data[:, self.force_index], fs, frequency)
            if abs(fit.frequency / frequency - 1) < 1e-3:
                f_meas = fit.frequency
            H = harmonics_at(data, fs, f_meas, N_HARMONICS)
        else:
            key = (frequency, data.shape[0])
            if self._projector is None or self._projector[0] != key:
                self._projector = (key, HarmonicProjector(frequency, fs, data.shape[0], N_HARMONICS))
            H = self._projector[1](data)
        Y1 = H.amplitudes[1]
        F = Y1[self.force_index]
        w2 = (2 * np.pi * f_meas) ** 2
        n = data.shape[0]
        amp_std = 2 * H.residual_rms / np.sqrt(n)                  # std of each complex amplitude
        frf, frf_std = {}, {}
        for d, i in zip(self.sensor_dofs, self.sensor_index):
            h = Y1[i] / (-w2 * F)
            frf[d] = h
            rel = np.hypot(amp_std[i] / max(abs(Y1[i]), 1e-300), amp_std[self.force_index] / max(abs(F), 1e-300))
            frf_std[d] = abs(h) * rel
        noise = max(frf_std[d] / max(abs(frf[d]), 1e-300) for d in self.sensor_dofs)
        return {"force": F, "frf": frf, "frf_std": frf_std, "harmonics": H.amplitudes, "noise": noise,
                "thd": total_harmonic_distortion(H.amplitudes), "f": f_meas, "raw": data}

    def _line(self, frequency, out, drive, rec, start, waited, steady, steps, before) -> LineMeasurement:
        return LineMeasurement(frequency, out["f"], out["force"], out["frf"], out["frf_std"], out["harmonics"],
                               out["thd"], drive, (rec.first_sample + len(rec.data) - start) / self.sample_rate,
                               waited, steady, steps, np.concatenate([before, rec.data], axis=0))


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
