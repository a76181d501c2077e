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
    s[4 + 2k], s[5 + 2k] reversal point k (k = 0 oldest; room for one more than the
    memory holds, pushed before a merge),
    s[134], s[135] the range of reversal points the last update wrote (:func:`iwan_update`).

At most ``MAX_REVERSALS`` = 64 nested reversal points are remembered (a slowly decaying
oscillation, or a random response followed by a steady one, piles them up). When one
more is needed, the smallest remembered loop is merged away: of the consecutive turning
points ``x_(j-1), x_j, x_(j+1)`` with the smallest gap between the same-side points
``x_(j-1)`` and ``x_(j+1)``, the three are replaced by one turning point ``x'`` between
``x_(j+1)`` and ``x_(j-1)`` on the branch that reached ``x_(j-1)``, placed so that the
branch leaving ``x'`` passes through the next remembered point. The memory is then the
exact memory of another history (the path turned at ``x'`` instead of making the
forgotten excursion): every remembered point lies on the branch from its predecessor,
so the force stays continuous (``|dF| <= kt |dx|``, as for any Jenkins ensemble) when the
path later closes loops across a merged point, and the error is that of moving one
turning point by less than the gap. The oldest point (on the virgin curve) is never
moved. Below 64 nested reversals the force is exact at every sample point (the update is
exact along any monotone path between two calls); the velocity argument is not used
(rate independent).

The kernel takes phi_max, ``chi + 1`` and ``1 / ((1 + beta)(chi + 2))`` from the parameter vector
(``Iwan.kernel_constants``, computed once) and the power ``(u / phi_max)^(chi+1)`` by a square root
or products where chi is -1/2, 0, 1/2 or 1: it runs twice per step of a simulation.
"""
from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from ..common.compiled import njit

from ._special import slip_imag, slip_real
from .base import Law, LimitForm, LimitReading, Origin, Param, broadcast
from .jenkins import Jenkins

MAX_REVERSALS = 64
SPIKE_ONLY = 1e3        # spike ratio beyond which the continuum's share of kbar is below any test's noise
_HEADER = 4  # n, direction, previous x, previous force
_WRITTEN = _HEADER + 2 * (MAX_REVERSALS + 1)  # the range of reversal points the last update wrote (room to push
#                                               one before merging)
# bisection steps placing a merged turning point (each halves the bracket; it stops early at adjacent doubles)
_BISECTIONS = 100
_N_CONTRACT = 4  # kt, fs, chi, beta; the kernel constants follow them in the parameter vector


class _Constants(NamedTuple):
    """What the kernel needs of the parameters, derived once (:meth:`Iwan.kernel_constants`)."""

    kt: float
    fs: float
    phi_max: float     # slip range
    exponent: float    # chi + 1
    curvature: float   # 1 / ((1 + beta) (chi + 2)): the backbone is kt u (1 - curvature (u / phi_max)^exponent)


def slip_range(xs, chi, beta):
    """phi_max: largest slip displacement of the population, for ``xs = fs / kt``."""
    return xs * (1.0 + beta) / (beta + (chi + 1.0) / (chi + 2.0))


@njit(cache=True)
def _power(y, exponent):
    """y ** exponent, by a square root or products for the exponents of chi = -1/2, 0, 1/2, 1 (a general power
    costs several times a square root, and the kernel takes one per call)."""
    if exponent == 0.5:
        return math.sqrt(y)
    if exponent == 1.0:
        return y
    if exponent == 1.5:
        return y * math.sqrt(y)
    if exponent == 2.0:
        return y * y
    return y ** exponent


@njit(cache=True)
def _backbone(u, c):
    """Virgin loading force at displacement u >= 0; ``c`` the kernel constants (:class:`_Constants`)."""
    if u >= c.phi_max:
        return c.fs
    return c.kt * u * (1.0 - _power(u / c.phi_max, c.exponent) * c.curvature)


@njit(cache=True)
def _virgin(x, c):
    """Force at x on the virgin curve (the backbone, odd in x)."""
    f = _backbone(abs(x), c)
    return -f if x < 0.0 else f


@njit(cache=True)
def _branch(x, x_r, f_r, direction, c):
    """Force at x on the Masing branch leaving the reversal point (x_r, f_r) in ``direction``."""
    return f_r + 2.0 * direction * _backbone(0.5 * direction * (x - x_r), c)


@njit(cache=True)
def _merge_one_loop(s, n, c):
    """Merge away the smallest remembered loop (module docstring); return the new count.

    Over the reversal points ``x_0 .. x_(n-1)`` (n >= 5), ``j`` runs over ``2 .. n-3``;
    ``x_(j-1), x_j, x_(j+1)`` become one turning point ``x'`` on the branch from ``x_(j-2)``,
    where the branch leaving ``x'`` meets point ``j + 2``. All branches have the shape
    ``2 B(u / 2)``, so a branch nested inside another in the same direction stays on its
    inner side until they meet: the mismatch at point ``j + 2`` has opposite signs (or a
    zero) at ``x' = x_(j+1)`` and ``x' = x_(j-1)``, and bisection finds ``x'`` between them.
    The virgin curve has another shape, so the oldest point is never moved.
    """
    best, best_gap = 2, math.inf
    for j in range(2, n - 2):
        gap = abs(s[_HEADER + 2 * (j + 1)] - s[_HEADER + 2 * (j - 1)])
        if gap < best_gap:
            best, best_gap = j, gap
    j = best
    x_outer, f_outer = s[_HEADER + 2 * (j - 2)], s[_HEADER + 2 * (j - 2) + 1]
    x_next, f_next = s[_HEADER + 2 * (j + 2)], s[_HEADER + 2 * (j + 2) + 1]
    lower, upper = s[_HEADER + 2 * (j + 1)], s[_HEADER + 2 * (j - 1)]
    outer_direction = 1.0 if upper > x_outer else -1.0  # the branch leaving x' runs the other way

    def mismatch(x_turn):
        f_turn = _branch(x_turn, x_outer, f_outer, outer_direction, c)
        return _branch(x_next, x_turn, f_turn, -outer_direction, c) - f_next

    m_lower, m_upper = mismatch(lower), mismatch(upper)
    # bisect while the ends bracket the root; without a sign change the root is at an end (it is there
    # exactly when the forgotten excursion saturated in macro-slip) up to round-off
    for _ in range(_BISECTIONS):
        middle = 0.5 * (lower + upper)
        if (m_lower > 0.0) == (m_upper > 0.0) or middle == lower or middle == upper:
            break
        m_middle = mismatch(middle)
        if (m_middle > 0.0) == (m_lower > 0.0):
            lower, m_lower = middle, m_middle
        else:
            upper, m_upper = middle, m_middle
    x_turn = lower if abs(m_lower) < abs(m_upper) else upper
    s[_HEADER + 2 * (j - 1)] = x_turn
    s[_HEADER + 2 * (j - 1) + 1] = _branch(x_turn, x_outer, f_outer, outer_direction, c)
    for k in range(j, n - 2):
        s[_HEADER + 2 * k] = s[_HEADER + 2 * (k + 2)]
        s[_HEADER + 2 * k + 1] = s[_HEADER + 2 * (k + 2) + 1]
    return n - 2


@njit(cache=True)
def iwan_update(x, v, p, s, out):
    """The law with its state read and written apart (:func:`_step`); the simulator calls it with C pointers."""
    return _step(x, v, p, s, out)


@njit(cache=True)
def iwan_force(x, v, p, s):
    return _step(x, v, p, s, s)


# inlined into both entries: a call across a function boundary costs more than the law's arithmetic
@njit(cache=True, inline="always")
def _step(x, v, p, s, out):
    """Force at x from the state ``s``; the state after goes to ``out``, which may be ``s`` itself.

    Only what changes is written to ``out``: the header, the written range ``out[_WRITTEN:]`` and the
    reversal points in it (the point pushed, or all after a merge). :func:`iwan_commit` copies exactly
    those, so a simulator that evaluates the law twice a step from the same committed state copies a few
    numbers instead of the whole memory. Points below the range are read from ``s``."""
    x_last, f_last = s[2], s[3]
    n = int(s[0])
    first = n  # reversal points from ``first`` on are read from (and were written to) out
    if x == x_last:
        out[0], out[1], out[2], out[3] = s[0], s[1], x_last, f_last
        out[_WRITTEN] = out[_WRITTEN + 1] = 0.0
        return f_last
    c = _Constants(p[0], p[1], p[_N_CONTRACT], p[_N_CONTRACT + 1], p[_N_CONTRACT + 2])
    direction = 1.0 if x > x_last else -1.0
    if s[1] != 0.0 and direction != s[1]:
        # x_last was a turning point: remember it
        out[_HEADER + 2 * n] = x_last
        out[_HEADER + 2 * n + 1] = f_last
        n += 1
        if n > MAX_REVERSALS:
            for i in range(_HEADER, _HEADER + 2 * first):
                out[i] = s[i]
            first = 0
            n = _merge_one_loop(out, n, c)
    written = n
    # Madelung memory: close every loop whose starting point the path has passed
    while n > 0:
        k = _HEADER + 2 * (n - 1)
        x_r = out[k] if n - 1 >= first else s[k]
        if n >= 2:
            target = out[k - 2] if n - 2 >= first else s[k - 2]
        else:
            target = -x_r
        if direction * (x - target) < 0.0:
            break
        n = n - 2 if n >= 2 else 0
    if n == 0:
        f = _virgin(x, c)
    else:
        k = _HEADER + 2 * (n - 1)
        if n - 1 >= first:
            f = _branch(x, out[k], out[k + 1], direction, c)
        else:
            f = _branch(x, s[k], s[k + 1], direction, c)
    out[0] = n
    out[1] = direction
    out[2] = x
    out[3] = f
    out[_WRITTEN] = first
    out[_WRITTEN + 1] = written
    return f


@njit(cache=True)
def iwan_commit(out, s):
    """Make ``s`` the state :func:`iwan_update` wrote into ``out``: the header and the written points."""
    for i in range(_HEADER):
        s[i] = out[i]
    lo, hi = _HEADER + 2 * int(out[_WRITTEN]), _HEADER + 2 * int(out[_WRITTEN + 1])
    for i in range(lo, hi):
        s[i] = out[i]
    s[_WRITTEN] = out[_WRITTEN]
    s[_WRITTEN + 1] = out[_WRITTEN + 1]


def iwan_unit(X, xs, chi, beta, less_stuck: bool = False) -> np.ndarray:
    """kbar / kt of the four-parameter Iwan model (complex, shape of ``X``).

    Parameters
    ----------
    X : array_like
        Amplitude, m or rad (> 0).
    xs : float
        fs / kt, m or rad (>= 0).
    chi, beta : float
        Density exponent (-1 < chi <= 1) and spike ratio (>= 0).
    less_stuck : bool
        kbar / kt - 1 instead: the departure from the stuck stiffness, computed as such below the slip range
        (where it is a power of X, subtracting 1 would lose it to round-off below 1e-16).
    """
    from scipy.special import beta as beta_function, hyp2f1    # here: `contactid laws` starts without scipy

    X = np.asarray(X, float)
    e = chi + 1.0
    phi_max = slip_range(xs, chi, beta)
    stuck_fraction = 1.0 / (1.0 + beta)        # continuous part of kt
    spike_fraction = beta / (1.0 + beta)       # S / kt
    full_beta = beta_function(chi + 2.5, 1.5)
    out = np.empty(X.shape, complex)

    stuck = 0.0 if less_stuck else 1.0         # kbar / kt with every slider stuck, or nothing of it

    micro = X <= phi_max
    u = X[micro] / phi_max
    ue = u**e
    out[micro] = (stuck - 8.0 * full_beta * stuck_fraction / math.pi * ue
                  + 1j * 4.0 * e * stuck_fraction / (math.pi * (chi + 2.0) * (chi + 3.0)) * ue)
    if micro.all():             # no element slips through: the macro-slip forms are not needed (nor paid for)
        return out

    m = phi_max / X[~micro]
    # B_m(a, 3/2) / m^(chi+1) = m^(3/2) 2F1(a, -1/2; a+1; m) / a, a = chi + 5/2: no 0/0 at m -> 0
    a = chi + 2.5
    partial = m**1.5 * hyp2f1(a, -0.5, a + 1.0, m) / a
    re_jenkins, im_jenkins = slip_real(m), slip_imag(m)
    continuous = (stuck_fraction * (re_jenkins - 8.0 / math.pi * partial)
                  + 1j * (4.0 / math.pi) * e * stuck_fraction * (m / (chi + 2.0) - m * m / (chi + 3.0)))
    out[~micro] = continuous + spike_fraction * (re_jenkins + 1j * im_jenkins) + (stuck - 1.0)
    return out


_XS = Param("xs", "{L}", "slip displacement fs / kt", lower=0.0)
_CHI = Param("chi", "1", "exponent of the slip-displacement density", lower=-1.0, upper=1.0, lower_open=True)
_BETA = Param("beta", "1", "spike ratio: stiffness of the macro-slip spike over that of the continuum", lower=0.0)


class Iwan(Law):
    name = "iwan"
    kind = "friction"
    summary = "four-parameter (Segalman) Iwan joint"
    force_text = "parallel Jenkins continuum, Masing branches with Madelung memory (below)"
    kbar_text = "closed form below"
    explanation = ("{re} and {im}: slip spreads over the contact from the smallest amplitudes -- micro-slip friction"
                   " (Iwan)")
    params = (Param("kt", "{F}/{L}", "stiffness while fully stuck", lower=0.0, lower_open=True),
              Param("fs", "{F}", "macro-slip force", lower=0.0),
              _CHI, _BETA)
    linear = ("kt",)
    shape = (_XS, _CHI, _BETA)
    n_state = _WRITTEN + 2
    hysteretic = True
    example = {"kt": 1.0e5, "fs": 10.0, "chi": -0.5, "beta": 0.1}
    example_amplitude = (1e-6, 1e-2)
    kernel = iwan_force
    update = iwan_update
    commit = iwan_commit

    def kernel_constants(self, kt, fs, chi, beta):
        return slip_range(fs / kt, chi, beta), chi + 1.0, 1.0 / ((1.0 + beta) * (chi + 2.0))

    def to_fit(self, values):
        return ({"kt": values["kt"]},
                {"xs": values["fs"] / values["kt"], "chi": values["chi"], "beta": values["beta"]})

    def from_fit(self, linear, shape):
        return {"kt": linear["kt"], "fs": linear["kt"] * shape["xs"],
                "chi": shape["chi"], "beta": shape["beta"]}

    def limit_forms(self, X_max):
        return (MicroSlip(X_max, self.from_reference, self.origin),)

    def small_amplitude_basis(self, xs, chi, beta):
        return np.ones(1)       # every slider stuck: the whole stiffness kt

    def basis(self, X, w, xs, chi, beta):
        X, w = broadcast(X, w)
        return iwan_unit(X, xs, chi, beta)[None]

    def basis_from_small_amplitude(self, X, w, xs, chi, beta):
        X, w = broadcast(X, w)
        return iwan_unit(X, xs, chi, beta, less_stuck=True)[None]

    def reading(self, values, X_min, X_max):
        """Micro-slip where no element slips through at the largest amplitude (``X_max <= phi_max``): the
        micro-slip forms are then exact (module docstring), kbar = kt [1 - r(chi) (nu / (pi kt)) X^(chi+1)]
        + j (nu / pi) X^(chi+1) with r(chi) = 2 B(chi + 5/2, 3/2) (chi + 2)(chi + 3) / (chi + 1), so the data
        determine kt, chi and the dissipation per cycle nu X^(chi+3), nu = 4 R / ((chi + 2)(chi + 3)), and fs
        and beta only through nu; measured from the reference (:meth:`Law.relative`), kbar - kt leaves kt
        undetermined too, only chi and nu. Beside nu the reading gives D, the dissipation per cycle at the largest
        amplitude measured (nu X_max^(chi+3)): nu is its value at a unit amplitude, decades away from the data, and
        so correlates with chi beyond any use, where D at the data's edge does not; the micro-slip form
        (:class:`MicroSlip`) is fitted in D, whose error is the one printed. Coulomb friction where the whole
        population slips a decade below the smallest amplitude (``X_min >= 10 phi_max``): kbar is then within a few per cent of 4 j fs / (pi X) and
        only fs is determined. First of all, a Jenkins element where the spike carries all but 1/SPIKE_ONLY of the
        stiffness (the continuum's share of kbar below any test's noise): kt and fs of the spike are determined, chi
        and beta not, whatever the amplitudes -- and that element is read in its own limit where it has one
        (Coulomb friction where the spike slips from a tenth of the smallest amplitude on: then only fs is
        determined). Measured from the reference, where nothing slips through, the continuum is read whatever the
        spike's share: the stuck stiffness is then the reference's and never seen, so the continuum is not
        negligible beside it, and all the data see is the continuum's micro-slip, kbar - kt = its departure."""
        kt, fs, chi, beta = (float(values[k]) for k in ("kt", "fs", "chi", "beta"))
        phi_max = float(slip_range(fs / kt, chi, beta))
        stuck_stiffness_unseen = self.from_reference and X_max <= phi_max
        if beta >= SPIKE_ONLY and not stuck_stiffness_unseen:
            spike = beta * kt / (1.0 + beta)
            alone = f"the spike carries all but 1/{1.0 + beta:.3g} of the stiffness, the continuum below any test's noise"
            gross = Jenkins().reading({"kt": spike, "fs": spike * phi_max}, X_min, X_max)
            if gross is not None:
                return LimitReading(gross.limit, gross.values, gross.units, f"{alone}; {gross.why}",
                                    ("kt", "chi", "beta"))
            return LimitReading(
                "Jenkins element", {"kt": spike, "fs": spike * phi_max}, {"kt": "{F}/{L}", "fs": "{F}"},
                f"{alone}: one slider of stiffness kt slipping at fs", ("chi", "beta"))
        if X_max <= phi_max:
            rate = kt * (chi + 1.0) / ((1.0 + beta) * phi_max ** (chi + 1.0))
            nu = 4.0 * rate / ((chi + 2.0) * (chi + 3.0))
            D = float(nu * X_max ** (chi + 3.0))
            nu_unit = f"{{F}}/{{L}}^{chi + 2.0:.4g}"
            if self.from_reference:         # kbar - kt: the stiffness kt itself is the reference's
                return LimitReading(
                    "micro-slip", {"chi": chi, "nu": nu, "D": D}, {"chi": "1", "nu": nu_unit, "D": "{F}·{L}"},
                    f"no part of the contact slips through at the largest amplitude (slip range {phi_max:.3g} "
                    f"against {X_max:.3g}), and the stuck stiffness is the reference's: the data determine the "
                    f"dissipation per cycle, D (X / {X_max:.3g})^(chi+3), and the softening that goes with it",
                    ("kt", "fs", "beta"))
            return LimitReading(
                "micro-slip", {"kt": kt, "chi": chi, "nu": nu, "D": D},
                {"kt": "{F}/{L}", "chi": "1", "nu": nu_unit, "D": "{F}·{L}"},
                f"no part of the contact slips through at the largest amplitude (slip range {phi_max:.3g} against "
                f"{X_max:.3g}): the dissipation per cycle is D (X / {X_max:.3g})^(chi+3)",
                ("fs", "beta"))
        if X_min >= 10.0 * phi_max:
            return LimitReading(
                "Coulomb friction", {"fs": fs}, {"fs": "{F}"},
                f"the whole contact slips from a tenth of the smallest amplitude on (slip range {phi_max:.3g} "
                f"against {X_min:.3g}): kbar is a dry friction's, 4 j fs / (pi X)",
                ("kt", "chi", "beta"))
        return None


#: Where the stuck stiffness is the reference's, micro-slip leaves the slip range open above the largest amplitude
#: measured; the model places it this many times beyond, so that it carries the power law the data determine over
#: the decade a prediction may reach, as the Coulomb reading takes a decade for "far" (:meth:`Iwan.reading`)
SLIP_RANGE_BEYOND = 10.0


class MicroSlip(LimitForm):
    """The Iwan joint in micro-slip up to the largest amplitude ``X_max`` of the data: no element slips through,
    and kbar = kt + D (X / X_max)^(chi+1) (-r(chi) + j) / (pi X_max^2) (:meth:`Iwan.reading`), D the dissipation
    per cycle at X_max. Measured from the reference (``relative``) kt is the reference's, and the form is
    D and chi alone; measured from an ``origin`` as well, it is less the spring and damper of its kbar there, as
    the Iwan it places back is (:meth:`analysis.laws.base.Law.relative`).

    Placed back in the Iwan (:meth:`law_values`) with no spike (beta = 0, the continuum alone): with kt known the
    continuum's slip range follows from D, and the form has no Iwan where it falls below X_max (the data ask for
    more dissipation than a contact of stiffness kt can give without slipping through); where kt is not seen --
    measured from the reference, or determined only in a sum with a linear spring beside it -- the slip range
    is put SLIP_RANGE_BEYOND times X_max, and kt follows from it."""

    name = "iwan"
    kind = "friction"
    summary = "the Iwan joint's micro-slip limit"
    kbar_text = "kt + D (X / X_max)^(chi+1) (-r(chi) + j) / (pi X_max^2)"
    params = (Param("kt", "{F}/{L}", "stiffness while fully stuck", lower=0.0, lower_open=True), _CHI,
              Param("D", "{F}·{L}", "dissipation per cycle at the largest amplitude measured", lower=0.0))
    linear = ("kt", "D")
    shape = (_CHI,)
    example = {"kt": 1.0e5, "chi": -0.5, "D": 1e-6}
    stiffness = "kt"

    def __init__(self, X_max: float, relative: bool = False, origin: Origin | None = None):
        self.X_max = float(X_max)
        self.from_reference = relative
        self.origin = origin if relative else None
        if relative:
            self.params = self.params[1:]
            self.linear = ("D",)
            self.example = {"chi": -0.5, "D": 1e-6}
            self.stiffness = None

    def relative(self, origin: Origin | None = None) -> "MicroSlip":
        return self if self.from_reference and origin == self.origin else MicroSlip(self.X_max, True, origin)

    def small_amplitude_basis(self, chi):
        return None if self.from_reference else np.array([1.0, 0.0])

    def basis(self, X, w, chi):
        X, w = broadcast(X, w)
        # the Iwan's own departure below its slip range, at no spike and the slip range X_max, per unit D
        xs = self.X_max * (chi + 1.0) / (chi + 2.0)
        per_kt = self.X_max ** 2 * 4.0 * (chi + 1.0) / ((chi + 2.0) * (chi + 3.0))     # D / kt there
        departure = iwan_unit(X, xs, chi, 0.0, less_stuck=True) / per_kt
        if not self.from_reference:
            return np.stack([np.ones(X.shape, complex), departure])
        if self.origin is None:
            return departure[None]
        at_origin = iwan_unit(np.array([self.origin.X]), xs, chi, 0.0, less_stuck=True) / per_kt
        return self.origin.less(departure[None], at_origin, w)

    def law_values(self, values, stiffness_seen=True):
        chi, D = float(values["chi"]), float(values["D"])
        e = chi + 1.0
        rate = D / self.X_max ** (chi + 3.0) * (chi + 2.0) * (chi + 3.0) / 4.0    # R of the continuum
        if not (rate > 0.0 and math.isfinite(rate)):
            return None
        if self.from_reference or not stiffness_seen:
            phi_max = SLIP_RANGE_BEYOND * self.X_max
            kt = rate * phi_max ** e / e
        else:
            kt = float(values["kt"])
            # near chi = -1 the power is large: a slip range beyond any float is no Iwan that can be placed
            with np.errstate(over="ignore"):
                phi_max = float(np.power(kt * e / rate, 1.0 / e))
            if not (phi_max >= self.X_max and math.isfinite(phi_max)):
                return None
        return {"kt": kt, "fs": kt * phi_max * e / (chi + 2.0), "chi": chi, "beta": 0.0}
