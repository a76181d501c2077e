"""Describing functions of the element laws against quadrature of their own time-domain kernels.

For x = X sin(t), kbar = (A1 + j B1) / X with A1, B1 the Fourier coefficients of the
force over one period. The period is split at the monotone segments (t = pi/2, 3pi/2),
at x = 0 and at every kink of the law, and each piece is integrated adaptively
(scipy.integrate.quad, relative tolerance 1e-12). Hysteretic laws are marched from rest;
within a monotone segment the force at any phase is the kernel applied to a copy of the
state at the segment start, which is exact for rate-independent laws; the second cycle
is integrated.
"""
from __future__ import annotations

import math
import pickle

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.integrate import quad
from scipy.special import beta as beta_function

from analysis.laws import LAWS
from analysis.laws.base import Origin
from analysis.laws.iwan import MAX_REVERSALS, iwan_unit, slip_range
from analysis.laws.jenkins import jenkins_unit
from analysis.laws.tanh_softening import tanh_fundamental

TOLERANCE = 1e-6
HALF_PI = 0.5 * math.pi


# --------------------------------------------------------------------------- quadrature
def _fourier(force, edges, X, floor):
    """(A1 + j B1) / X of ``force(t)`` over the pieces between consecutive ``edges``."""
    a1 = b1 = 0.0
    for lo, hi in zip(edges[:-1], edges[1:]):
        opts = dict(epsabs=floor, epsrel=1e-12, limit=400)
        a1 += quad(lambda t: force(t) * math.sin(t), lo, hi, **opts)[0]
        b1 += quad(lambda t: force(t) * math.cos(t), lo, hi, **opts)[0]
    return (a1 + 1j * b1) / (math.pi * X)


def _edges(start, stop, extra):
    grid = set(np.arange(start, stop + 1e-12, HALF_PI).tolist()) | {start, stop}
    grid |= {t for t in extra if start < t < stop}
    return np.array(sorted(grid))


def _turning_phase_kinks(phases, X, slip):
    """Phases where a Masing branch from a turning point starts to slip: |x - x_r| = 2 slip."""
    if X <= slip:
        return []
    psi = 2.0 * math.asin(math.sqrt(slip / X))  # cos(psi) = 1 - 2 slip / X
    return [t + psi for t in phases]


def _law_breakpoints(name, X, values):
    """Phases in [0, 2 pi) of the kinks (and steep layers) of a memoryless law."""
    def at_level(level):  # phases where x = level
        if abs(level) >= X:
            return []
        t = math.asin(level / X)
        return [t % (2 * math.pi), math.pi - t]

    if name == "gap":
        return at_level(values["gap"]) + at_level(-values["gap"])
    if name == "unilateral":
        return at_level(values["gap"])
    if name in ("tanh_softening", "arctan_softening"):
        # not kinks, but the layer |beta x| < 30 where the force turns over is thin at large beta X
        levels = np.array([1e-2, 1e-1, 1.0, 3.0, 10.0, 30.0]) / values["beta"]
        return [t for level in np.concatenate((levels, -levels)) for t in at_level(level)]
    return []


def kbar_by_quadrature(name, values, X, w, law=None):
    """kbar of law ``name`` (or of ``law``, a form of it) at amplitude X and frequency w from its own kernel."""
    law = LAWS[name] if law is None else law
    p = law.parameter_vector(**values)
    floor = 1e-13 * X * max(abs(complex(law.describing_function(X, w, **values))), 1e-300)

    def motion(t):
        return X * math.sin(t), X * w * math.cos(t)

    if not law.hysteretic:
        scratch = law.initial_state(p)
        return _fourier(lambda t: law.kernel(*motion(t), p, scratch),
                        _edges(0.0, 2 * math.pi, _law_breakpoints(name, X, values)), X, floor)

    # march from rest to every turning point of the first two cycles
    turning = [HALF_PI, 3 * HALF_PI, 5 * HALF_PI, 7 * HALF_PI]
    state = law.initial_state(p)
    segment_state = {}
    for t in turning:
        law.kernel(*motion(t), p, state)
        segment_state[t] = state.copy()

    def force(t):
        start = max(s for s in turning if s <= t)
        return law.kernel(*motion(t), p, segment_state[start].copy())

    slip = values["fs"] / values["kt"]
    if name == "iwan":
        slip = slip_range(slip, values["chi"], values["beta"])
    kinks = _turning_phase_kinks(turning[1:], X, slip)
    return _fourier(force, _edges(2 * math.pi, 4 * math.pi, kinks), X, floor)


def worst_relative_error(name, values, X, w):
    df = LAWS[name].describing_function(X[:, None], w[None, :], **values)
    quad_values = np.array([[kbar_by_quadrature(name, values, x, f) for f in w] for x in X])
    return float(np.max(np.abs(quad_values - df) / np.abs(df)))


def decades(center, below, above, n=9):
    return center * np.logspace(-below, above, n)


W_ONE = np.array([1.0])
W_MANY = np.array([0.5, 40.0, 3000.0])

# (law, parameters, amplitudes spanning >= 4 decades, frequencies)
CASES = [
    ("linear", {"k": 1.0e4, "c": 5.0}, decades(1e-3, 3, 2), W_MANY),
    ("cubic", {"k3": -5.0e2}, decades(1e-1, 3, 2), W_ONE),
    ("quintic", {"k5": 1.0e8}, decades(1e-2, 3, 2), W_ONE),
    ("quadratic_damping", {"c2": 10.0}, decades(1e-3, 3, 2), W_MANY),
    ("cubic_damping", {"c3": 10.0}, decades(1e-3, 3, 2), W_MANY),
    ("coulomb", {"fs": 1.0}, decades(1e-3, 3, 2), W_MANY),
    ("tanh_softening", {"alpha": 10.0, "beta": 1.0e3}, decades(1e-3, 4, 4, 13), W_ONE),
    ("arctan_softening", {"alpha": 10.0, "beta": 1.0e3}, decades(1e-3, 4, 4, 13), W_ONE),
    ("velocity_stiffness", {"gamma": -2.5}, decades(1e-3, 3, 2), W_MANY),
    ("anderson_ferri", {"a": 1.0, "b": 500.0, "c": 2.0}, decades(1e-3, 3, 2), W_MANY),
    ("jenkins", {"kt": 1.0e5, "fs": 10.0}, decades(1e-4, 2, 3, 11), W_ONE),
    ("iwan", {"kt": 1.0e5, "fs": 10.0, "chi": -0.5, "beta": 0.1}, decades(1e-4, 3, 3, 11), W_ONE),
    ("iwan", {"kt": 1.0e5, "fs": 10.0, "chi": 0.0, "beta": 0.0}, decades(1e-4, 3, 2), W_ONE),
    ("iwan", {"kt": 1.0e5, "fs": 10.0, "chi": -0.9, "beta": 1.0}, decades(1e-4, 3, 2), W_ONE),
    ("iwan", {"kt": 1.0e5, "fs": 10.0, "chi": 0.7, "beta": 0.3}, decades(1e-4, 3, 2), W_ONE),
    # amplitudes just past the clearance up to far beyond it: X - gap spans 8 decades
    ("gap", {"k": 1.0e5, "gap": 1.0e-4}, 1.0e-4 * (1 + np.logspace(-4, 4, 9)), W_ONE),
    ("unilateral", {"k": 1.0e5, "gap": 1.0e-4}, 1.0e-4 * (1 + np.logspace(-4, 4, 9)), W_ONE),
    ("unilateral", {"k": 1.0e5, "gap": -1.0e-4}, decades(1e-4, 2, 3), W_ONE),
    ("bilinear", {"k_pos": 2.0e4, "k_neg": 1.0e4}, decades(1e-3, 3, 2), W_ONE),
]


@pytest.mark.parametrize("name, values, X, w", CASES, ids=[f"{c[0]}-{i}" for i, c in enumerate(CASES)])
def test_describing_function_matches_quadrature_of_its_kernel(name, values, X, w):
    assert np.log10(X.max() / X.min()) >= 4 or name in ("gap", "unilateral")
    assert worst_relative_error(name, values, X, w) <= TOLERANCE


def test_every_law_is_checked_against_quadrature():
    assert {c[0] for c in CASES} == set(LAWS)


RELATIVE = [c for c in CASES if LAWS[c[0]].relative() is not LAWS[c[0]]]


@pytest.mark.parametrize("name, values, X, w", RELATIVE, ids=[f"{c[0]}-{i}" for i, c in enumerate(RELATIVE)])
def test_a_law_measured_from_the_reference_is_its_kernel_less_its_small_amplitude_stiffness(name, values, X, w):
    """docs/laws.md, "Measured from the reference": the relative form's describing function is the quadrature of
    its own kernel (f - k0 x), and k0 is the limit of the law's Re kbar as X -> 0."""
    law, relative = LAWS[name], LAWS[name].relative()
    assert (relative.name, relative.params, relative.from_reference, law.from_reference) == \
        (law.name, law.params, True, False)
    absolute = law.describing_function(X[:, None], w[None, :], **values)
    df = relative.describing_function(X[:, None], w[None, :], **values)
    quadrature = np.array([[kbar_by_quadrature(name, values, x, f, relative) for f in w] for x in X])
    assert np.max(np.abs(quadrature - df) / np.abs(absolute)) <= TOLERANCE
    k0, c = relative.parameter_vector(**values)[-2:]
    np.testing.assert_allclose(absolute - df, k0, rtol=1e-12)
    assert c == 0.0         # a damper only where the law is measured from an origin
    tiny = law.describing_function(1e-40 * X.min(), w, **values)     # X^(chi+1) falls slowly for chi near -1
    assert np.all(np.abs(tiny.real / k0 - 1) < 1e-2) and np.all(np.abs(tiny.imag) < 1e-2 * k0)


FROM_ORIGIN = [c for c in CASES if LAWS[c[0]].amplitude_dependent and not LAWS[c[0]].placed]


@pytest.mark.parametrize("name, values, X, w", FROM_ORIGIN, ids=[f"{c[0]}-{i}" for i, c in enumerate(FROM_ORIGIN)])
def test_a_law_measured_from_an_origin_is_its_kernel_less_the_spring_and_damper_of_its_kbar_there(name, values, X,
                                                                                                   w):
    """docs/laws.md, "Measured from the reference": measured from the element's state at an origin (X0, w0), a
    law's describing function is the quadrature of its own kernel (f - k x - c v), it vanishes at the origin, and
    it differs from the law's own by the spring and damper that equal the law's kbar at the origin (less k0, which
    the form from no amplitude takes off already), k + j c w with c = Im / w0."""
    X0, w0 = float(np.sqrt(X.min() * X.max())), 1.3 * float(w.mean())
    origin = Origin(X0, w0)
    law, measured = LAWS[name], LAWS[name].relative(origin)
    assert (measured.name, measured.params, measured.from_reference, measured.origin) == \
        (law.name, law.params, True, origin)
    assert pickle.loads(pickle.dumps(measured)) is measured and measured.relative() is law.relative()
    at_origin = complex(law.relative().describing_function(X0, w0, **values))
    assert at_origin != 0.0
    df = measured.describing_function(X[:, None], w[None, :], **values)
    expected = law.relative().describing_function(X[:, None], w[None, :], **values) - (
        at_origin.real + 1j * at_origin.imag * w[None, :] / w0)
    np.testing.assert_allclose(df, expected, rtol=1e-12, atol=1e-12 * abs(at_origin))
    assert abs(complex(measured.describing_function(X0, w0, **values))) <= 1e-12 * abs(at_origin)
    absolute = law.describing_function(X[:, None], w[None, :], **values)
    quadrature = np.array([[kbar_by_quadrature(name, values, x, f, measured) for f in w] for x in X])
    assert np.max(np.abs(quadrature - df) / np.maximum(np.abs(absolute), abs(at_origin))) <= TOLERANCE
    k, c = measured.parameter_vector(**values)[-2:]
    k0 = law.relative().parameter_vector(**values)[-2] if law.relative() is not law else 0.0
    np.testing.assert_allclose([k, c * w0], [k0 + at_origin.real, at_origin.imag], rtol=1e-12)


def test_a_viscous_term_measured_from_an_origin_is_none_and_a_fit_leaves_it_at_zero():
    """The origin's damper is the law's own viscous term: Anderson-Ferri's ``c |x'| sgn(x') = c x'`` gives
    ``j c w``, which the damper equal to the law's kbar at the origin cancels at every line. Its basis column is
    then exactly zero, not the rounding left of ``j c w - j c w0 (w / w0)``, which a fit scaling its columns to
    unit length would take for a direction (it had put c at 2.5e14 +- 8.5e14, a time-domain force of
    rounding); the fit reports c as not identifiable and leaves it at zero, and the kbar is the same."""
    from analysis.fitting.fit import fit_laws

    X, w = np.geomspace(1e-6, 1e-4, 30), np.linspace(490.0, 510.0, 30)
    measured = LAWS["anderson_ferri"].relative(Origin(1e-5, 500.0))
    B = measured.basis(X, w)
    assert np.all(B[2] == 0.0) and np.all(np.abs(B[:2]).max(axis=1) > 0)
    truth = {"a": 0.3, "b": 40.0, "c": 2.0}
    kbar = measured.describing_function(X, w, **truth)
    fit = fit_laws([measured], X, w, kbar, 1e-3 * np.abs(kbar).max())
    term = fit.terms[0]
    assert term.params["c"] == 0.0 and term.stderr["c"] == np.inf
    assert {"a": term.params["a"], "b": term.params["b"]} == pytest.approx({"a": 0.3, "b": 40.0}, rel=1e-6)


def test_amplitude_independent_and_placed_laws_are_measured_as_before_whatever_the_origin():
    """A linear law measured from an origin would vanish (it corrects the reference itself), and a contact placed
    in its structure has its balance's kbar at the origin, which no spring and damper carry."""
    origin = Origin(1e-5, 500.0)
    for law in LAWS.values():
        if law.placed or not law.amplitude_dependent:
            assert law.relative(origin) is law.relative()


def test_the_laws_with_a_small_amplitude_stiffness_are_the_softening_and_stuck_ones():
    """The rest have none to subtract (their kbar vanishes as X -> 0, or a slider holds rigidly): their form
    measured from the reference is the law itself."""
    assert {n for n, law in LAWS.items() if law.relative() is not law} == \
        {"tanh_softening", "arctan_softening", "jenkins", "iwan"}
    assert all(law.relative().relative() is law.relative() for law in LAWS.values())


# --------------------------------------------------------------------------- softening laws
def tanh_fundamental_by_series(z):
    """G(z) from the partial-fraction series of tanh with an Euler-Maclaurin tail.

    G = (4/z^2) sum_n [1 - c_n / sqrt(c_n^2 + z^2)], c_n = (n - 1/2) pi; the terms are
    written as z^2 / (r (r + c)) to avoid cancellation; the tail beyond N terms is the
    integral from N + 1/2 plus the midpoint Euler-Maclaurin correction f'(N + 1/2) / 24.
    """
    n_terms = int(64 + 8 * z)
    c = (np.arange(1, n_terms + 1) - 0.5) * math.pi
    r = np.sqrt(c * c + z * z)
    head = math.fsum(1.0 / (r * (r + c)))
    cn, rn = math.pi * n_terms, math.hypot(math.pi * n_terms, z)
    tail = 1.0 / (math.pi * (rn + cn)) - (math.pi / 24.0) / rn**3
    return 4.0 * (head + tail)


@pytest.mark.parametrize("z", np.logspace(-3, 5, 17))
def test_tanh_quadrature_matches_exact_series(z):
    assert tanh_fundamental(z) == pytest.approx(tanh_fundamental_by_series(z), rel=1e-10)


def test_tanh_fundamental_is_the_series_on_both_sides_of_where_its_large_amplitude_expansion_takes_over():
    z = np.array([150.0, 199.9, 200.0, 200.1, 260.0, 1e4, 1e8])
    exact = np.array([tanh_fundamental_by_series(v) for v in z[:-1]] + [4 / (math.pi * 1e8)])
    np.testing.assert_allclose(tanh_fundamental(z), exact, rtol=1e-13)
    # samples on both sides at once: each is evaluated as alone
    np.testing.assert_allclose(tanh_fundamental(z), [tanh_fundamental(np.array([v]))[0] for v in z], rtol=1e-15)


@pytest.mark.parametrize("name, z4", [("tanh_softening", 1 / 12), ("arctan_softening", 1 / 8)])
def test_a_saturating_spring_measured_from_the_reference_keeps_its_departure_at_the_smallest_amplitudes(name, z4):
    """kbar - alpha beta = alpha beta (-z^2/4 + c z^4 + O(z^6)), z = beta X, from the laws' Taylor series (tanh
    u = u - u^3/3 + ..., arctan's closed form): computed as such down to z = 1e-9, where the subtraction keeps
    nothing of it, and the same as the subtraction where that is exact enough."""
    law = LAWS[name].relative()
    alpha, beta = 2.0, 1.0e3
    z = np.geomspace(1e-9, 1e-3, 7)
    kbar = law.describing_function(z / beta, 1.0, alpha=alpha, beta=beta)
    np.testing.assert_allclose(kbar.real, alpha * beta * (-z ** 2 / 4 + z4 * z ** 4), rtol=1e-12)
    assert not kbar.imag.any()
    z = np.array([0.05, 0.0999, 0.1, 0.1001, 0.2, 1.0, 30.0, 500.0])
    whole = LAWS[name].describing_function(z / beta, 1.0, alpha=alpha, beta=beta).real - alpha * beta
    np.testing.assert_allclose(law.describing_function(z / beta, 1.0, alpha=alpha, beta=beta).real, whole, rtol=1e-11)


@pytest.mark.parametrize("name", ["tanh_softening", "arctan_softening"])
def test_softening_laws_small_amplitude_limit(name):
    alpha, beta = 3.0, 250.0
    X = np.array([1e-5, 1e-4, 1e-3]) / beta
    kbar = LAWS[name].describing_function(X, 1.0, alpha=alpha, beta=beta)
    limit = alpha * beta - alpha * beta**3 * X**2 / 4
    # the next term is O((beta X)^4) relative
    assert np.all(np.abs(kbar - limit) / (alpha * beta) <= 1e-11)


@pytest.mark.parametrize("name", ["tanh_softening", "arctan_softening"])
def test_softening_laws_large_amplitude_limit(name):
    alpha, beta, X = 3.0, 250.0, 1e6 / 250.0
    saturation = {"tanh_softening": alpha, "arctan_softening": 0.5 * math.pi * alpha}[name]
    kbar = LAWS[name].describing_function(X, 1.0, alpha=alpha, beta=beta)
    # a saturated force F sgn(x) has kbar = 4 F / (pi X)
    assert kbar.real == pytest.approx(4 * saturation / (math.pi * X), rel=1e-5)


def test_paper_eq34_is_the_arctan_law_and_overestimates_tanh_by_26_percent():
    alpha, beta = 53.67, 15.92  # paper Table 3, load case a
    X = 4.0 / beta
    corrected_eq34 = 2 * alpha * (math.sqrt((beta * X) ** 2 + 1) - 1) / (beta * X**2)
    arctan = LAWS["arctan_softening"].describing_function(X, 1.0, alpha=alpha, beta=beta).real
    tanh = LAWS["tanh_softening"].describing_function(X, 1.0, alpha=alpha, beta=beta).real
    assert arctan == pytest.approx(corrected_eq34, rel=1e-14)
    assert arctan / tanh - 1 == pytest.approx(0.2612, abs=5e-4)


# --------------------------------------------------------------------------- jenkins, iwan
def test_jenkins_is_stuck_below_the_slip_displacement_and_sliding_far_above():
    law = LAWS["jenkins"]
    kt, fs = 2.0e5, 4.0
    xs = fs / kt
    assert law.describing_function(0.999 * xs, 1.0, kt=kt, fs=fs) == kt
    X = 1e4 * xs
    kbar = law.describing_function(X, 1.0, kt=kt, fs=fs)
    assert kbar.imag == pytest.approx(4 * fs / (math.pi * X) * (1 - xs / X), rel=1e-14)
    # Re -> (kt/pi)(2 psi^3/3) with psi = 2 sqrt(xs/X): 16 kt (xs/X)^1.5 / (3 pi)
    assert kbar.real == pytest.approx(16 * kt * (xs / X) ** 1.5 / (3 * math.pi), rel=1e-3)


def test_iwan_uniform_density_reduces_to_the_classical_microslip_result():
    kt, fs = 1.0e5, 10.0
    phi = slip_range(fs / kt, 0.0, 0.0)
    assert phi == pytest.approx(2 * fs / kt)  # uniform density: fs = kt phi / 2
    X = np.geomspace(1e-4, 1.0, 9) * phi
    kbar = LAWS["iwan"].describing_function(X, 1.0, kt=kt, fs=fs, chi=0.0, beta=0.0)
    assert np.allclose(kbar.real, kt * (1 - X / (2 * phi)), rtol=1e-13)
    assert np.allclose(kbar.imag, 2 * kt * X / (3 * math.pi * phi), rtol=1e-13)


def _iwan_c_chi(chi: float) -> float:
    """c(chi) = int_0^1 s^chi ReJ(s) ds by quadrature, with s = (1 - cos psi)/2 (ReJ: the unit Jenkins element)."""
    def integrand(psi):
        s = 0.5 * (1 - math.cos(psi))
        return s**chi * (psi - 0.5 * math.sin(2 * psi)) / math.pi * 0.5 * math.sin(psi)

    return quad(integrand, 0.0, math.pi, epsabs=0, epsrel=1e-13, limit=200)[0]


@pytest.mark.parametrize("chi, beta", [(-0.5, 0.1), (0.0, 0.0), (-0.95, 2.0), (1.0, 0.5)])
def test_iwan_microslip_matches_the_density_integral(chi, beta):
    """Re = R X^(chi+1) c(chi) + R (phi_max^(chi+1) - X^(chi+1))/(chi+1) + S, with c(chi) by quadrature."""
    kt, fs = 1.0e5, 10.0
    phi = slip_range(fs / kt, chi, beta)
    R = kt * (chi + 1) / ((1 + beta) * phi ** (chi + 1))
    S = beta * kt / (1 + beta)

    c_chi = _iwan_c_chi(chi)
    assert c_chi == pytest.approx((1 - 8 * beta_function(chi + 2.5, 1.5) / math.pi) / (chi + 1), rel=1e-11)
    X = np.geomspace(1e-4, 1.0, 7) * phi
    real = R * X ** (chi + 1) * c_chi + R * (phi ** (chi + 1) - X ** (chi + 1)) / (chi + 1) + S
    imag = 4 * R * X ** (chi + 1) / (math.pi * (chi + 2) * (chi + 3))
    kbar = LAWS["iwan"].describing_function(X, 1.0, kt=kt, fs=fs, chi=chi, beta=beta)
    assert np.allclose(kbar.real, real, rtol=1e-10)
    assert np.allclose(kbar.imag, imag, rtol=1e-10)


@pytest.mark.parametrize("chi, beta", [(-0.5, 0.1), (0.15, 20.0), (1.0, 0.0)])
def test_iwan_measured_from_the_reference_keeps_its_micro_slip_departure_at_any_stiffness(chi, beta):
    """The Iwan element less its stuck stiffness, below the slip range: Re = R X^(chi+1) (c(chi) - 1/(chi+1)),
    Im as above (the density integral, c(chi) by quadrature), to 1e-10 down to X = 1e-20 phi_max and with kt =
    1e18 -- where kbar less kt by subtraction keeps nothing of a departure below 1e-16 of kt."""
    kt, fs = 1.0e18, 1.0e13
    phi = slip_range(fs / kt, chi, beta)
    R = kt * (chi + 1) / ((1 + beta) * phi ** (chi + 1))

    c_chi = _iwan_c_chi(chi)
    X = np.geomspace(1e-20, 0.5, 9) * phi
    real = R * X ** (chi + 1) * (c_chi - 1 / (chi + 1))
    imag = 4 * R * X ** (chi + 1) / (math.pi * (chi + 2) * (chi + 3))
    kbar = LAWS["iwan"].relative().describing_function(X, 1.0, kt=kt, fs=fs, chi=chi, beta=beta)
    np.testing.assert_allclose(kbar.real, real, rtol=1e-10)
    np.testing.assert_allclose(kbar.imag, imag, rtol=1e-10)
    # slipping through, it is the law less kt (the macro-slip forms subtract it)
    X = np.array([1.5, 4.0, 30.0]) * phi
    np.testing.assert_allclose(LAWS["iwan"].relative().describing_function(X, 1.0, kt=kt, fs=fs, chi=chi, beta=beta),
                               LAWS["iwan"].describing_function(X, 1.0, kt=kt, fs=fs, chi=chi, beta=beta) - kt,
                               rtol=1e-12)


GAUSS_400 = np.polynomial.legendre.leggauss(400)


def _iwan_population(phi_max, chi, beta, kt, kinks=()):
    """Jenkins elements (stiffness, slip displacement) discretising the Iwan density.

    In t = (phi / phi_max)^(chi+1) the continuous density is uniform with total stiffness
    kt / (1 + beta); 400 Gauss-Legendre nodes on each interval between ``kinks`` (slip
    displacements where an element's describing function has a kink), plus the spike.
    """
    e = chi + 1
    edges = np.unique(np.clip(np.concatenate(([0.0, 1.0], (np.asarray(kinks) / phi_max) ** e)), 0, 1))
    nodes, weights = GAUSS_400
    t = np.concatenate([0.5 * (b - a) * nodes + 0.5 * (b + a) for a, b in zip(edges[:-1], edges[1:])])
    wt = np.concatenate([0.5 * (b - a) * weights for a, b in zip(edges[:-1], edges[1:])])
    stiffness = np.append(wt * kt / (1 + beta), beta * kt / (1 + beta))
    slip = np.append(phi_max * t ** (1 / e), phi_max)
    return stiffness, slip


@pytest.mark.parametrize("chi, beta", [(-0.5, 0.1), (0.0, 0.0), (-0.9, 1.0), (0.7, 0.3)])
def test_iwan_matches_a_discretised_jenkins_ensemble(chi, beta):
    kt, fs = 1.0e5, 10.0
    phi = slip_range(fs / kt, chi, beta)
    for X in np.geomspace(1e-3, 1e2, 11) * phi:
        stiffness, slip = _iwan_population(phi, chi, beta, kt, kinks=[X])
        ensemble = np.sum(stiffness * jenkins_unit(X, slip))
        kbar = complex(LAWS["iwan"].describing_function(X, 1.0, kt=kt, fs=fs, chi=chi, beta=beta))
        assert abs(ensemble - kbar) <= 1e-8 * abs(kbar)


def test_iwan_large_amplitude_is_coulomb_sliding_at_the_macroslip_force():
    kt, fs = 1.0e5, 10.0
    X = 1e6 * fs / kt
    kbar = LAWS["iwan"].describing_function(X, 1.0, kt=kt, fs=fs, chi=-0.5, beta=0.2)
    assert kbar.imag == pytest.approx(4 * fs / (math.pi * X), rel=1e-5)


def _march_ensemble(stiffness, slip, history):
    """Force of parallel Jenkins elements along the sampled history (exact on monotone steps)."""
    z = np.zeros_like(stiffness)
    limit = stiffness * slip
    out = np.empty(len(history))
    for i, x in enumerate(history):
        f = np.clip(stiffness * (x - z), -limit, limit)
        z = x - f / stiffness
        out[i] = f.sum()
    return out


def _monotone_history(turning_points, samples_per_leg=5):
    legs = [np.linspace(a, b, samples_per_leg + 1)[1:] for a, b in zip(turning_points[:-1], turning_points[1:])]
    return np.concatenate(legs)


def _fine_population(phi, chi, beta, kt, n=40000):
    """Many equal elements (midpoint rule in t), for time-domain comparisons."""
    e = chi + 1
    t = (np.arange(n) + 0.5) / n
    stiffness = np.full(n, kt / ((1 + beta) * n))
    slip = phi * t ** (1 / e)
    if beta > 0:
        stiffness, slip = np.append(stiffness, beta * kt / (1 + beta)), np.append(slip, phi)
    return stiffness, slip


@pytest.mark.parametrize("chi, beta", [(-0.5, 0.1), (0.3, 0.0)])
def test_iwan_kernel_follows_an_ensemble_under_random_amplitudes(chi, beta):
    """Madelung memory: nested loops close and the path resumes the interrupted branch."""
    kt, fs = 1.0e5, 10.0
    law = LAWS["iwan"]
    phi = slip_range(fs / kt, chi, beta)
    rng = np.random.default_rng(7)
    turning, reach = [0.0], 3.0 * phi
    for k in range(120):  # the direction alternates, the turning points are random in [-reach, reach]
        turning.append(rng.uniform(turning[-1], reach) if k % 2 == 0 else rng.uniform(-reach, turning[-1]))
    history = _monotone_history(np.array(turning))
    values = {"kt": kt, "fs": fs, "chi": chi, "beta": beta}
    kernel = law.force(history, np.zeros_like(history), **values)
    ensemble = _march_ensemble(*_fine_population(phi, chi, beta, kt), history)
    # the kernel is exact; the 40000-element ensemble converges to it like 1/n^2
    assert np.max(np.abs(kernel - ensemble)) <= 1e-7 * fs


def test_iwan_kernel_bounds_the_error_when_its_reversal_memory_overflows():
    """A slow decay nests one reversal per half cycle, far more than the memory holds."""
    kt, fs, chi, beta = 1.0e5, 10.0, -0.5, 0.1
    law = LAWS["iwan"]
    phi = slip_range(fs / kt, chi, beta)
    n_half = 4 * MAX_REVERSALS
    amplitude = 2.0 * phi * 0.99 ** np.arange(n_half)
    turning = np.concatenate(([0.0], amplitude * (-1.0) ** np.arange(n_half)))
    # then grow again through all the forgotten loops
    turning = np.concatenate((turning, 2.5 * phi * (-1.0) ** np.arange(n_half, n_half + 4)))
    history = _monotone_history(turning, 3)
    kernel = law.force(history, np.zeros_like(history), kt=kt, fs=fs, chi=chi, beta=beta)
    ensemble = _march_ensemble(*_fine_population(phi, chi, beta, kt), history)
    error = np.abs(kernel - ensemble)
    exact_until = 3 * (MAX_REVERSALS + 1)  # samples before the memory first overflows
    assert np.max(error[:exact_until]) <= 1e-7 * fs
    # forgotten loops: the merged turning points move by less than the decrement of a cycle
    # (1.5e-5 fs measured; a memory that drops the loops without moving the outer point: 2.5e-3 fs)
    assert np.max(error) <= 1e-4 * fs


def iwan_lipschitz_excess(state, values, reach, samples=100001):
    """Largest ``(|dF| - kt |dx|) / (kt |dx|)`` over fine sweeps from ``state`` to ``+-reach``.

    A parallel ensemble of Jenkins elements of total stiffness kt changes its force by at
    most ``kt |dx|`` along any path, so an exact Iwan state gives at most round-off
    (negative values: slack). A remembered reversal point off the branch of its
    predecessor shows as a force jump where the sweep closes the loop there.
    """
    law = LAWS["iwan"]
    worst = -math.inf
    for target in (reach, -reach):
        x = np.linspace(state[2], target, samples)
        f = law.force(x, np.zeros_like(x), state=state.copy(), **values)
        dx = np.abs(np.diff(x))
        worst = max(worst, float(np.max((np.abs(np.diff(f)) - values["kt"] * dx) / (values["kt"] * dx))))
    return worst


def _overflowing_turning_points(kind, phi, level, rng, n=600):
    """Turning points of a long history that nests more reversals than the memory holds."""
    k = np.arange(n)
    if kind == "decay":  # a slow decay with jitter, from micro- to macro-slip levels
        amplitude = level * phi * np.exp(-k / rng.uniform(50.0, 400.0)) * (1.0 + 0.05 * rng.standard_normal(n))
        points = amplitude * (-1.0) ** k + 1e-3 * level * phi * rng.standard_normal(n)
    elif kind == "beat":  # slowly rising and falling amplitude
        points = level * phi * (1.2 + np.sin(k / rng.uniform(20.0, 100.0))) * (-1.0) ** k
    else:  # a random walk: offset loops of random size
        points = level * phi * np.cumsum(rng.standard_normal(n))
    return np.concatenate(([0.0], points))


@settings(max_examples=30, deadline=None)
@given(kind=st.sampled_from(["decay", "beat", "walk"]), chi=st.floats(-0.95, 1.0),
       beta=st.sampled_from([0.0, 0.1, 1.5]), log_level=st.floats(-3.0, 1.0), seed=st.integers(0, 2**32 - 1))
def test_iwan_force_stays_continuous_when_its_reversal_memory_overflows(kind, chi, beta, log_level, seed):
    """Merging remembered loops keeps the memory of a real history: no force jump when the
    path later closes loops across a merged point (a jump leaves an implicit time step
    with no solution)."""
    values = {"kt": 1.0e5, "fs": 10.0, "chi": chi, "beta": beta}
    phi = slip_range(values["fs"] / values["kt"], chi, beta)
    turning = _overflowing_turning_points(kind, phi, 10.0**log_level, np.random.default_rng(seed))
    law = LAWS["iwan"]
    state = law.initial_state(law.parameter_vector(**values))
    law.force(_monotone_history(turning, 3), np.zeros(3 * (len(turning) - 1)), state=state, **values)
    assert iwan_lipschitz_excess(state, values, 1.1 * np.max(np.abs(turning))) <= 1e-6


def _live_state(s):
    """An iwan state's meaning: the header and the remembered reversal points (not the spare room)."""
    return s[:4 + 2 * int(s[0])]


@pytest.mark.parametrize("kind", ["decay", "beat", "walk"])
@pytest.mark.parametrize("chi, beta", [(-0.5, 0.1), (0.3, 0.0)])
def test_update_apart_then_commit_is_the_kernel_in_place(kind, chi, beta):
    """The simulator's use of a law with ``update``: evaluations from the committed state (a probe, then the
    accepted point) into a row holding anything, then ``commit``. Force and committed state are those of
    the in-place kernel to the last bit, through histories that overflow the memory (merges)."""
    law = LAWS["iwan"]
    values = {"kt": 1.0e5, "fs": 10.0, "chi": chi, "beta": beta}
    p = law.parameter_vector(**values)
    phi = slip_range(values["fs"] / values["kt"], chi, beta)
    x = _monotone_history(_overflowing_turning_points(kind, phi, 0.3, np.random.default_rng(7)), 4)
    in_place = law.initial_state(p)
    committed = law.initial_state(p)
    written = np.empty_like(committed)
    merges = 0
    for xi in x:
        expected = law.kernel(xi, 0.0, p, in_place)
        written[:] = np.nan  # what an earlier evaluation left there must not matter
        law.update(xi * (1.0 + 1e-3) + 1e-3 * phi, 0.0, p, committed, written)
        written[:] = np.nan
        assert law.update(xi, 0.0, p, committed, written) == expected
        merges += written[-1] - written[-2] > 1  # only a merge writes more than the point it pushes
        law.commit(written, committed)
        assert np.array_equal(_live_state(committed), _live_state(in_place))
    assert merges > 0 or kind == "walk"  # a random walk closes most of its loops: it need not fill the memory


def test_a_law_needs_both_update_and_commit():
    with pytest.raises(TypeError, match="update and commit"):
        class _Half(type(LAWS["jenkins"])):
            update = LAWS["jenkins"].kernel


@pytest.mark.parametrize("chi", [-0.3, -0.5, 0.0, 0.5, 1.0])  # a general power, and the kernel's square roots
def test_iwan_virgin_loading_is_the_population_backbone(chi):
    """F(u) = int_0^u rho phi dphi + u int_u^phi_max rho dphi + S min(u, phi_max), by quadrature."""
    kt, fs, beta = 1.0e5, 10.0, 0.4
    phi = slip_range(fs / kt, chi, beta)
    R = kt * (chi + 1) / ((1 + beta) * phi ** (chi + 1))
    S = beta * kt / (1 + beta)
    x = np.linspace(0.0, 2 * phi, 201)
    f = LAWS["iwan"].force(x, np.ones_like(x), kt=kt, fs=fs, chi=chi, beta=beta)
    for u, force in zip(x[1:], f[1:]):
        slipped = quad(lambda q: R * q ** (chi + 1), 0.0, min(u, phi), epsrel=1e-13)[0]
        stuck = u * quad(lambda q: R * q**chi, min(u, phi), phi, epsrel=1e-13)[0] if u < phi else 0.0
        assert force == pytest.approx(slipped + stuck + S * min(u, phi), rel=1e-10)
    assert f[100] == pytest.approx(fs, rel=1e-14)  # x = phi_max: macro-slip
    assert np.all(f[100:] == fs)


def test_iwan_unit_is_continuous_at_the_macroslip_onset():
    xs, chi, beta = 1e-4, -0.4, 0.3
    phi = slip_range(xs, chi, beta)
    below, above = iwan_unit(np.array([phi * (1 - 1e-12), phi * (1 + 1e-12)]), xs, chi, beta)
    assert abs(below - above) <= 1e-9
