"""The N/V a voltage-driven shaker gives at the next line (analysis/signals/drive_prediction.py), against the analytic
force per volt of a shaker model on a 2-DOF structure, built here from polynomials in s."""
import numpy as np
import pytest
from numpy.polynomial import Polynomial as P

from analysis.signals.drive_prediction import predicted_gain

# the linear-shaker rig's structure and shaker (tests/rigs/linear-shaker.toml)
M = np.diag([1.0, 0.5])
K = np.array([[6000.0, -2000.0], [-2000.0, 2000.0]])
C = 0.5 * M + 2e-4 * K
R, L, BL, MA, KS, CS = 4.0, 1e-3, 4.0, 0.05, 500.0, 1.0


def shaker_on_structure():
    """(F/V as a function of s, coupled poles with positive imaginary part) for the shaker at DOF 1.

    Drive-point receptance H = N/D with D = det(K + C s + M s^2) and N its (2, 2) entry; the coil
    V = (R + L s) i + BL s x1, the armature BL i - F = (MA s^2 + CS s + KS) x1, x1 = H F, so
    F/V = BL D / ((R + L s)(D + Za N) + BL^2 s N)."""
    entry = [[P([K[i, j], C[i, j], M[i, j]]) for j in range(2)] for i in range(2)]
    D = entry[0][0] * entry[1][1] - entry[0][1] * entry[1][0]
    N = entry[1][1]
    Za, Ze = P([KS, CS, MA]), P([R, L])
    den = Ze * (D + Za * N) + BL**2 * P([0, 1]) * N
    poles = den.roots()
    return (lambda s: BL * D(s) / den(s)), poles[poles.imag > 0]


def test_predicts_the_shaker_force_per_volt_through_both_resonances():
    gain_of, poles = shaker_on_structure()
    f = np.arange(5.0, 17.0001, 0.25)
    g = np.abs(gain_of(2j * np.pi * f))
    assert g.max() / g.min() > 4                 # the force per volt dips and peaks at the resonances
    errors = np.array([predicted_gain(f[:j], g[:j], poles, f[j]) / g[j] - 1 for j in range(1, len(f))])
    # within the force loop's 1 % once four lines are known: no correction needed anywhere after that
    assert np.all(np.abs(errors[3:]) < 0.01), np.abs(errors).round(4)
    assert np.all(np.abs(errors[4:]) < 1e-3)     # five lines: the degree the two modes need
    # the same from measured values: N/V to 1e-5, poles as scattered as the transient fits give them
    rng = np.random.default_rng(3)
    noisy = g * (1 + 1e-5 * rng.standard_normal(len(g)))
    scattered = poles * (1 + 1e-5 * rng.standard_normal(len(poles)))
    errors = np.array([predicted_gain(f[:j], noisy[:j], scattered, f[j]) / g[j] - 1 for j in range(1, len(f))])
    assert np.all(np.abs(errors[3:]) < 0.01), np.abs(errors).round(4)


def test_a_log_linear_extrapolation_of_the_same_lines_would_miss_the_resonances():
    """What the poles buy: extrapolating the N/V from the last two lines leaves many lines beyond 1 %."""
    gain_of, _ = shaker_on_structure()
    f = np.arange(5.0, 17.0001, 0.25)
    g = np.abs(gain_of(2j * np.pi * f))
    log_linear = g[1:-1] * (g[1:-1] / g[:-2])
    assert np.sum(np.abs(log_linear / g[2:] - 1) > 0.01) >= 20


def test_an_ideal_force_source_keeps_its_constant_gain():
    _, poles = shaker_on_structure()
    f = np.arange(1.0, 3.0, 0.05)
    g = np.full(len(f), 0.8)
    for j in range(1, len(f)):
        assert predicted_gain(f[:j], g[:j], poles, f[j]) == pytest.approx(0.8, rel=1e-9)


def test_without_lines_or_poles():
    assert predicted_gain([], [], [], 5.0) is None
    assert predicted_gain([5.0], [0.7], [], 5.5) == pytest.approx(0.7)
    # no poles: a polynomial in w^2 for |F/V|^2, exact for a gain that is one
    f = np.array([5.0, 5.5, 6.0])
    g = np.sqrt(1 + 0.01 * (2 * np.pi * f) ** 2)
    assert predicted_gain(f, g, [], 6.5) == pytest.approx(np.sqrt(1 + 0.01 * (2 * np.pi * 6.5) ** 2), rel=1e-9)
