"""The noise of FRFs that came without it: estimated from how far each line lies from a smooth curve.

An imported FRF (another system's UFF58 or CSV) carries no standard deviation, but the analysis weighs every
line by one. Between its lines a receptance is a smooth rational function of frequency (a few modes, and a
weak nonlinearity only bends it slowly), so what the lines scatter about a local rational fit is noise:

* around each line, a window of ``WINDOW`` neighbouring lines (fewer in a short run) is fitted by
  ``N(x) / D(x)``, numerator of degree ``DEGREE - 1``, denominator of degree ``DEGREE`` (two modes in the
  window), complex coefficients, ``x`` the frequency scaled to [-1, 1] over the window -- by Levy's linearised
  least squares refined by Sanathanan-Koerner iterations;
* the noise is taken as relative, a constant fraction of ``|H|`` within the window (as a force-controlled
  measurement with a steady signal-to-noise ratio gives), so residuals are weighed by ``1 / |H|`` and
  ``sigma_rel^2 = sum |e / H|^2 / (n - p)`` with ``p`` the complex coefficients fitted;
* each line gets ``sigma_rel |H|`` of the window centred on it.

Where the curve is not smooth enough for the fit (a resonance peak bent over towards a fold, a jump), the
window's estimate is larger than the noise. Left alone it would call those lines 10-100 times noisier than the
rest, and drop the very lines (the resonance, the largest amplitudes) that carry most of what a nonlinear law
shows; so each window's relative noise is capped at ``LOCAL_CAP`` times the median over the FRF's windows. The
line still counts less there, never more. A noise-free record is floored at ``FLOOR`` of the largest FRF value
(its round-off).
Fewer than ``MIN_LINES`` lines: no estimate.
"""
from __future__ import annotations

import numpy as np

WINDOW = 15
DEGREE = 4
ITERATIONS = 4
MIN_LINES = 5
FLOOR = 1e-9
LOCAL_CAP = 3.0                 # a window's relative noise std: at most this x the median over the FRF
METHOD = (f"from each FRF's scatter about a local rational fit over {WINDOW} neighbouring lines "
          "(noise taken as a constant fraction of |H| within the window)")


def _degree(n: int) -> int:
    """Denominator degree for a window of n lines: DEGREE, less where n leaves under 3 degrees of freedom."""
    return max(1, min(DEGREE, (n - 3) // 2))


def _least_squares(A: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Least-squares solutions of the stacked systems ``A[i] x = b[i]``: by QR, six times faster than the
    pseudo-inverse; systems whose R is (nearly) singular -- an exact fit of lower degree, noise-free data -- by
    the pseudo-inverse, which cuts singular values as ``lstsq`` does."""
    Q, R = np.linalg.qr(A)
    d = np.abs(np.diagonal(R, axis1=1, axis2=2))
    full = d.min(axis=1) > max(A.shape[1:]) * np.finfo(float).eps * d.max(axis=1)
    x = np.empty(A.shape[::2], complex)
    rhs = np.conj(np.swapaxes(Q[full], 1, 2)) @ b[full][..., None]
    x[full] = np.linalg.solve(R[full], rhs)[..., 0]
    if not full.all():
        x[~full] = (np.linalg.pinv(A[~full]) @ b[~full][..., None])[..., 0]
    return x


def _relative_variances(f: np.ndarray, H: np.ndarray) -> np.ndarray:
    """``E|n / H|^2`` of each window (rows of ``f`` and ``H``, all of one width) from the residual of its
    rational fit; every window is fitted at once (:func:`_least_squares`)."""
    x = (f - f.mean(axis=1, keepdims=True)) / np.maximum(np.ptp(f, axis=1, keepdims=True) / 2, 1e-300)
    nd = _degree(f.shape[1])
    scale = 1 / np.maximum(np.abs(H), 1e-300)
    weight = scale
    powers = x[..., None] ** np.arange(nd + 1)                       # x^0 .. x^nd
    for _ in range(ITERATIONS):
        A = np.concatenate([powers[..., :nd], -H[..., None] * powers[..., 1:]], axis=2) * weight[..., None]
        coef = _least_squares(A.astype(complex), H * weight)
        D = 1 + np.einsum("wnk,wk->wn", powers[..., 1:], coef[:, nd:])
        weight = scale / np.maximum(np.abs(D), 1e-300)
    e = (H - np.einsum("wnk,wk->wn", powers[..., :nd], coef[:, :nd]) / D) * scale
    return np.sum(np.abs(e) ** 2, axis=1) / (f.shape[1] - 2 * nd)


def smoothness_noise(frequency_hz, receptance) -> np.ndarray | None:
    """Estimated ``sqrt(E|n|^2)`` per line and sensor, shape (L, P), m/N; None with fewer than MIN_LINES lines.

    Lines may come in any order (a down sweep); windows are taken in order of frequency."""
    f = np.asarray(frequency_hz, float)
    H = np.asarray(receptance, complex).reshape(len(f), -1)
    L = len(f)
    if L < MIN_LINES:
        return None
    order = np.argsort(f, kind="stable")
    fs, Hs = f[order], H[order]
    width = min(WINDOW, L)
    starts = np.clip(np.arange(L) - width // 2, 0, L - width)
    distinct, window_of_line = np.unique(starts, return_inverse=True)
    rows = distinct[:, None] + np.arange(width)                      # (windows, width) line indices
    rel = np.stack([_relative_variances(fs[rows], Hs[rows, p])[window_of_line] for p in range(H.shape[1])],
                   axis=1)
    rel = np.minimum(rel, LOCAL_CAP ** 2 * np.median(rel, axis=0))      # variances: the cap squared
    std = np.empty_like(rel)
    std[order] = np.sqrt(rel) * np.abs(Hs)
    return np.maximum(std, FLOOR * np.abs(H).max())
