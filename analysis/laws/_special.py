"""Special functions shared by several describing functions.

The fundamental of a unit Jenkins element (unit stiffness in series with a slider)
under ``x = X sin(w t)`` depends only on the slip ratio ``s = (slip displacement) / X``.
With ``cos(psi) = 1 - 2 s`` (``psi`` in [0, pi]):

    Re = (psi - sin(2 psi) / 2) / pi,      Im = (4 / pi) s (1 - s),      0 <= s <= 1,

and kbar = 1 for ``s >= 1`` (the element sticks). The same real part is the describing
function of the dead zone and of the unilateral spring, whose forces are clipped linear
functions of ``x`` (see gap.py, unilateral.py).

Near ``s = 0`` the real part is ``16 s^(3/2) / (3 pi)``: evaluated as written it loses
every digit to cancellation, so ``psi - sin(2 psi)/2 = (y - sin y)/2`` with ``y = 2 psi``
is computed from its Taylor series for small ``y``, and ``psi = 2 asin(sqrt(s))`` is
used instead of ``acos(1 - 2 s)`` (which would round ``1 - 2 s`` first).
"""
from __future__ import annotations

import math

import numpy as np

# y - sin y = sum_{k=1..9} (-1)^(k+1) y^(2k+1) / (2k+1)!  for |y| < 1: the first omitted
# term is below 1e-19 y^3, while the direct form loses a factor ~6/y^2 to cancellation.
_SERIES_COEFFS = tuple((-1.0) ** (k + 1) / math.factorial(2 * k + 1) for k in range(1, 10))


def y_minus_sin(y) -> np.ndarray:
    """``y - sin(y)`` to full relative precision (float array, any shape)."""
    y = np.asarray(y, float)
    out = np.asarray(y - np.sin(y))
    small = np.abs(y) < 1.0
    if small.any():                     # the series only where it is used
        ys = y[small]
        y2 = ys * ys
        series = np.zeros_like(ys)
        for c in reversed(_SERIES_COEFFS):  # Horner in y^2
            series = series * y2 + c
        out[small] = series * ys * y2
    return out


def slip_real(s) -> np.ndarray:
    """Real part of the unit Jenkins describing function at slip ratio ``s``.

    Parameters
    ----------
    s : array_like
        Slip displacement over amplitude; clipped to [0, 1] (``s >= 1``: stuck, 1;
        ``s <= 0``: free slider, 0).

    Returns
    -------
    ndarray
        ``(psi - sin(2 psi)/2) / pi`` with ``cos(psi) = 1 - 2 s``, in [0, 1].
    """
    s = np.clip(np.asarray(s, float), 0.0, 1.0)
    psi = 2.0 * np.arcsin(np.sqrt(s))
    return y_minus_sin(2.0 * psi) / (2.0 * math.pi)


def slip_imag(s) -> np.ndarray:
    """Imaginary part of the unit Jenkins describing function, ``(4/pi) s (1 - s)`` on [0, 1]."""
    s = np.clip(np.asarray(s, float), 0.0, 1.0)
    return (4.0 / math.pi) * s * (1.0 - s)
