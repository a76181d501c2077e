"""FRF estimation from random excitation: H1, H2, Hv and coherence by Welch averaging.

One estimator object (pyFRF style): feed it blocks of force and response samples as they arrive with
:meth:`FRFEstimator.add_data`, read the estimates whenever you like. Segments are Hann-windowed with 50 %
overlap by default (Bendat & Piersol; ISO 7626-2 practice); samples left over from one block are kept for the
next, so streaming in blocks of any size gives the same result as one long record.

Estimators, with ``G_ab = E[conj(A) B]`` the averaged cross-spectra:
- ``H1 = G_fx / G_ff``   -- unbiased by noise on the response;
- ``H2 = G_xx / G_xf``   -- unbiased by noise on the force;
- ``Hv``                  -- total least squares (equal noise on both): the principal eigenvector of the 2x2
  spectral matrix, ``(G_xx - G_ff + sqrt((G_ff - G_xx)^2 + 4 |G_fx|^2)) / (2 G_xf)``;
- ``coherence = |G_fx|^2 / (G_ff G_xx)``.
The normalised random error of ``|H1|`` is ``sqrt(1 - coh) / (sqrt(coh) sqrt(2 n_avg))`` (Bendat & Piersol,
Random Data, table 9.6).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.signal


class FRFEstimator:
    """Welch-averaged FRF estimates for one force and several response channels.

    Parameters
    ----------
    sample_rate : float
        Hz.
    segment_length : int
        Samples per FFT segment (frequency resolution ``sample_rate / segment_length``).
    overlap : float
        Fraction of a segment shared with the next, in [0, 1).
    window : str
        Any window scipy.signal.get_window knows; "hann" by default.
    """

    def __init__(self, sample_rate: float, segment_length: int, overlap: float = 0.5, window: str = "hann"):
        if segment_length < 8:
            raise ValueError(f"segment_length must be >= 8 samples, got {segment_length}")
        if not 0.0 <= overlap < 1.0:
            raise ValueError(f"overlap must be in [0, 1), got {overlap}")
        self.sample_rate = float(sample_rate)
        self.segment_length = int(segment_length)
        self.step = max(1, int(round(self.segment_length * (1.0 - overlap))))
        self.window = scipy.signal.get_window(window, self.segment_length)
        self.frequency = np.fft.rfftfreq(self.segment_length, 1.0 / self.sample_rate)
        self.n_averages = 0
        self._pending: np.ndarray | None = None      # samples not yet in a full segment, (m, 1 + p)
        self._Gff = self._Gfx = self._Gxx = None

    def add_data(self, force, responses) -> None:
        """Append samples: ``force`` shape (m,), ``responses`` shape (m,) or (m, p), same units throughout."""
        force = np.asarray(force, float).reshape(-1, 1)
        responses = np.asarray(responses, float)
        responses = responses.reshape(-1, 1) if responses.ndim == 1 else responses
        if responses.shape[0] != force.shape[0]:
            raise ValueError(f"force has {force.shape[0]} samples but responses have {responses.shape[0]}")
        block = np.hstack([force, responses])
        if self._pending is not None:
            if self._pending.shape[1] != block.shape[1]:
                raise ValueError("the number of response channels changed between blocks")
            block = np.vstack([self._pending, block])
        n_seg = 0 if len(block) < self.segment_length else 1 + (len(block) - self.segment_length) // self.step
        if n_seg:
            starts = np.arange(n_seg) * self.step
            idx = starts[:, None] + np.arange(self.segment_length)[None, :]
            segs = block[idx] * self.window[None, :, None]            # (n_seg, N, 1 + p)
            spec = np.fft.rfft(segs, axis=1)
            F, X = spec[:, :, 0], spec[:, :, 1:]
            Gff = np.sum(np.abs(F) ** 2, axis=0)
            Gfx = np.sum(np.conj(F)[:, :, None] * X, axis=0)
            Gxx = np.sum(np.abs(X) ** 2, axis=0)
            if self._Gff is None:
                self._Gff, self._Gfx, self._Gxx = Gff, Gfx, Gxx
            else:
                self._Gff, self._Gfx, self._Gxx = self._Gff + Gff, self._Gfx + Gfx, self._Gxx + Gxx
            self.n_averages += n_seg
            block = block[n_seg * self.step:]
        self._pending = block

    def _spectra(self):
        if not self.n_averages:
            raise ValueError(f"no complete segment yet: need at least {self.segment_length} samples")
        return self._Gff[:, None], self._Gfx, self._Gxx

    def get_H1(self) -> np.ndarray:
        """H1, shape (n_freq, p), response units per force unit."""
        Gff, Gfx, _ = self._spectra()
        return Gfx / Gff

    def get_H2(self) -> np.ndarray:
        """H2, shape (n_freq, p)."""
        _, Gfx, Gxx = self._spectra()
        return Gxx / np.conj(Gfx)

    def get_Hv(self) -> np.ndarray:
        """Hv (total least squares), shape (n_freq, p)."""
        Gff, Gfx, Gxx = self._spectra()
        return (Gxx - Gff + np.sqrt((Gff - Gxx) ** 2 + 4 * np.abs(Gfx) ** 2)) / (2 * np.conj(Gfx))

    def get_coherence(self) -> np.ndarray:
        """Ordinary coherence in [0, 1], shape (n_freq, p)."""
        Gff, Gfx, Gxx = self._spectra()
        return np.abs(Gfx) ** 2 / (Gff * Gxx)

    def get_random_error(self) -> np.ndarray:
        """Normalised random error of |H1| (one standard deviation, relative), shape (n_freq, p)."""
        coh = np.clip(self.get_coherence(), 1e-12, 1.0)
        return np.sqrt(1.0 - coh) / (np.sqrt(coh) * np.sqrt(2.0 * self.n_averages))

    def get_force_autospectrum(self) -> np.ndarray:
        """One-sided force power spectral density, N^2/Hz, shape (n_freq,)."""
        Gff, _, _ = self._spectra()
        scale = 2.0 / (self.sample_rate * np.sum(self.window ** 2) * self.n_averages)
        psd = Gff[:, 0] * scale
        psd[0] /= 2.0
        if self.segment_length % 2 == 0:
            psd[-1] /= 2.0
        return psd


# ---------------------------------------------------------------------------------------------- resolution
LINES_PER_BANDWIDTH = 6      # automatic resolution: lines per half-power bandwidth of the lightest mode (Hann
                             # leakage then overstates its damping by about 4 %)
MIN_AVERAGES = 8             # ...unless the run is too short for this many Welch averages (50 % overlap)


@dataclass
class WelchResolution:
    """The frequency resolution of a Welch estimate and how it was chosen.

    Attributes
    ----------
    resolution : float
        Hz, the line spacing (1 / segment duration).
    wanted : float
        Hz, what the rule asked for (LINES_PER_BANDWIDTH lines per half-power bandwidth ``2 zeta f_low``), or
        the resolution the plan set.
    averages : int
        Welch averages (Hann, 50 % overlap) a run of the given duration gives.
    limited_by_duration : bool
        The run is too short for ``wanted`` with MIN_AVERAGES averages: the resolution is coarser.
    """

    resolution: float
    wanted: float
    averages: int
    limited_by_duration: bool

    @property
    def segment_seconds(self) -> float:
        return 1.0 / self.resolution


def welch_averages(duration: float, resolution: float, overlap: float = 0.5) -> int:
    """Segments of ``1 / resolution`` seconds a record of ``duration`` seconds holds with ``overlap``."""
    segment = 1.0 / resolution
    if duration < segment:
        return 0
    return 1 + int(np.floor((duration - segment) / (segment * (1.0 - overlap)) + 1e-9))


def auto_resolution(band: tuple[float, float], duration: float, damping: float) -> WelchResolution:
    """The resolution a random run of ``duration`` s over ``band`` Hz needs to resolve modes of damping ratio
    ``damping``: LINES_PER_BANDWIDTH lines per half-power bandwidth ``2 damping band[0]`` (the narrowest: the
    lightest mode at the lowest frequency), but no finer than MIN_AVERAGES Welch averages allow."""
    wanted = 2.0 * damping * band[0] / LINES_PER_BANDWIDTH
    finest = (MIN_AVERAGES + 1) / (2.0 * duration)        # 50 % overlap: averages = 2 duration / T - 1
    resolution = max(wanted, finest)
    return WelchResolution(resolution, wanted, welch_averages(duration, resolution), wanted < finest)


# ---------------------------------------------------------------------------------------------- leakage
def hann_kernel(offset_hz, resolution: float) -> np.ndarray:
    """|W(offset)|^2 of a Hann window of duration 1 / resolution (unnormalised): how a Welch line at f weighs
    the spectrum at f + offset."""
    x = np.asarray(offset_hz, float) / resolution
    return (np.sinc(x) + 0.5 * np.sinc(x - 1.0) + 0.5 * np.sinc(x + 1.0)) ** 2


def _kernel_average(frf, lines_hz, resolution: float, reach: float, points_per_line: int):
    """(kernel-averaged H, kernel-averaged |H|^2) at each line: the expected cross and auto spectra per unit
    force spectrum."""
    lines_hz = np.asarray(lines_hz, float)
    offsets = np.linspace(-reach, reach, int(2 * reach * points_per_line) + 1) * resolution
    weight = hann_kernel(offsets, resolution)
    weight = weight / weight.sum()
    v = lines_hz[:, None] + offsets[None, :]
    values = np.asarray(frf(np.abs(v).ravel()), complex).reshape(v.shape)
    values = np.where(v > 0, values, np.conj(values))          # H(-f) = conj(H(f)) for a real system
    return values @ weight, np.abs(values) ** 2 @ weight


def expected_coherence(frf, lines_hz, resolution: float, reach: float = 8.0, points_per_line: int = 40):
    """The coherence a Hann-windowed Welch estimate of a noise-free linear system converges to: below 1 only
    where the FRF changes within a line (leakage), ``|E[G_fx]|^2 / (E[G_ff] E[G_xx])``."""
    h, h2 = _kernel_average(frf, lines_hz, resolution, reach, points_per_line)
    return np.abs(h) ** 2 / h2


def expected_h1(frf, lines_hz, resolution: float, reach: float = 8.0, points_per_line: int = 40) -> np.ndarray:
    """The H1 a Hann-windowed Welch estimate converges to under a flat force spectrum: the true FRF averaged
    over each line's window kernel, ``E[H1](f) = int |W(f - v)|^2 H(v) dv / int |W(f - v)|^2 dv`` (the leakage
    bias; random error averaged away). ``frf(f_hz)`` evaluates the true FRF on an array of frequencies."""
    return _kernel_average(frf, lines_hz, resolution, reach, points_per_line)[0]
