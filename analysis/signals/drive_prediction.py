"""The force per volt (N/V) a voltage-driven shaker will give at the next line of a stepped sine.

A shaker driven by a voltage V through its coil (resistance R, inductance L, force factor Bl, armature mass,
suspension Z_a) on a linear structure of drive-point receptance H(s) = N_s(s) / D_s(s) gives the gauge force

    F / V = 1 / ((R + L s) / Bl (1 + Z_a H) + Bl s H) = Bl D_s(s) / D_c(s),

a rational function whose zeros are the structure's own poles (the force drops at its resonances) and whose
poles are those of structure and shaker together -- the poles of the free response the transient-aware path
fits (analysis/signals/transient_fit.py). Only the magnitude is measured (the generator's phase is not recorded), so with
the coupled poles known

    Q(u) = |F/V|^2 |D_c(j w)|^2 = Bl^2 |D_s(j w)|^2,   u = w^2,

is a polynomial in u -- each structural mode adds degree 2 -- however sharp the force's dip at the resonance.
The lines measured so far give Q; a polynomial fitted to the last WINDOW of them, extrapolated to the next
line, gives its N/V.

A few lines do not determine that polynomial, and an ideal force source (a constant N/V) needs the full degree
to come out constant through |D_c|^2; so the same fit without the poles -- a polynomial in u for |F/V|^2
itself -- competes with it, and the one that predicted the latest line better from the lines before it
predicts the next one (a single line: the N/V stays as it was).
"""
from __future__ import annotations

import numpy as np

WINDOW = 8         # lines the polynomial is fitted to (the latest)
MAX_DEGREE = 4     # in u: two structural modes within the window (more lines than that: local fit)


def predicted_gain(frequencies, gains, poles, frequency: float) -> float | None:
    """N/V at ``frequency`` Hz from the lines at ``frequencies`` Hz that gave ``gains`` N/V, with the free
    response's ``poles`` (rad/s, one of each conjugate pair); None when no line is known or the extrapolated
    N/V is not positive (the fit says nothing there)."""
    f = np.asarray(frequencies, float)[-WINDOW:]
    g = np.asarray(gains, float)[-WINDOW:]
    if not len(f) or np.any(g <= 0):
        return None
    return _extrapolated(f, g, _better_model(f, g, poles), frequency)


def _better_model(f: np.ndarray, g: np.ndarray, poles) -> np.ndarray:
    """The poles (or none) whose model predicted the latest line better from the lines before it."""
    with_poles = np.asarray(poles, complex).ravel()
    if len(f) < 2 or not len(with_poles):
        return with_poles[:0]
    errors = []
    for candidate in (with_poles, with_poles[:0]):
        guess = _extrapolated(f[:-1], g[:-1], candidate, f[-1])
        errors.append(np.inf if guess is None else abs(np.log(guess / g[-1])))
    return with_poles if errors[0] < errors[1] else with_poles[:0]


def _extrapolated(f: np.ndarray, g: np.ndarray, poles: np.ndarray, frequency: float) -> float | None:
    """|F/V| at ``frequency`` from the polynomial in u fitted to Q = |F/V|^2 |D(j w)|^2 over ``poles``."""
    w = 2 * np.pi * f
    q = g**2 * _denominator(w, poles)
    degree = min(MAX_DEGREE, _distinct(w) - 1)
    scale = float(np.mean(w**2))                     # u / scale near 1: a well-conditioned Vandermonde
    V = np.vander(w**2 / scale, degree + 1)
    coef, *_ = np.linalg.lstsq(V / q[:, None], np.ones_like(q), rcond=None)    # relative residuals
    w_next = 2 * np.pi * frequency
    q_next = float(np.polyval(coef, w_next**2 / scale))
    if not q_next > 0:
        return None
    return float(np.sqrt(q_next / _denominator(np.array([w_next]), poles)[0]))


def _denominator(w: np.ndarray, poles) -> np.ndarray:
    """|D_c(j w)|^2 over the given poles and their conjugates."""
    s = 1j * w[:, None]
    p = np.asarray(poles, complex).reshape(1, -1)
    return np.prod(np.abs((s - p) * (s - np.conj(p)))**2, axis=1)


def _distinct(w: np.ndarray) -> int:
    """How many different frequencies (a polynomial through repeated ones is not determined by them)."""
    return len(np.unique(np.round(w, 9)))
