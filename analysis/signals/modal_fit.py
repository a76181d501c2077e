"""Natural frequencies, damping and mode shapes from measured FRFs.

A global single-mode fit per peak (all sensors share the pole), in the receptance form

    h_p(w) = A_p / (w_r^2 - w^2 + 2 j zeta_r w_r w) + B_p + D_p / w^2,

where the complex residue ``A_p`` carries the mode shape and ``B_p``, ``D_p`` take up the modes above and below
the band. For a trial pole the residues and residual terms are linear and come from a least-squares solve; the
pole (w_r, zeta_r) is found by bounded nonlinear least squares on the projected residual (variable
projection). Candidate peaks come from the sum of |h| over sensors (a mode indicator), so a mode visible at only
one sensor is still found.

A fitted pole is a mode only if it is one: a pole that ends on a bound of its search (``zeta`` at its floor,
the frequency at 0.8 or 1.25 x the peak) or outside the band it was fitted on describes noise or a bump the
single-mode form cannot follow, and is listed in :attr:`ModalFit.rejected` with the reason instead. Where the
FRFs come with their coherence (random excitation), each mode carries the mean coherence over its half-power
band at the sensor that sees it most, and :data:`LOW_COHERENCE` marks the modes not to be trusted
(docs/workbench.md, section 1).
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import scipy.optimize
import scipy.signal

from .frf_estimation import expected_coherence, expected_h1

NOISE_PROMINENCE = 10.0    # a peak must stand this many random errors of |H1| above its surroundings (noise
                           # bumps of a Welch estimate of 8 averages reach 5-12)
LOW_COHERENCE = 0.8        # mean H1 coherence over a mode's half-power band below this: the mode is not trusted
F_BOUNDS = (0.8, 1.25)     # the pole's frequency is searched within these factors of its peak line
ZETA_BOUNDS = (1e-6, 0.5)


@dataclass
class RejectedPeak:
    """A peak whose fitted pole is not a mode: the peak line (Hz) and why."""

    frequency: float
    reason: str


@dataclass
class ModalFit:
    """Fitted modes, ascending in frequency.

    Attributes
    ----------
    frequency : ndarray, shape (m,)
        Undamped natural frequencies, Hz.
    damping : ndarray, shape (m,)
        Viscous damping ratios.
    residues : ndarray, shape (m, p)
        Complex modal constants per sensor (m/N · (rad/s)^2 for receptance input).
    band : ndarray, shape (m, 2)
        Frequency band (Hz) each mode was fitted on.
    fit_error : ndarray, shape (m,)
        Relative rms misfit of the model in its band.
    coherence : ndarray, shape (m,), or None
        Mean coherence over each mode's half-power band at the sensor with the largest residue (None when
        no coherence was given).
    leakage_coherence : ndarray, shape (m,), or None
        The coherence a noise-free linear mode of the fitted frequency and damping shows on the same lines at
        the Welch resolution (Hann leakage alone; 1 where the resolution is not known).
    rejected : list of RejectedPeak
        Peaks whose pole ended on a bound or outside its band.
    residuals : ndarray, shape (m, 2, p), complex, or None
        Each mode's residual terms ``B_p`` (m/N) and ``D_p`` (m/N (rad/s)^2) fitted on its band.
    """

    frequency: np.ndarray
    damping: np.ndarray
    residues: np.ndarray
    band: np.ndarray
    fit_error: np.ndarray
    coherence: np.ndarray | None = None
    rejected: list[RejectedPeak] = field(default_factory=list)
    leakage_coherence: np.ndarray | None = None
    residuals: np.ndarray | None = None

    @property
    def low_coherence(self) -> np.ndarray:
        """Per mode: True where its coherence is below LOW_COHERENCE times what leakage alone leaves (all False
        without coherence)."""
        if self.coherence is None:
            return np.zeros(len(self.frequency), bool)
        ceiling = 1.0 if self.leakage_coherence is None else self.leakage_coherence
        return self.coherence < LOW_COHERENCE * ceiling

    def subset(self, keep) -> "ModalFit":
        """The modes selected by the boolean mask or index array ``keep`` (the rejected peaks stay)."""
        return ModalFit(self.frequency[keep], self.damping[keep], self.residues[keep], self.band[keep],
                        self.fit_error[keep], None if self.coherence is None else self.coherence[keep],
                        list(self.rejected),
                        None if self.leakage_coherence is None else self.leakage_coherence[keep],
                        None if self.residuals is None else self.residuals[keep])

    def shapes(self) -> np.ndarray:
        """Real mode shapes (m, p) from the residues, each scaled so its largest entry is +1."""
        A = self.residues
        # rotate each residue vector to its best real direction
        phase = 0.5 * np.angle(np.sum(A * A, axis=1))
        real = (A * np.exp(-1j * phase)[:, None]).real
        return real / np.take_along_axis(real, np.abs(real).argmax(axis=1)[:, None], axis=1)


def _design(w, wr, zeta):
    return np.stack([1.0 / (wr**2 - w**2 + 2j * zeta * wr * w), np.ones_like(w, complex), 1.0 / w**2 + 0j], axis=1)


def _projected(w, H, wr, zeta):
    D = _design(w, wr, zeta)
    coef, *_ = np.linalg.lstsq(D, H, rcond=None)
    return D, coef, H - D @ coef


def fit_modes(frequency_hz, H, n_modes: int | None = None, band=None, min_prominence: float = 0.05,
              coherence=None, random_error=None, resolution: float | None = None) -> ModalFit:
    """Fit modes to receptance FRFs.

    Parameters
    ----------
    frequency_hz : array_like, shape (L,)
        Lines, Hz (> 0).
    H : array_like, shape (L,) or (L, p)
        Receptance FRFs (m/N) of p sensors for one excitation.
    n_modes : int, optional
        Keep the ``n_modes`` most prominent peaks (default: every peak above ``min_prominence``).
    band : (float, float), optional
        Restrict the search to this band, Hz.
    min_prominence : float
        Peak prominence in the log mode indicator (natural-log units) below which a bump is not a mode.
    coherence : array_like, shape (L,) or (L, p), optional
        Coherence of each FRF (random excitation): each mode's coherence is reported.
    random_error : array_like, shape (L,) or (L, p), optional
        Normalised random error of each |H1| (random excitation): a peak must also stand NOISE_PROMINENCE
        times the random error (of the sensor that dominates the indicator there) above its surroundings.
    resolution : float, optional
        Hz, of the Hann-windowed Welch estimate the FRFs come from: a mode's coherence is judged against what
        leakage alone leaves at that resolution.

    Returns the modes ascending in frequency; peaks whose pole is not a mode are in ``rejected``.
    """
    f = np.asarray(frequency_hz, float)
    H = np.asarray(H, complex)
    H = H[:, None] if H.ndim == 1 else H
    coh = None if coherence is None else np.asarray(coherence, float).reshape(len(f), -1)
    err = None if random_error is None else np.asarray(random_error, float).reshape(len(f), -1)
    if band is not None:
        keep = (f >= band[0]) & (f <= band[1])
        f, H = f[keep], H[keep]
        coh = None if coh is None else coh[keep]
        err = None if err is None else err[keep]
    if len(f) < 8 or np.any(f <= 0):
        raise ValueError("need at least 8 lines, all at positive frequency")
    w = 2 * np.pi * f
    indicator = np.log(np.sum(np.abs(H) * (w[:, None] ** 2), axis=1))   # accelerance-weighted: flat in mass line
    peaks, props = scipy.signal.find_peaks(indicator, prominence=min_prominence)
    if err is not None:                      # above the estimate's own scatter (a mass line is flat, not peaky)
        dominant = np.abs(H[peaks]).argmax(axis=1)
        above = props["prominences"] >= NOISE_PROMINENCE * err[peaks, dominant]
        peaks, props = peaks[above], {k: v[above] for k, v in props.items()}
    if not len(peaks):
        raise ValueError("no resonance peak found in the band")
    if n_modes is not None:
        peaks = np.sort(peaks[np.argsort(-props["prominences"])[:n_modes]])
    modes, rejected = [], []
    for k, i in enumerate(peaks):
        sel = slice((peaks[k - 1] + i) // 2 if k > 0 else 0,
                    (i + peaks[k + 1]) // 2 + 1 if k + 1 < len(peaks) else len(f))
        mode = _fit_peak(f, H, i, sel)
        why = _not_a_mode(mode)
        if why:
            rejected.append(RejectedPeak(float(f[i]), why))
        else:
            modes.append(mode)
    modes.sort(key=lambda m: m.frequency)
    fit = ModalFit(np.array([m.frequency for m in modes]), np.array([m.damping for m in modes]),
                   np.array([m.residue for m in modes]).reshape(len(modes), H.shape[1]),
                   np.array([m.band for m in modes]).reshape(len(modes), 2),
                   np.array([m.fit_error for m in modes]), None, rejected,
                   residuals=np.array([m.residuals for m in modes]).reshape(len(modes), 2, H.shape[1]))
    if coh is not None:
        fit.coherence = np.array([coh[_half_power_lines(f, m), int(np.abs(m.residue).argmax())].mean()
                                  for m in modes])
        if resolution is not None:
            fit.leakage_coherence = np.array([_leakage_coherence(f, m, resolution) for m in modes])
    return fit


@dataclass
class _Pole:
    """One peak's single-mode fit and whether the pole ended on a bound of its search."""

    frequency: float
    damping: float
    residue: np.ndarray
    band: tuple[float, float]
    fit_error: float
    on_bound: str             # "" or which bound
    residuals: np.ndarray     # (2, p): B_p and D_p


def _fit_peak(f, H, i, sel) -> _Pole:
    """Variable-projection fit of one pole on the lines ``sel`` around peak line ``i``."""
    w = 2 * np.pi * f
    ws, Hs = w[sel], H[sel]
    zeta0 = _half_power_damping(f[sel], np.abs(Hs).sum(axis=1), i - sel.start)

    def residual(x):
        _, _, R = _projected(ws, Hs, x[0] * w[i], x[1])
        return np.concatenate([R.real.ravel(), R.imag.ravel()]) / np.abs(Hs).max()

    sol = scipy.optimize.least_squares(residual, [1.0, zeta0], bounds=list(zip(F_BOUNDS, ZETA_BOUNDS)),
                                       x_scale=[1e-3, zeta0], xtol=1e-14, ftol=1e-14)
    wr, zeta = sol.x[0] * w[i], sol.x[1]
    _, coef, R = _projected(ws, Hs, wr, zeta)
    bound = ""
    if sol.active_mask[0]:
        bound = f"frequency at {F_BOUNDS[int(sol.active_mask[0] > 0)]:g} x the peak"
    elif sol.active_mask[1]:
        bound = f"damping at its {'floor' if sol.active_mask[1] < 0 else 'ceiling'} {sol.x[1]:.2g}"
    return _Pole(wr / (2 * np.pi), zeta, coef[0], (f[sel][0], f[sel][-1]),
                 np.linalg.norm(R) / np.linalg.norm(Hs), bound, coef[1:])


def _not_a_mode(pole: _Pole) -> str:
    """Why a fitted pole is not a mode ("" if it is one)."""
    if pole.on_bound:
        return f"pole on the bound of its search ({pole.on_bound})"
    lo, hi = pole.band
    if not lo <= pole.frequency <= hi:
        return f"pole at {pole.frequency:.4g} Hz, outside the band {lo:.4g}-{hi:.4g} Hz it was fitted on"
    return ""


def _half_power_lines(f, pole: _Pole) -> np.ndarray:
    """The lines within the mode's half-power band, or its nearest line: where its coherence is read (at the
    sensor with the largest residue, the one that sees the mode most)."""
    distance = np.abs(f - pole.frequency)
    near = distance <= pole.frequency * pole.damping
    return near if near.any() else distance == distance.min()


def _leakage_coherence(f, pole: _Pole, resolution: float) -> float:
    """The mean coherence Hann leakage alone leaves on the same lines for a single linear mode of this pole."""
    wr = 2 * np.pi * pole.frequency

    def receptance(f_hz):
        w = 2 * np.pi * f_hz
        return 1.0 / (wr**2 - w**2 + 2j * pole.damping * wr * w)

    return float(expected_coherence(receptance, f[_half_power_lines(f, pole)], resolution).mean())


def _half_power_damping(f, mag, ipk):
    """Damping ratio from the half-power bandwidth around the peak (starting value only)."""
    half = mag[ipk] / np.sqrt(2)
    left = np.flatnonzero(mag[:ipk] < half)
    right = np.flatnonzero(mag[ipk:] < half)
    if len(left) and len(right):
        width = f[ipk + right[0]] - f[left[-1]]
        return float(np.clip(width / (2 * f[ipk]), 1e-4, 0.3))
    return 0.01


@dataclass
class LeakageBias:
    """What a Hann-windowed Welch estimate at ``resolution`` Hz does to a mode's fitted damping.

    ``measured`` is the damping ratio fitted; ``corrected`` the true damping ratio whose expected Welch FRF
    fits to ``measured`` (NaN where none does: the mode is narrower than the resolution can tell)."""

    resolution: float
    measured: float
    corrected: float

    @property
    def bias(self) -> float:
        """Relative overstatement of the damping, ``measured / corrected - 1``."""
        return self.measured / self.corrected - 1.0


def hann_damping_bias(frequency: float, damping: float, resolution: float) -> float:
    """Relative error of the damping this modal fit finds for a single mode (``frequency`` Hz, true damping
    ratio ``damping``) from the H1 a Hann-windowed Welch estimate at ``resolution`` Hz converges to
    (:func:`analysis.signals.frf_estimation.expected_h1`, flat force spectrum)."""
    half = max(10.0 * frequency * damping, 12.0 * resolution)
    k = np.arange(max(1, int(np.ceil((frequency - half) / resolution))), int((frequency + half) / resolution) + 1)
    lines = k * resolution
    wr = 2 * np.pi * frequency

    def receptance(f_hz):
        w = 2 * np.pi * f_hz
        return 1.0 / (wr**2 - w**2 + 2j * damping * wr * w)

    fit = fit_modes(lines, expected_h1(receptance, lines, resolution), n_modes=1)
    return float(fit.damping[0] / damping - 1.0) if len(fit.frequency) else float("nan")


def leakage_bias(frequency: float, damping: float, resolution: float) -> LeakageBias:
    """The leakage bias of a mode fitted at (``frequency``, ``damping``) from a Welch estimate at
    ``resolution``: the true damping is found by solving ``d (1 + bias(d)) = damping``."""
    def excess(d):
        b = hann_damping_bias(frequency, d, resolution)
        return (d * (1 + b) if np.isfinite(b) else 0.0) - damping

    lo = damping / 20
    if excess(lo) >= 0 or excess(damping) <= 0:
        return LeakageBias(resolution, damping, float("nan") if excess(lo) >= 0 else damping)
    return LeakageBias(resolution, damping, float(scipy.optimize.brentq(excess, lo, damping, xtol=1e-3 * damping)))
