"""Amplitude and phase of the harmonics of a periodic record.

Two estimators, both returning complex amplitudes in the project's sine convention
(docs/contracts.md §1): a component ``a sin(k w t) + b cos(k w t)`` has the complex
amplitude ``Y_k = a + j b``, so ``y(t) = Y_0 + sum_k Im(Y_k exp(j k w t))`` with ``t``
measured from the first sample of the record, and ``X sin(w t)`` has ``Y_1 = X``.
A ratio of two such amplitudes is the usual complex FRF.

- :func:`harmonics` -- single-bin DFT per harmonic (a lock-in amplifier) on a record
  holding a whole number of periods (coherent sampling). Exact for every harmonic
  below the Nyquist frequency; white noise of variance ``sigma^2`` gives each complex
  amplitude an error variance ``4 sigma^2 / N`` (docs/method.md §5).
- :func:`sine_fit` -- the IEEE Std 1057 four-parameter sine fit (frequency, two
  quadrature amplitudes, offset), for records that are not coherent, e.g. when the
  DAQ clock differs from the generator's by some ppm. :func:`harmonics_at` then
  extracts the harmonics of every channel at the fitted frequency by least squares.

THD (total harmonic distortion) is ``sqrt(sum_{k>=2} |Y_k|^2) / |Y_1|`` per channel.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

# A record counts as holding whole periods when it is within this many periods of an
# integer; beyond that the single-bin DFT leaks and sine_fit is the right tool.
COHERENCE_TOLERANCE = 1e-6


@dataclass
class Harmonics:
    """Harmonic content of a record.

    Attributes
    ----------
    frequency : float
        Fundamental frequency, Hz.
    amplitudes : ndarray, shape (n_harmonics + 1,) or (n_harmonics + 1, n_channels), complex
        ``Y_k`` for k = 0 (mean, real) .. n_harmonics, in the sine convention.
    residual_rms : ndarray, shape () or (n_channels,)
        RMS of what the harmonics do not explain (noise, non-harmonic content), in the
        record's units.
    """

    frequency: float
    amplitudes: np.ndarray
    residual_rms: np.ndarray

    @property
    def fundamental(self) -> np.ndarray:
        """``Y_1``, complex, one per channel."""
        return self.amplitudes[1]

    @property
    def magnitude(self) -> np.ndarray:
        """``|Y_k|`` (amplitude of each sine component; the mean for k = 0)."""
        return np.abs(self.amplitudes)

    @property
    def phase(self) -> np.ndarray:
        """Phase of each harmonic, rad, relative to ``sin(k w t)`` at the first sample."""
        return np.angle(self.amplitudes)

    @property
    def thd(self) -> np.ndarray:
        """Total harmonic distortion per channel (0 for a pure sine; inf without a fundamental)."""
        return total_harmonic_distortion(self.amplitudes)


def total_harmonic_distortion(amplitudes) -> np.ndarray:
    """THD = sqrt(sum_{k>=2} |Y_k|^2) / |Y_1|.

    Parameters
    ----------
    amplitudes : array_like, shape (n_harmonics + 1, ...), complex
        Harmonic amplitudes with the mean at index 0 and the fundamental at index 1.

    Returns
    -------
    ndarray
        THD per trailing index; ``inf`` where the fundamental is zero but harmonics are not.
    """
    Y = np.asarray(amplitudes)
    if Y.shape[0] < 2:
        raise ValueError("need at least the mean and the fundamental (n_harmonics >= 1)")
    higher = np.sqrt(np.sum(np.abs(Y[2:]) ** 2, axis=0))
    fundamental = np.abs(Y[1])
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(fundamental > 0, higher / np.where(fundamental > 0, fundamental, 1.0),
                        np.where(higher > 0, np.inf, 0.0))


def whole_periods(frequency: float, sample_rate: float, n_samples: int) -> float:
    """Number of periods of ``frequency`` (Hz) in ``n_samples`` taken at ``sample_rate`` (Hz)."""
    return frequency * n_samples / sample_rate


def coherent_length(frequency: float, sample_rate: float, min_samples: int,
                    max_samples: int | None = None) -> tuple[int, int]:
    """The shortest record of at least ``min_samples`` holding a whole number of periods.

    Parameters
    ----------
    frequency, sample_rate : float
        Hz. Coherence needs ``frequency * n / sample_rate`` to be an integer, which
        happens only when the ratio is rational: choose the frequency on a grid
        ``m * sample_rate / n`` for exact coherence.
    min_samples : int
        Lower bound on the record length.
    max_samples : int, optional
        Upper bound (default ``100 * min_samples``).

    Returns
    -------
    (n_samples, n_periods) : tuple of int

    Raises
    ------
    ValueError
        When no length up to ``max_samples`` is coherent within COHERENCE_TOLERANCE.
    """
    if frequency <= 0 or sample_rate <= 0:
        raise ValueError("frequency and sample_rate must be > 0")
    max_samples = 100 * min_samples if max_samples is None else max_samples
    period = sample_rate / frequency
    first = max(1, math.ceil(min_samples / period - 1e-9))
    for m in range(first, int(max_samples / period) + 1):
        n = round(m * period)
        if n >= min_samples and abs(whole_periods(frequency, sample_rate, n) - m) <= COHERENCE_TOLERANCE:
            return n, m
    raise ValueError(f"no record of {min_samples}..{max_samples} samples holds a whole number of "
                     f"periods of {frequency} Hz at {sample_rate} Hz; use sine_fit")


def harmonics(record, sample_rate: float, frequency: float, n_harmonics: int = 5) -> Harmonics:
    """Single-bin DFT of every harmonic of a coherent record.

    Parameters
    ----------
    record : array_like, shape (N,) or (N, n_channels)
        Samples; the record must span a whole number of periods of ``frequency``.
    sample_rate : float
        Hz.
    frequency : float
        Fundamental frequency, Hz.
    n_harmonics : int
        Highest harmonic returned (every harmonic must lie below the Nyquist frequency).

    Returns
    -------
    Harmonics

    Raises
    ------
    ValueError
        If the record does not hold a whole number of periods (within
        COHERENCE_TOLERANCE periods), or a harmonic reaches the Nyquist frequency.
    """
    y = np.asarray(record, float)
    n = y.shape[0]
    periods = whole_periods(frequency, sample_rate, n)
    if n < 2 or abs(periods - round(periods)) > COHERENCE_TOLERANCE or round(periods) < 1:
        raise ValueError(f"the record of {n} samples holds {periods:.9g} periods of {frequency} Hz, not a "
                         "whole number: choose its length with coherent_length, or use sine_fit")
    _check_harmonics(frequency, sample_rate, n_harmonics)
    k = np.arange(n_harmonics + 1)
    # bin index of harmonic k is k * periods (an integer): exact orthogonality
    phase = 2.0 * np.pi * np.outer(k * round(periods), np.arange(n)) / n
    basis = np.exp(-1j * phase)                           # (K, N)
    c = basis @ y.astype(complex) * (2.0 / n)             # Re(c e^{jwt}) reconstructs y
    Y = 1j * c                                            # sine convention: Im(Y e^{jwt})
    Y[0] = c[0].real / 2.0                                # the mean
    residual = y - _synthesise(Y, frequency, sample_rate, n)
    return Harmonics(float(frequency), Y, _rms(residual))


def harmonics_at(record, sample_rate: float, frequency: float, n_harmonics: int = 5) -> Harmonics:
    """Harmonics of a record at a known (e.g. fitted) frequency by linear least squares.

    Unlike :func:`harmonics`, the record need not hold a whole number of periods; the
    least-squares fit of the mean and of ``sin``/``cos`` of every harmonic removes the
    leakage that a single-bin DFT would suffer. Records shorter than one period are
    ill-conditioned and refused.

    Parameters and returns as :func:`harmonics`. For many records of one length at one
    frequency, :class:`HarmonicProjector` does the same without refactoring each time.
    """
    y = np.asarray(record, float)
    return HarmonicProjector(frequency, sample_rate, y.shape[0], n_harmonics)(y)


class HarmonicProjector:
    """:func:`harmonics_at` for records of ``n`` samples at one frequency: the least-squares
    projector is computed once (a stepped-sine line analyses many records alike).

    Parameters
    ----------
    frequency, sample_rate : float
        Hz.
    n : int
        Samples per record (at least one period).
    n_harmonics : int
    """

    def __init__(self, frequency: float, sample_rate: float, n: int, n_harmonics: int = 5):
        if whole_periods(frequency, sample_rate, n) < 1.0:
            raise ValueError("the record must span at least one period")
        _check_harmonics(frequency, sample_rate, n_harmonics)
        self.frequency, self.n, self.n_harmonics = float(frequency), int(n), int(n_harmonics)
        self._A = _design(frequency, sample_rate, n, n_harmonics)
        self._pinv = np.linalg.pinv(self._A)

    def __call__(self, record) -> Harmonics:
        y = np.asarray(record, float)
        if y.shape[0] != self.n:
            raise ValueError(f"record has {y.shape[0]} samples, the projector {self.n}")
        coef = self._pinv @ y
        residual = y - self._A @ coef
        return Harmonics(self.frequency, _phasors(coef), _rms(residual))

    def batch(self, records) -> tuple[np.ndarray, np.ndarray]:
        """The harmonics of ``records`` (B, n, channels) at once: amplitudes (B, n_harmonics + 1, channels)
        complex and residual rms (B, channels), each record's as :meth:`__call__` gives them."""
        y = np.asarray(records, float)
        if y.ndim != 3 or y.shape[1] != self.n:
            raise ValueError(f"records of shape {y.shape}, the projector takes (B, {self.n}, channels)")
        coef = self._pinv @ y
        residual = y - self._A @ coef
        return np.moveaxis(_phasors(np.moveaxis(coef, 1, 0)), 0, 1), _rms(np.moveaxis(residual, 1, 0))


def _rms(residual: np.ndarray) -> np.ndarray:
    """Root mean square along the first axis (samples): an inner product per column, where ``mean(r**2)`` made
    two temporaries and took half a record's harmonics' time."""
    return np.sqrt(np.einsum("i...,i...->...", residual, residual) / residual.shape[0])


def _phasors(coef: np.ndarray) -> np.ndarray:
    """Complex amplitudes [offset, a1 + j b1, a2 + j b2, ...] from least-squares coefficients [offset, a1, b1, a2,
    b2, ...] along the first axis (the columns of :func:`_design`)."""
    Y = np.empty(((coef.shape[0] + 1) // 2,) + coef.shape[1:], complex)
    Y[0] = coef[0]
    Y[1:] = coef[1::2] + 1j * coef[2::2]
    return Y


@dataclass
class SineFit:
    """Result of the IEEE 1057 four-parameter sine fit.

    Attributes
    ----------
    frequency : float
        Fitted frequency, Hz (in the record's time base).
    amplitude : complex
        ``a + j b`` of ``a sin(w t) + b cos(w t)`` (sine convention), record units.
    offset : float
        Mean, record units.
    residual_rms : float
        RMS of the fit residual.
    iterations : int
        Gauss-Newton iterations used.
    """

    frequency: float
    amplitude: complex
    offset: float
    residual_rms: float
    iterations: int


def sine_fit(record, sample_rate: float, frequency_guess: float | None = None, *,
             max_iterations: int = 30, tolerance: float = 1e-12) -> SineFit:
    """IEEE Std 1057 four-parameter sine fit of a single-channel record.

    The model ``y = a sin(w t) + b cos(w t) + c`` is fitted by Gauss-Newton in
    ``(a, b, c, w)`` starting from a three-parameter fit at ``frequency_guess``. Without
    a guess the start is the peak of a Hann-windowed spectrum, refined by parabolic
    interpolation of the log magnitude (good to a small fraction of a bin).

    Parameters
    ----------
    record : array_like, shape (N,)
        Samples, covering a few periods at least.
    sample_rate : float
        Hz.
    frequency_guess : float, optional
        Hz; should lie within about one DFT bin (``sample_rate / N``) of the truth.
    max_iterations : int
    tolerance : float
        Stop when the relative frequency update falls below this.

    Returns
    -------
    SineFit

    Raises
    ------
    ValueError
        For a record shorter than 4 samples or a flat record.
    """
    y = np.asarray(record, float)
    if y.ndim != 1 or y.shape[0] < 4:
        raise ValueError("sine_fit needs a 1-D record of at least 4 samples")
    if np.ptp(y) == 0:
        raise ValueError("the record is constant: there is no sine to fit")
    n = y.shape[0]
    t = np.arange(n) / sample_rate
    f = _spectral_peak(y, sample_rate) if frequency_guess is None else float(frequency_guess)
    coef = _three_parameter(y, t, f)
    iterations = 0
    for iterations in range(1, max_iterations + 1):
        a, b = coef[0], coef[1]
        wt = 2 * np.pi * f * t
        s, c = np.sin(wt), np.cos(wt)
        # d/dw of a sin(wt) + b cos(wt) = t (a cos - b sin); the column is in Hz units
        dfreq = 2 * np.pi * t * (a * c - b * s)
        A = np.column_stack([s, c, np.ones(n), dfreq])
        sol, *_ = np.linalg.lstsq(A, y - (a * s + b * c + coef[2]), rcond=None)
        coef = coef + sol[:3]
        f_new = f + sol[3]
        if not np.isfinite(f_new) or f_new <= 0:
            raise ValueError("sine_fit diverged: give a frequency_guess within one bin of the tone")
        step = abs(f_new - f)
        f = f_new
        if step <= tolerance * f:
            break
    coef = _three_parameter(y, t, f)
    wt = 2 * np.pi * f * t
    residual = y - (coef[0] * np.sin(wt) + coef[1] * np.cos(wt) + coef[2])
    return SineFit(float(f), complex(coef[0], coef[1]), float(coef[2]),
                   float(np.sqrt(np.mean(residual**2))), iterations)


# --- helpers -------------------------------------------------------------------
def _check_harmonics(frequency: float, sample_rate: float, n_harmonics: int) -> None:
    if n_harmonics < 1:
        raise ValueError("n_harmonics must be >= 1")
    if frequency <= 0:
        raise ValueError("frequency must be > 0")
    if n_harmonics * frequency >= sample_rate / 2:
        raise ValueError(f"harmonic {n_harmonics} of {frequency} Hz is not below the Nyquist "
                         f"frequency {sample_rate / 2} Hz: lower n_harmonics")


def _design(frequency: float, sample_rate: float, n: int, n_harmonics: int) -> np.ndarray:
    """Columns [1, sin(wt), cos(wt), sin(2wt), cos(2wt), ...], shape (n, 2 K + 1)."""
    wt = 2 * np.pi * frequency * np.arange(n) / sample_rate
    A = np.empty((n, 2 * n_harmonics + 1))
    A[:, 0] = 1.0
    for k in range(1, n_harmonics + 1):
        A[:, 2 * k - 1] = np.sin(k * wt)
        A[:, 2 * k] = np.cos(k * wt)
    return A


def _synthesise(Y: np.ndarray, frequency: float, sample_rate: float, n: int) -> np.ndarray:
    """The record ``Y_0 + sum_k Im(Y_k e^{j k w t})`` at n samples."""
    k = np.arange(Y.shape[0])
    wt = 2 * np.pi * frequency * np.arange(n) / sample_rate
    E = np.exp(1j * np.outer(wt, k))                      # (N, K)
    out = np.tensordot(E[:, 1:], Y[1:], axes=1).imag
    return out + np.real(Y[0])


def _three_parameter(y: np.ndarray, t: np.ndarray, f: float) -> np.ndarray:
    wt = 2 * np.pi * f * t
    A = np.column_stack([np.sin(wt), np.cos(wt), np.ones_like(t)])
    coef, *_ = np.linalg.lstsq(A, y, rcond=None)
    return coef


def _spectral_peak(y: np.ndarray, sample_rate: float) -> float:
    n = y.shape[0]
    spectrum = np.abs(np.fft.rfft((y - y.mean()) * np.hanning(n)))
    k = int(np.argmax(spectrum[1:])) + 1
    if 1 <= k < len(spectrum) - 1:
        lo, mid, hi = np.log(spectrum[k - 1:k + 2] + 1e-300)
        denom = lo - 2 * mid + hi
        shift = 0.5 * (lo - hi) / denom if denom != 0 else 0.0
    else:
        shift = 0.0
    return (k + float(np.clip(shift, -0.5, 0.5))) * sample_rate / n
