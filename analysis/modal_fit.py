"""Natural frequencies, damping and mode shapes from measured FRFs.

A global single-mode fit per peak (all sensors share the pole), in the receptance form

    h_p(w) = A_p / (w_r^2 - w^2 + 2 j zeta_r w_r w) + B_p + D_p / w^2,

where the complex residue ``A_p`` carries the mode shape and ``B_p``, ``D_p`` take up the modes above and below
the band. For a trial pole the residues and residual terms are linear and come from a least-squares solve; the
pole (w_r, zeta_r) is found by bounded nonlinear least squares on the projected residual (variable
projection). Candidate peaks come from the sum of |h| over sensors (a mode indicator), so a mode visible at only
one sensor is still found.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.optimize
import scipy.signal


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
    """

    frequency: np.ndarray
    damping: np.ndarray
    residues: np.ndarray
    band: np.ndarray
    fit_error: np.ndarray

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


def fit_modes(frequency_hz, H, n_modes: int | None = None, band=None, min_prominence: float = 0.05) -> ModalFit:
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
    """
    f = np.asarray(frequency_hz, float)
    H = np.asarray(H, complex)
    H = H[:, None] if H.ndim == 1 else H
    if band is not None:
        keep = (f >= band[0]) & (f <= band[1])
        f, H = f[keep], H[keep]
    if len(f) < 8 or np.any(f <= 0):
        raise ValueError("need at least 8 lines, all at positive frequency")
    w = 2 * np.pi * f
    indicator = np.log(np.sum(np.abs(H) * (w[:, None] ** 2), axis=1))   # accelerance-weighted: flat in mass line
    peaks, props = scipy.signal.find_peaks(indicator, prominence=min_prominence)
    if not len(peaks):
        raise ValueError("no resonance peak found in the band")
    if n_modes is not None:
        peaks = np.sort(peaks[np.argsort(-props["prominences"])[:n_modes]])
    freqs, zetas, residues, bands, errors = [], [], [], [], []
    for k, i in enumerate(peaks):
        lo = peaks[k - 1] if k > 0 else 0
        hi = peaks[k + 1] if k + 1 < len(peaks) else len(f) - 1
        sel = slice((lo + i) // 2 if k > 0 else 0, (i + hi) // 2 + 1 if k + 1 < len(peaks) else len(f))
        ws, Hs = w[sel], H[sel]
        zeta0 = _half_power_damping(f[sel], np.abs(Hs).sum(axis=1), i - sel.start)

        def residual(x):
            _, _, R = _projected(ws, Hs, x[0] * w[i], x[1])
            return np.concatenate([R.real.ravel(), R.imag.ravel()]) / np.abs(Hs).max()

        sol = scipy.optimize.least_squares(residual, [1.0, zeta0], bounds=([0.8, 1e-6], [1.25, 0.5]),
                                           x_scale=[1e-3, zeta0], xtol=1e-14, ftol=1e-14)
        wr, zeta = sol.x[0] * w[i], sol.x[1]
        _, coef, R = _projected(ws, Hs, wr, zeta)
        freqs.append(wr / (2 * np.pi))
        zetas.append(zeta)
        residues.append(coef[0])
        bands.append((f[sel][0], f[sel][-1]))
        errors.append(np.linalg.norm(R) / np.linalg.norm(Hs))
    return ModalFit(np.array(freqs), np.array(zetas), np.array(residues), np.array(bands), np.array(errors))


def _half_power_damping(f, mag, ipk):
    """Damping ratio from the half-power bandwidth around the peak (starting value only)."""
    half = mag[ipk] / np.sqrt(2)
    left = np.flatnonzero(mag[:ipk] < half)
    right = np.flatnonzero(mag[ipk:] < half)
    if len(left) and len(right):
        width = f[ipk + right[0]] - f[left[-1]]
        return float(np.clip(width / (2 * f[ipk]), 1e-4, 0.3))
    return 0.01
