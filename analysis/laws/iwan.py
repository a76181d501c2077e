"""iwan: four-parameter (Segalman) Iwan joint model.

A continuum of Jenkins elements in parallel, each of unit stiffness and slip
displacement ``phi``, with population density

    rho(phi) = R phi^chi  on (0, phi_max)   plus a spike  S delta(phi - phi_max).

Contract parameters: the stiffness while fully stuck ``kt = R phi_max^(chi+1)/(chi+1) + S``,
the macro-slip force ``fs = R phi_max^(chi+2)/(chi+2) + S phi_max``, the exponent ``chi``
(-1 < chi <= 1) and the spike ratio ``beta = S / (R phi_max^(chi+1)/(chi+1))``. Hence

    phi_max = fs (1 + beta) / (kt (beta + (chi+1)/(chi+2))),
    R = kt (chi+1) / ((1 + beta) phi_max^(chi+1)),      S = beta kt / (1 + beta).

kbar / kt depends only on X / phi_max, chi and beta, so the fit parametrisation is
``kt`` linear and the shapes ``xs = fs / kt``, ``chi``, ``beta``.

Describing function (u = X / phi_max, m = 1/u; the unit Jenkins parts ReJ, ImJ are in
_special.py). Integrating the Jenkins describing function over the density, and the
real part by parts (``dReJ/ds = (8/pi) sqrt(s (1 - s))``), gives closed forms in the
beta function B and the incomplete beta function
``B_m(a, 3/2) = int_0^m s^(a-1) sqrt(1 - s) ds = (m^a / a) 2F1(a, -1/2; a+1; m)``:

    X <= phi_max (micro-slip):
        Re = kt [1 - 8 B(chi + 5/2, 3/2) u^(chi+1) / (pi (1 + beta))]
        Im = 4 R X^(chi+1) / (pi (chi+2)(chi+3))
    X > phi_max (macro-slip: every element slips):
        Re = kt/(1+beta) [ReJ(m) - (8/pi) B_m(chi + 5/2, 3/2) / m^(chi+1)] + S ReJ(m)
        Im = (4/pi) kt (chi+1)/(1+beta) [m/(chi+2) - m^2/(chi+3)] + S ImJ(m)

The micro-slip real part is ``R X^(chi+1) c(chi) + R (phi_max^(chi+1) - X^(chi+1))/(chi+1) + S``
with ``c(chi) = int_0^1 s^chi ReJ(s) ds = (1 - 8 B(chi+5/2, 3/2)/pi) / (chi+1)``; the tests
check both forms against quadrature. For uniform density (chi = 0, beta = 0) it reduces
to Re = kt (1 - X/(2 phi_max)), Im = 2 kt X / (3 pi phi_max). At large X, Im -> 4 fs/(pi X).

Time domain: a parallel ensemble of Jenkins elements obeys Masing's rules with
Madelung's memory exactly. With the virgin backbone (u >= 0)

    B(u) = kt u - R u^(chi+2) / ((chi+1)(chi+2))    (u < phi_max),   B(u) = fs  (u >= phi_max),

odd in u, a branch leaving the reversal point (x_r, F_r) in direction d (+1 or -1) is
``F = F_r + 2 d B(d (x - x_r) / 2)``; when it reaches the previous reversal point the loop
closes and the path continues on the branch that was interrupted there (a branch from
the first reversal rejoins the backbone at ``-x_r``). The state array holds the reversal
stack:

    s[0] number of remembered reversal points n, s[1] current direction (0 at rest),
    s[2], s[3] the previous position and force,
    s[4 + 2k], s[5 + 2k] reversal point k (k = 0 oldest).

At most ``MAX_REVERSALS`` = 64 nested reversal points are remembered (a slowly decaying
oscillation piles them up). When one more is needed, the pair of consecutive points
``(x_j, x_{j+1})`` whose removal changes the remembered loops least -- the smallest gap
between the same-side points ``x_{j-1}`` and ``x_{j+1}`` -- is forgotten: the path
then closes at ``x_{j-1}`` instead of at ``x_{j+1}``, and the force jumps there by at most
the force change of the branch over that gap. The oldest point (on the backbone) is
never forgotten. Below 64 nested reversals the force is exact at every sample point
(the update is exact along any monotone path between two calls); the velocity argument
is not used (rate independent).
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit
from scipy.special import beta as beta_function
from scipy.special import hyp2f1

from ._special import slip_imag, slip_real
from .base import Law, Param

MAX_REVERSALS = 64
_HEADER = 4  # n, direction, previous x, previous force


@njit(cache=True)
def slip_range(xs, chi, beta):
    """phi_max: largest slip displacement of the population, for ``xs = fs / kt``."""
    return xs * (1.0 + beta) / (beta + (chi + 1.0) / (chi + 2.0))


@njit(cache=True)
def _backbone(u, kt, fs, chi, beta, phi_max):
    """Virgin loading force at displacement u >= 0."""
    if u >= phi_max:
        return fs
    return kt * u * (1.0 - (u / phi_max) ** (chi + 1.0) / ((1.0 + beta) * (chi + 2.0)))


@njit(cache=True)
def _forget_one_loop(s, n):
    """Remove the pair of reversal points whose loss changes the remembered loops least."""
    best, best_gap = 1, math.inf
    for j in range(1, n - 1):
        gap = abs(s[_HEADER + 2 * (j + 1)] - s[_HEADER + 2 * (j - 1)])
        if gap < best_gap:
            best, best_gap = j, gap
    for k in range(best, n - 2):
        s[_HEADER + 2 * k] = s[_HEADER + 2 * (k + 2)]
        s[_HEADER + 2 * k + 1] = s[_HEADER + 2 * (k + 2) + 1]
    return n - 2


@njit(cache=True)
def iwan_force(x, v, p, s):
    kt, fs, chi, beta = p[0], p[1], p[2], p[3]
    x_last, f_last = s[2], s[3]
    if x == x_last:
        return f_last
    phi_max = slip_range(fs / kt, chi, beta)
    n = int(s[0])
    direction = 1.0 if x > x_last else -1.0
    if s[1] != 0.0 and direction != s[1]:
        # x_last was a turning point: remember it
        if n == MAX_REVERSALS:
            n = _forget_one_loop(s, n)
        s[_HEADER + 2 * n] = x_last
        s[_HEADER + 2 * n + 1] = f_last
        n += 1
    # Madelung memory: close every loop whose starting point the path has passed
    while n > 0:
        x_r = s[_HEADER + 2 * (n - 1)]
        target = s[_HEADER + 2 * (n - 2)] if n >= 2 else -x_r
        if direction * (x - target) < 0.0:
            break
        n = n - 2 if n >= 2 else 0
    if n == 0:
        f = _backbone(abs(x), kt, fs, chi, beta, phi_max)
        if x < 0.0:
            f = -f
    else:
        x_r = s[_HEADER + 2 * (n - 1)]
        f_r = s[_HEADER + 2 * (n - 1) + 1]
        f = f_r + 2.0 * direction * _backbone(0.5 * direction * (x - x_r), kt, fs, chi, beta, phi_max)
    s[0] = n
    s[1] = direction
    s[2] = x
    s[3] = f
    return f


def iwan_unit(X, xs, chi, beta) -> np.ndarray:
    """kbar / kt of the four-parameter Iwan model (complex, shape of ``X``).

    Parameters
    ----------
    X : array_like
        Amplitude, m or rad (> 0).
    xs : float
        fs / kt, m or rad (>= 0).
    chi, beta : float
        Density exponent (-1 < chi <= 1) and spike ratio (>= 0).
    """
    X = np.asarray(X, float)
    e = chi + 1.0
    phi_max = slip_range(xs, chi, beta)
    stuck_fraction = 1.0 / (1.0 + beta)        # continuous part of kt
    spike_fraction = beta / (1.0 + beta)       # S / kt
    full_beta = beta_function(chi + 2.5, 1.5)
    out = np.empty(X.shape, complex)

    micro = X <= phi_max
    u = X[micro] / phi_max
    ue = u**e
    out[micro] = (1.0 - 8.0 * full_beta * stuck_fraction / math.pi * ue
                  + 1j * 4.0 * e * stuck_fraction / (math.pi * (chi + 2.0) * (chi + 3.0)) * ue)

    m = phi_max / X[~micro]
    # B_m(a, 3/2) / m^(chi+1) = m^(3/2) 2F1(a, -1/2; a+1; m) / a, a = chi + 5/2: no 0/0 at m -> 0
    a = chi + 2.5
    partial = m**1.5 * hyp2f1(a, -0.5, a + 1.0, m) / a
    re_jenkins, im_jenkins = slip_real(m), slip_imag(m)
    continuous = (stuck_fraction * (re_jenkins - 8.0 / math.pi * partial)
                  + 1j * (4.0 / math.pi) * e * stuck_fraction * (m / (chi + 2.0) - m * m / (chi + 3.0)))
    out[~micro] = continuous + spike_fraction * (re_jenkins + 1j * im_jenkins)
    return out


_XS = Param("xs", "{L}", "fs / kt", lower=0.0)
_CHI = Param("chi", "1", "exponent of the slip-displacement density", lower=-1.0, upper=1.0, lower_open=True)
_BETA = Param("beta", "1", "spike ratio: stiffness of the macro-slip spike over that of the continuum", lower=0.0)


class Iwan(Law):
    name = "iwan"
    summary = "four-parameter (Segalman) Iwan joint"
    params = (Param("kt", "{F}/{L}", "stiffness while fully stuck", lower=0.0, lower_open=True),
              Param("fs", "{F}", "macro-slip force", lower=0.0),
              _CHI, _BETA)
    linear = ("kt",)
    shape = (_XS, _CHI, _BETA)
    n_state = _HEADER + 2 * MAX_REVERSALS
    hysteretic = True
    example = {"kt": 1.0e5, "fs": 10.0, "chi": -0.5, "beta": 0.1}
    example_amplitude = (1e-6, 1e-2)
    kernel = iwan_force

    def to_fit(self, values):
        return ({"kt": values["kt"]},
                {"xs": values["fs"] / values["kt"], "chi": values["chi"], "beta": values["beta"]})

    def from_fit(self, linear, shape):
        return {"kt": linear["kt"], "fs": linear["kt"] * shape["xs"],
                "chi": shape["chi"], "beta": shape["beta"]}

    def basis(self, X, w, xs, chi, beta):
        X, w = np.broadcast_arrays(X, w)
        return iwan_unit(X, xs, chi, beta)[None]
