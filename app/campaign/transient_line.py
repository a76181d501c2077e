"""The transient-aware path of a stepped-sine line (``[settle] method = "transient"``, docs/campaigns.md).

Instead of waiting for the free response to die, each new record refits the line's records so far -- since the
line began or the drive last changed -- as forced harmonics plus decaying modes (analysis/signals/transient_fit.py) and
takes the forced part as the steady state when the fit says its model holds:

- **precise**: three standard deviations of every FRF and of the force magnitude within the settle tolerance;
- **consistent**: the same fit without the window's head -- its first record, or the first half of the only
  one: where the transient is strongest -- agrees within the tolerance (the steady-state check's own
  criterion, applied to the estimate);
- **linear**: no acceleration channel shows harmonics (THD) above THD_SHARE of the tolerance: a nonlinear
  element changes the decay with the amplitude, by about as much as it makes harmonics (measured on a Duffing
  oscillator: lines with a THD of 0.2-0.9 % fitted 0.3-2.5 % off their settled value), and near a jump the
  response heads for an attractor no sum of modes describes;
- **explained**: what the fit leaves in the head is within MODEL_SHARE of the free response it explains
  there, or within WHITENESS times what it leaves in the tail (the last record, or the second half of the only
  one), both relative to their part of the record: noise is alike everywhere, a wrong model of the transient
  is not.

A line whose records show harmonics goes to the **phasor sequence** (analysis/signals/phasor_sequence.py): its
harmonic phasors over consecutive windows of WINDOW_PERIODS periods converge to the steady state geometrically,
by the Floquet multipliers of the orbit the structure approaches, linear or not, and by their products (the
deviation's second-order terms, which a nonlinear element makes: without them the drift of a beating mode's
square reads as a limit that moves with the windows fitted). The sequence's limit is taken when it is

- **not shown linear**: the limit's harmonics, each three standard deviations larger, are beyond what a linear
  line may show (below). The first record's do not tell alone: where the poles known miss a mode, the fit of
  modes puts the free response it cannot describe into the harmonics;
- **converging**: every multiplier whose term is above the noise inside the unit circle by a margin (near a
  jump one approaches it);
- **within its error budget**: the limit's error has two parts, and together they stay within the tolerance:
  what the model misses, measured by how much the limit changes with the windows it is fitted to -- started
  later, without a quarter or a half of its windows (HEAD_SHARES: its head, where the deviation from the orbit
  is largest and its linearisation holds least), or ended a record earlier (so at least two records in a row
  must agree) -- and the noise, three standard deviations of the FRFs (from the covariance of limits,
  amplitudes and multipliers together). Where both are of a size, either alone within the tolerance leaves
  the sum beyond it.

A limit whose harmonics, each three standard deviations larger, stay within THD_SHARE of the tolerance says the
line is linear where it settles: the harmonics its first records showed were the transient's (the decay from
another branch after a jump, which is large and nonlinear, or a mode the poles known miss). The fit of modes then
takes the line's records from the next one on, where that transient has decayed toward the linear steady state,
as on any linear line; where they still show harmonics the sequence goes on. Such a line, once taken, hands on
the poles of its whole free response (its records less the forced response taken), as a line that waited does:
where the poles known missed a mode, what is left in the tail is too small to teach it. An uncertain limit's
harmonics are as uncertain, and say nothing: a line handed on by a limit without harmonics while its deviation
was still large and nonlinear was taken by modes that do not describe its decay, beyond the tolerance. Such a
line stays with its sequence, which takes it once within its error budget (teaching no poles, linear or not).

A line without harmonics that the fit of modes refuses waits: its free response is one of modes, and a
refusal says the poles known are not all of them, which the line's settled free response then teaches (a line
taken from its sequence teaches none, and the start drives predicted without the mode miss). Every line the
estimates refuse waits as the steady path does, and the reason is kept for the line's record. The poles come
from the measurement itself: a line that ended by waiting hands its free response (its records minus the settled
forced response) to a matrix pencil; a line the fit took hands on its refined poles. So the first line of a
campaign waits -- the free response of a settled line gives the poles; the few records of a sequence, less
the limit's error, give spurious ones, and the start drives predicted from them miss -- and the lines after it
are measured from their transients. A line taken from its sequence hands on nothing: its free response need not
be modal. (A random run's modal fit is not used:
with a voltage-driven shaker the free response has the poles of structure and shaker together, back-EMF damping
included, which the force-to-acceleration FRF does not show.)
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from analysis.signals.harmonics import total_harmonic_distortion
from analysis.signals.phasor_sequence import fit_sequence, window_phasors
from analysis.signals.transient_fit import fit_transient, free_response_poles

MIN_RECORDS = 1          # records a transient fit needs (the consistency check drops the first half of one)
MAX_FIT_RECORDS = 8      # a line not accepted within this many records waits as the steady path does
THD_SHARE = 0.5          # harmonics above this share of the tolerance say the structure is not linear here
WHITENESS = 2.0          # misfit in the head of the window / in its tail, both relative to their part's rms
MODEL_SHARE = 0.05       # misfit in the head / the free response fitted there
WINDOW_PERIODS = 2       # periods per phasor of the sequence: the shortest window whose harmonics stay apart
                         # where the period is not a whole number of samples
SEQUENCE_WINDOWS = 60    # the sequence's latest windows (the oldest are furthest from the orbit)
HEAD_SHARES = (0.25, 0.5)  # shares of the sequence's windows its consistency checks drop


@dataclass
class TransientEstimate:
    """One fit of a line's records: the forced response and whether it stands for the steady state.

    ``phasors`` and ``std`` (n_harmonics + 1, channels) are at the first sample of the line's last record (the
    origin of the steady path's harmonics); ``frf_std`` is the largest relative standard deviation of the FRFs;
    ``reason`` says why the estimate was not taken ("" when it was); ``miss`` the relative size of what the
    estimate's model misses: the largest change of the FRFs with the data fitted (without the head, a record
    earlier) and, for the fit of modes, the harmonics (a nonlinear element changes the decay with the amplitude by
    about as much as it makes harmonics: module docstring, "linear")."""

    phasors: np.ndarray
    std: np.ndarray
    frf_std: float
    accepted: bool
    reason: str
    miss: float = 0.0


class TransientLines:
    """The poles known so far and the records of the line in progress.

    Parameters
    ----------
    sample_rate : float
    n_harmonics : int
    tolerance : float
        The settle tolerance (relative).
    force_index : int
    sensor_index : list of int
        DAQ channel indices of the force and the accelerometers.
    """

    def __init__(self, sample_rate: float, n_harmonics: int, tolerance: float, force_index: int,
                 sensor_index: list[int]):
        self.sample_rate = sample_rate
        self.n_harmonics = n_harmonics
        self.tolerance = tolerance
        self.force_index = force_index
        self.sensor_index = list(sensor_index)
        self.poles = np.empty(0, complex)
        self.last: TransientEstimate | None = None     # the latest fit of this line (None: none made)
        self.reason = ""                                # why the line in progress is waiting
        self._records: list = []
        self._nonlinear = False                         # the line in progress showed harmonics
        self._modal_from = 0                            # its first record the fit of modes may take
        self._previous_limit = None                     # its phasor sequence's limit one record before

    @property
    def fitting(self) -> bool:
        """Whether the line in progress is one the fit of modes may take: poles known, no harmonics shown."""
        return len(self.poles) > 0 and not self._nonlinear

    def restart(self) -> None:
        """A new line, or the drive changed: the records so far hold another forcing."""
        self._records = []
        self._nonlinear = False
        self._modal_from = 0
        self._previous_limit = None
        self.last = None
        self.reason = "no poles known yet" if not len(self.poles) else ""

    def add(self, rec, frequency: float) -> TransientEstimate | None:
        """Add a record; the estimate of the line's steady state if the records allow one (else None)."""
        self._records.append(rec)
        if not len(self.poles):          # the line waits: its free response gives the poles for the rest
            self.reason = "no poles known yet"
            return None
        estimate = None
        if not self._nonlinear and MIN_RECORDS <= len(self._modal()) <= MAX_FIT_RECORDS:
            estimate = self._estimate(frequency)          # finds the harmonics, if any, in the first record
        if self._nonlinear:
            estimate = self._sequence(frequency) or estimate
        if estimate is not None:
            self.last = estimate
            self.reason = estimate.reason
        return estimate

    def learn(self, frequency: float, harmonics: np.ndarray) -> None:
        """A line ended by waiting, its steady harmonics ``harmonics`` (at the first sample of its last record):
        the poles of what its records held beyond them."""
        if not self._records:
            return
        run = self._contiguous()
        t, y = self._window(run)
        h = np.arange(harmonics.shape[0])
        forced = np.real(harmonics[0]) + np.imag(np.exp(1j * 2 * np.pi * frequency * np.outer(t, h[1:]))
                                                 @ harmonics[1:])
        poles = free_response_poles(y - forced, self.sample_rate, scale=np.sqrt(np.mean(y**2, axis=0)))
        if len(poles):
            self.poles = poles

    # ----- the decisions, one function each --------------------------------------------------------
    def _sequence(self, frequency: float) -> TransientEstimate | None:
        """The limit of the line's phasor sequence, or None where its records hold too few windows."""
        run = self._contiguous()
        origin = run[-1].first_sample - run[0].first_sample
        P, noise = window_phasors(np.concatenate([r.data for r in run]), self.sample_rate, frequency,
                                  WINDOW_PERIODS, self.n_harmonics, origin, last=SEQUENCE_WINDOWS)
        fit = fit_sequence(P, noise, products=True)
        heads = [max(1, int(share * len(P))) for share in HEAD_SHARES]
        later = [fit_sequence(P[h:], noise[h:], products=True) for h in heads] if fit is not None else [None]
        if any(f is None for f in later):
            return None
        frf_std = self._relative_std(fit.limit[1], fit.std[1])
        # the fundamentals' ratios and the force magnitude do not depend on the time origin, so the limit of the
        # record before (referred to its own first sample) compares as it is
        others = [f.limit[1] for f in later] + [self._previous_limit]
        change = max(_change(fit.limit[1], b, self.force_index, self.sensor_index) if b is not None else np.inf
                     for b in others)
        self._previous_limit = fit.limit[1]
        linear = self._linear(fit.limit, fit.std)
        if linear:                  # the harmonics were the transient's: the records after this one go to the modes
            self._nonlinear, self._modal_from = False, len(self._records)
        reason = linear or self._diverging(fit) or self._beyond_budget(frf_std, change)
        return TransientEstimate(fit.limit, fit.std, frf_std, not reason, reason, change)

    def _linear(self, limit: np.ndarray, std: np.ndarray) -> str:
        """Why the limit says the line is linear ("" where it does not): its harmonics, each 3 standard deviations
        larger, within the THD a linear line may show (an uncertain limit's harmonics are as uncertain)."""
        upper = limit.copy()
        upper[2:] = np.abs(limit[2:]) + 3 * std[2:]
        if not self._distorted(upper):
            return ("no harmonics in the steady state: a linear line, whose free response the fit of modes "
                    "takes once its transient is linear")
        return ""

    @staticmethod
    def _diverging(fit) -> str:
        if not fit.converging:
            return f"phasors not converging (a Floquet multiplier of magnitude {fit.slowest:.4f})"
        return ""

    def _estimate(self, frequency: float) -> TransientEstimate:
        records = self._modal()
        t, y = self._window(records)
        first = self._head(records)
        quick = fit_transient(t, y, frequency, self.poles, self.n_harmonics, refine=False)
        distorted = self._distorted(quick.phasors)
        if distorted:                    # to its sequence, until the limit of that shows no harmonics
            self._nonlinear = True
            return TransientEstimate(quick.phasors, quick.std, np.nan, False, distorted)
        full = fit_transient(t, y, frequency, self.poles, self.n_harmonics)
        later = fit_transient(t[first:], y[first:], frequency, full.poles, self.n_harmonics, refine=False)
        frf_std = self._relative_std(full.phasors[1], full.std[1])
        change = _change(full.phasors[1], later.phasors[1], self.force_index, self.sensor_index)
        reason = (self._imprecise(frf_std) or self._inconsistent(change)
                  or self._distorted(full.phasors) or self._unexplained(full, y, first))
        if not reason and self._modal_from:       # the line's tail: its whole free response teaches the poles
            self.learn(frequency, full.phasors)
        elif not reason:
            self.poles = full.poles
        miss = float(np.hypot(change, self._thd(full.phasors)))
        return TransientEstimate(full.phasors, full.std, frf_std, not reason, reason, miss)

    def _beyond_budget(self, relative_std: float, change: float) -> str:
        """The sequence's error budget: what its model misses -- the change of the limit with the windows it is
        fitted to -- and its noise (three standard deviations) add up to the tolerance at most."""
        if not change + 3 * relative_std <= self.tolerance:
            return (f"phasor sequence's limit uncertain: it changes by {change:.1e} with the windows fitted, "
                    f"3 std = {3 * relative_std:.1e}")
        return ""

    def _imprecise(self, relative_std: float) -> str:
        if 3 * relative_std > self.tolerance:
            return f"transient fit too uncertain (3 std = {3 * relative_std:.1e})"
        return ""

    def _inconsistent(self, change: float) -> str:
        if not change <= self.tolerance:
            return f"transient fit changes by {change:.1e} without its head"
        return ""

    def _thd(self, phasors: np.ndarray) -> float:
        return float(np.max(total_harmonic_distortion(phasors[:, self.sensor_index])))

    def _distorted(self, phasors: np.ndarray) -> str:
        thd = self._thd(phasors)
        if not thd <= THD_SHARE * self.tolerance:
            return f"harmonics (THD {thd:.1e}): not linear here"
        return ""

    def _unexplained(self, fit, y: np.ndarray, first: int) -> str:
        last = min(len(self._records[-1].data), len(y) - first)
        share = _relative_rms(fit.residual[:first], fit.free[:first])
        early = _relative_rms(fit.residual[:first], y[:first])
        late = _relative_rms(fit.residual[-last:], y[-last:])
        if share <= MODEL_SHARE or early <= WHITENESS * late:
            return ""
        return (f"transient fit leaves {share:.1e} of the free response unexplained, {early:.1e} of the first "
                f"record against {late:.1e} of the last: the modes do not describe it")

    def _relative_std(self, Y1: np.ndarray, std1: np.ndarray) -> float:
        F, sF = abs(Y1[self.force_index]), std1[self.force_index]
        rel = [np.hypot(std1[i] / max(abs(Y1[i]), 1e-300), sF / max(F, 1e-300)) for i in self.sensor_index]
        return float(max(rel + [sF / max(F, 1e-300)]))

    # ----- the records -----------------------------------------------------------------------------
    def _window(self, records: list) -> tuple[np.ndarray, np.ndarray]:
        """Samples and their times from the first sample of the last record (records may have gaps between)."""
        origin = records[-1].first_sample
        t = np.concatenate([(r.first_sample - origin + np.arange(len(r.data))) / self.sample_rate
                            for r in records])
        return t, np.concatenate([r.data for r in records])

    def _modal(self) -> list:
        """The records the fit of modes may take: the line's, from its first without the transient's harmonics."""
        return self._records[self._modal_from:]

    @staticmethod
    def _head(records: list) -> int:
        """Samples at the start of the window where the transient is strongest: the first record, or the first
        half of the only one."""
        first = len(records[0].data)
        return first if len(records) > 1 else first // 2

    def _contiguous(self) -> list:
        """The last records of the line that follow one another without a gap (the pencil needs uniform time)."""
        run = [self._records[-1]]
        for r in reversed(self._records[:-1]):
            if r.first_sample + len(r.data) != run[0].first_sample:
                break
            run.insert(0, r)
        return run


def _change(a: np.ndarray, b: np.ndarray, force_index: int, sensor_index: list[int]) -> float:
    """Largest relative change of the force magnitude and of the FRFs (sensor over force) between two fits."""
    with np.errstate(divide="ignore", invalid="ignore"):
        changes = [abs(abs(a[force_index]) / abs(b[force_index]) - 1)]
        changes += [abs((a[i] / a[force_index]) / (b[i] / b[force_index]) - 1) for i in sensor_index]
    return float(np.max(np.nan_to_num(changes, nan=np.inf)))


def _relative_rms(residual: np.ndarray, y: np.ndarray) -> float:
    rms = np.sqrt(np.mean(y**2, axis=0))
    return float(np.max(np.sqrt(np.mean(residual**2, axis=0)) / np.where(rms > 0, rms, np.inf)))
