"""Phase resonance: the frequency tracked until the response lags the force by a target phase, force level by level.

At a force level the lock measures a stepped-sine line (force control, settling and safety as every line:
:class:`~app.campaign.stepped_sine.LineMeter`) and reads the phase lag of the fundamental displacement at its DOF
behind the force, ``-arg h`` of the receptance. Below an isolated mode the lag is small, at the natural frequency
of the (nonlinear) mode it is 90 deg, above it nears 180 deg; the lag grows with frequency. So the next
frequency comes from a secant on lag against frequency -- the first step a probe of PROBE_STEP of the frequency
in the direction the error says -- until the lag is within the tolerance. Each step is at most MAX_STEP of the
frequency and at most MAX_LAG_STEP over the steepest slope of lag against frequency the run has seen, which is
the slope at phase resonance, (180/pi) / (zeta f) deg/Hz for a lone mode: a quarter of the mode's half-power band.
Small steps keep the lock on the branch it follows: a hardening mode's peak ends at a fold just above the
phase-resonance point, and a secant step across it (the lag changes slowly on the way up the branch) dropped
the response to the low branch, where the secant sent it back below (measured on tests/rigs/hardening.toml at
0.4 N: 12 lines between the branches, no lock; with the bound the lock walks up the branch). The next level
starts at the frequency the last one locked at: the mode moves little from one force to the next, and the
structure's state carries over as in a sweep.

The locked line is the point: its frequency, force, FRFs, harmonics, the measured lag, the lock's error, its
iterations and whether it converged, and the shaker time the level took (all its lines).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from app.campaign.plan import PhaseSpec
from app.campaign.stepped_sine import LineMeasurement, LineMeter

PROBE_STEP = 0.005       # the first step of a level: this share of the frequency, toward the target
MAX_STEP = 0.05          # no step larger than this share of the frequency (a secant across a flat lag)
MIN_SLOPE = 1e-6         # deg per Hz: a secant flatter than this is no guide (the probe step again)
MAX_LAG_STEP = 30.0      # deg: no step larger than what moves the lag by this much at the steepest slope seen
                         # (at phase resonance: a quarter of the mode's half-power band)


@dataclass
class LockedPoint:
    """One force level of a phase-resonance run: the line it locked at (or its last, unconverged), with the
    measured ``lag`` and ``error`` (deg), the ``iterations`` (lines measured), whether the lock ``converged``,
    and the ``shaker_seconds`` of all its lines (DAQ time)."""

    line: LineMeasurement
    lag: float
    error: float
    iterations: int
    converged: bool
    shaker_seconds: float


def phase_lag(m: LineMeasurement, dof: str) -> float:
    """Degrees the fundamental displacement at ``dof`` lags the force (0..360, the receptance's -arg)."""
    return float(np.degrees(-np.angle(m.frf[dof])) % 360.0)


def lag_error(lag: float, target: float) -> float:
    """Lag minus target, wrapped to -180..180 deg (negative: below the mode, raise the frequency)."""
    return float((lag - target + 180.0) % 360.0 - 180.0)


@dataclass
class PhaseTrack:
    """What the lock has learnt over a run: the steepest slope of lag against frequency seen (deg/Hz)."""

    steepest: float = 0.0

    def next_frequency(self, f: float, error: float, previous: tuple[float, float] | None) -> float:
        """The frequency to try after a line at ``f`` Hz whose lag is ``error`` deg off: a secant through
        ``previous`` (frequency, error) where it is a guide, else a probe step toward the target; within
        MAX_STEP of ``f`` and MAX_LAG_STEP over the steepest slope (module docstring)."""
        step = -np.sign(error) * PROBE_STEP * f
        if previous is not None and previous[0] != f:
            slope = (error - previous[1]) / (f - previous[0])
            if slope > MIN_SLOPE:                # the lag grows with frequency near a mode; else no guide
                self.steepest = max(self.steepest, slope)
                step = -error / slope
        bound = MAX_STEP * f if self.steepest <= 0 else min(MAX_STEP * f, MAX_LAG_STEP / self.steepest)
        return float(f + np.clip(step, -bound, bound))


def lock(meter: LineMeter, spec: PhaseSpec, track: PhaseTrack, force: float, frequency: float,
         drive: float) -> LockedPoint:
    """Track the frequency from ``frequency`` Hz at ``force`` N (drive ``drive`` V to start) until the lag at
    ``spec.dof`` is within ``spec.tolerance`` of ``spec.phase``, at most ``spec.max_iterations`` lines."""
    previous, seconds, iteration = None, 0.0, 0
    while True:
        iteration += 1
        m = meter.measure(frequency, force, drive)
        seconds += m.settle_time
        lag = phase_lag(m, spec.dof)
        error = lag_error(lag, spec.phase)
        if abs(error) <= spec.tolerance or iteration >= spec.max_iterations:
            return LockedPoint(m, lag, error, iteration, abs(error) <= spec.tolerance, seconds)
        previous, frequency = (frequency, error), track.next_frequency(frequency, error, previous)
        drive = m.drive
