"""The steady-state phasor of a sine response that still holds its transient.

After a step in frequency or amplitude a linear structure answers with the forced response -- harmonics of the
drive -- plus its free response, decaying modes. Every channel of a record is modelled as

    y(t) = Y_0 + sum_h Im(Y_h e^{j h w t}) + sum_k e^{-sigma_k tau} (p_k cos(w_k tau) + q_k sin(w_k tau)),

``t`` measured from the phasor origin the caller names (sine convention of docs/contracts.md §1, as
analysis/signals/harmonics.py), ``tau`` from the first sample of the window. The poles ``s_k = -sigma_k + j w_k`` are
shared by all channels (one structure); the amplitudes are linear. For given poles the amplitudes come from one
least-squares solve; the poles are refined by nonlinear least squares on the projected residual (variable
projection: Golub and Pereyra 1973), starting from poles known before. The standard deviations come from the
covariance of the whole problem -- amplitudes and poles together -- so an ill-separated pole (a mode close to the
line frequency, a short window) widens them as it should.

:func:`free_response_poles` finds poles where none are known: a matrix pencil (Hua and Sarkar 1990) on a free
response, all channels stacked, the order taken from the singular values.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.optimize

MAX_MODES = 6              # free-response modes a window is fitted with at most
PENCIL_SAMPLES = 800       # samples of a free response the pencil looks at (its first, where it is strongest)
PENCIL_COLUMNS = 100       # pencil width: enough for MAX_MODES modes well above the noise, and a small SVD
PENCIL_FLOOR = 1e-2        # singular values below this fraction of the largest are noise
MIN_DAMPING_RATIO = 1e-4   # a pole with less damping is a left-over tone, not a mode


@dataclass
class TransientFit:
    """The forced response of a window fitted together with its free response.

    Attributes
    ----------
    phasors : ndarray, shape (n_harmonics + 1, channels), complex
        ``Y_h`` of the forced response (mean at 0), at the caller's time origin.
    std : ndarray, shape (n_harmonics + 1, channels)
        Standard deviation of each complex amplitude, ``sqrt(E|dY|^2)``.
    poles : ndarray, shape (K,), complex
        Refined poles ``-sigma + j w_d`` (rad/s, imaginary part > 0), ascending in frequency.
    residual_rms : ndarray, shape (channels,)
        RMS of what the model does not explain, channel units.
    residual : ndarray, shape (n, channels)
        What the model does not explain, sample by sample.
    free : ndarray, shape (n, channels)
        The fitted free response (the decaying modes), sample by sample.
    """

    phasors: np.ndarray
    std: np.ndarray
    poles: np.ndarray
    residual_rms: np.ndarray
    residual: np.ndarray
    free: np.ndarray


def fit_transient(t, y, frequency: float, poles, n_harmonics: int = 5, refine: bool = True) -> TransientFit:
    """Fit forced harmonics at ``frequency`` plus decaying modes to a window.

    Parameters
    ----------
    t : array_like, shape (n,)
        Sample times, s, from the phasor origin (need not be uniform: records with a gap between them).
    y : array_like, shape (n,) or (n, channels)
    frequency : float
        Line frequency, Hz (known: the generator's).
    poles : array_like, complex
        Starting poles ``-sigma + j w_d``, rad/s, imaginary part > 0; may be empty.
    n_harmonics : int
    refine : bool
        Refine the poles (variable projection); else keep them as given.
    """
    t = np.asarray(t, float)
    y = np.asarray(y, float)
    y = y[:, None] if y.ndim == 1 else y
    tau = t - t[0]
    w = 2 * np.pi * frequency
    forced = _forced_design(t, w, n_harmonics)
    x = _pole_params(np.asarray(poles, complex))
    scale = np.std(y, axis=0)
    scale[scale == 0] = 1.0
    ys = y / scale                                    # channels in their own units weigh alike
    if refine and x.size:
        x = _refine(x, forced, tau, ys)
    A = np.hstack([forced, _free_design(x, tau)])
    coef, *_ = np.linalg.lstsq(A, ys, rcond=None)
    residual = ys - A @ coef
    phasors, std = _phasors_and_std(A, coef, residual, x, tau, n_harmonics)
    free = A[:, forced.shape[1]:] @ coef[forced.shape[1]:]
    return TransientFit(phasors * scale, std * scale, _poles(x), np.sqrt(np.mean(residual**2, axis=0)) * scale,
                        residual * scale, free * scale)


def free_response_poles(y, sample_rate: float, max_modes: int = MAX_MODES, scale=None) -> np.ndarray:
    """Poles of a free response (uniformly sampled, the forced response removed), by a matrix pencil.

    ``scale`` (per channel, channel units; default the free response's own rms) weighs the channels: pass the
    rms of the records the free response came from, so that a channel with almost none of it (the force of an
    ideal source) adds its noise at its true, small weight rather than at that of the others.
    Returns the damped oscillatory poles ``-sigma + j w_d`` (rad/s, imaginary part > 0), ascending in frequency;
    empty when the response holds nothing above the noise.
    """
    y = np.asarray(y, float)
    y = (y[:, None] if y.ndim == 1 else y)[:PENCIL_SAMPLES]
    rms = np.sqrt(np.mean(y**2, axis=0)) if scale is None else np.asarray(scale, float)
    y = y[:, rms > 0] / rms[rms > 0]
    n = y.shape[0]
    if n < 12 or y.shape[1] == 0:
        return np.empty(0, complex)
    L = min(n // 3, PENCIL_COLUMNS)
    H = np.vstack([np.lib.stride_tricks.sliding_window_view(y[:, c], L + 1) for c in range(y.shape[1])])
    # right singular vectors from the small Gram matrix: only the subspace above PENCIL_FLOOR is used, far
    # above what squaring the singular values loses
    s2, V = np.linalg.eigh(H.T @ H)
    s2, V = s2[::-1], V[:, ::-1]
    order = int(np.sum(s2 > PENCIL_FLOOR**2 * s2[0]))
    if order > 2 * max_modes + 1:                 # no gap between signal and noise: nothing to find
        return np.empty(0, complex)
    V = V[:, :order]
    z = np.linalg.eigvals(np.linalg.pinv(V[:-1]) @ V[1:])
    z = z[np.abs(z) > 0]
    s_poles = np.log(z) * sample_rate
    keep = (s_poles.imag > 0) & (-s_poles.real > MIN_DAMPING_RATIO * np.abs(s_poles)) \
        & (s_poles.imag < 0.95 * np.pi * sample_rate)
    s_poles = s_poles[keep]
    return s_poles[np.argsort(s_poles.imag)][:max_modes]


# ----- the model ---------------------------------------------------------------------------------------
def _forced_design(t, w, n_harmonics):
    """Columns [1, sin(wt), cos(wt), sin(2wt), cos(2wt), ...] (the order of analysis/signals/harmonics.py)."""
    cols = [np.ones_like(t)]
    for h in range(1, n_harmonics + 1):
        cols += [np.sin(h * w * t), np.cos(h * w * t)]
    return np.stack(cols, axis=1)


def _pole_params(poles):
    """Parameters of the nonlinear fit: (log sigma, w_d) per mode (log: sigma stays positive)."""
    return np.concatenate([[np.log(-p.real), p.imag] for p in poles]) if len(poles) else np.empty(0)


def _poles(x):
    return np.array([-np.exp(x[2 * k]) + 1j * x[2 * k + 1] for k in range(len(x) // 2)])


def _free_design(x, tau):
    cols = []
    for k in range(len(x) // 2):
        e = np.exp(-np.exp(x[2 * k]) * tau)
        cols += [e * np.cos(x[2 * k + 1] * tau), e * np.sin(x[2 * k + 1] * tau)]
    return np.stack(cols, axis=1) if cols else np.empty((len(tau), 0))


def _free_derivatives(x, tau, coef_free):
    """d(model)/d(x) per channel: shape (n, channels, len(x)) for the free-response amplitudes ``coef_free``."""
    out = np.empty((len(tau), coef_free.shape[1], len(x)))
    for k in range(len(x) // 2):
        sigma, wd = np.exp(x[2 * k]), x[2 * k + 1]
        e = np.exp(-sigma * tau)
        c, s = e * np.cos(wd * tau), e * np.sin(wd * tau)
        p, q = coef_free[2 * k], coef_free[2 * k + 1]
        out[:, :, 2 * k] = -sigma * tau[:, None] * (np.outer(c, p) + np.outer(s, q))      # d/d log sigma
        out[:, :, 2 * k + 1] = tau[:, None] * (np.outer(-s, p) + np.outer(c, q))          # d/d w_d
    return out


def _refine(x0, forced, tau, ys):
    """Variable projection: the poles that leave the least residual once the amplitudes are solved for (Kaufman's
    Jacobian: the derivative of the model, projected off the design's columns)."""
    def solve(x):
        Q, R = np.linalg.qr(np.hstack([forced, _free_design(x, tau)]))
        Qy = Q.T @ ys
        return Q, Qy, np.linalg.lstsq(R, Qy, rcond=None)[0]

    def residual(x):
        Q, Qy, _ = solve(x)
        return (ys - Q @ Qy).ravel()

    def jacobian(x):
        Q, _, coef = solve(x)
        D = _free_derivatives(x, tau, coef[forced.shape[1]:])          # (n, channels, params)
        D = D - np.einsum("ni,icp->ncp", Q, np.einsum("ni,ncp->icp", Q, D))
        return -D.reshape(-1, len(x))

    # a pole may not wander far (onto a harmonic of the drive, where it would take the forced response)
    lo = np.concatenate([[x0[2 * k] - 5.0, 0.5 * x0[2 * k + 1]] for k in range(len(x0) // 2)])
    hi = np.concatenate([[x0[2 * k] + 5.0, 2.0 * x0[2 * k + 1]] for k in range(len(x0) // 2)])
    try:
        sol = scipy.optimize.least_squares(residual, x0, jac=jacobian, bounds=(lo, hi), x_scale="jac",
                                           xtol=1e-10, ftol=1e-10, max_nfev=20 * (len(x0) + 1))
    except (ValueError, np.linalg.LinAlgError):     # a singular design at the start: keep what was known
        return x0
    return sol.x if np.all(np.isfinite(sol.x)) else x0


def _phasors_and_std(A, coef, residual, x, tau, n_harmonics):
    """Phasors of the forced part and their standard deviations from the covariance of amplitudes and poles."""
    n, channels = residual.shape
    p = A.shape[1]
    n_forced = 2 * n_harmonics + 1
    Y = np.empty((n_harmonics + 1, channels), complex)
    Y[0] = coef[0]
    Y[1:] = coef[1:n_forced:2] + 1j * coef[2:n_forced:2]
    s2 = np.sum(residual**2, axis=0) / max(n - p - len(x) / channels, 1)   # per channel
    # channels are in units of their own spread, so round-off is eps: a channel held at exactly zero (a DOF
    # friction holds, below one count of the DAQ) fits with no residual, and a smaller floor weighs it so that
    # J^T J overflows
    s2 = np.maximum(s2, np.finfo(float).eps ** 2)
    # whole-problem Jacobian, rows weighted by each channel's noise: [block-diagonal A | shared pole columns]
    D = _free_derivatives(x, tau, coef[n_forced:]) if len(x) else np.empty((n, channels, 0))
    J = np.zeros((n * channels, p * channels + len(x)))
    for c in range(channels):
        rows = slice(c * n, (c + 1) * n)
        w = 1.0 / np.sqrt(s2[c])
        J[rows, c * p:(c + 1) * p] = A * w
        J[rows, p * channels:] = D[:, c, :] * w
    cov = np.linalg.pinv(J.T @ J)
    var = np.diag(cov)[:p * channels].reshape(channels, p).T
    var = np.where(var >= 0, var, np.inf)          # round-off of a singular problem: precision unknown
    std = np.empty((n_harmonics + 1, channels))
    std[0] = np.sqrt(var[0])
    std[1:] = np.sqrt(var[1:n_forced:2] + var[2:n_forced:2])
    return Y, std
