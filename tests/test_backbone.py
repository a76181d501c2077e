"""Amplitude-dependent natural frequency and damping (analysis/backbone.py) against independent truth: the Duffing
oscillator's first-order backbone w^2 = (k + 3/4 k3 a^2) / m, and a Jenkins element's describing function
computed here by quadrature of its hysteresis loop."""
import numpy as np
import pytest
import scipy.optimize

from analysis.backbone import measured_backbone, predict_backbone
from analysis.elements import load_elements
from analysis.measurements import Control, SineRun
from analysis.structures import Structure

M, K, C = 2.0, 5000.0, 0.8


def sdof(laws: str) -> tuple[Structure, list]:
    s = Structure(["x"], np.array([[M]]), np.array([[K]]), np.array([[C]]))
    return s, load_elements({"element": [{"name": "joint", "dof": "x", "laws": laws}]}, s, complete=True)


def test_the_duffing_backbone_is_the_first_order_harmonic_balance():
    k3 = 3.0e8
    s, els = sdof([{"law": "cubic", "k3": k3}])
    a = np.array([1e-4, 1e-3, 3e-3])
    bb = predict_backbone(s, els, "x", "displacement", a, 8.0)
    amp, f, zeta = bb.arrays()
    k_eq = K + 0.75 * k3 * a ** 2
    np.testing.assert_allclose(2 * np.pi * f, np.sqrt(k_eq / M), rtol=1e-9)
    np.testing.assert_allclose(zeta, C / (2 * np.sqrt(k_eq * M)), rtol=1e-9)
    assert all(p.converged for p in bb.points) and bb.source == "predicted"


def test_an_acceleration_amplitude_is_converted_at_the_mode_s_own_frequency():
    k3 = 3.0e8
    s = Structure(["x"], np.array([[M]]), np.array([[K]]), np.zeros((1, 1)))
    els = load_elements({"element": [{"name": "j", "dof": "x", "laws": [{"law": "cubic", "k3": k3}]}]}, s,
                        complete=True)
    acc = np.array([0.5, 5.0, 20.0])
    f = predict_backbone(s, els, "x", "acceleration", acc, 8.0).arrays()[1]
    for a, fi in zip(acc, f):       # w^2 = (k + 3/4 k3 (a / w^2)^2) / m, solved for w here
        w = scipy.optimize.brentq(lambda w: M * w ** 2 - K - 0.75 * k3 * (a / w ** 2) ** 2, 1.0, 500.0)
        assert 2 * np.pi * fi == pytest.approx(w, rel=1e-7)    # the iteration stops at a change of 1e-10


def jenkins_kbar_by_quadrature(kt: float, fs: float, X: float, n: int = 200_000) -> complex:
    """kbar of a Jenkins element at x = X cos(theta): its second cycle's force, projected on cos (Re) and the
    energy it dissipates, D = pi X^2 Im kbar (Im)."""
    theta = np.linspace(0.0, 4 * np.pi, 2 * n + 1)
    x = X * np.cos(theta)
    force = np.empty_like(x)
    z = 0.0
    for i, xi in enumerate(x):
        f = kt * (xi - z)
        if abs(f) > fs:
            z = xi - np.sign(f) * fs / kt
            f = np.sign(f) * fs
        force[i] = f
    x2, f2, t2 = x[n:], force[n:], theta[n:]
    real = np.trapezoid(f2 * np.cos(t2), t2) / (np.pi * X)
    dissipated = np.trapezoid(f2, x2)       # the work done on the element over the cycle
    return complex(real, dissipated / (np.pi * X ** 2))


def test_jenkins_frequency_and_damping_follow_its_describing_function_by_quadrature():
    kt, fs = 2000.0, 1.0                  # slips beyond fs / kt = 0.5 mm
    s, els = sdof([{"law": "jenkins", "kt": kt, "fs": fs}])
    a = np.array([2e-4, 1e-3, 3e-3])
    bb = predict_backbone(s, els, "x", "displacement", a, 12.0)
    _, f, zeta = bb.arrays()
    for X, fi, zi in zip(a, f, zeta):
        k_eq = K + jenkins_kbar_by_quadrature(kt, fs, X)
        lam = np.roots([M, C, k_eq])
        lam = lam[lam.imag > 0][0]
        assert fi == pytest.approx(abs(lam) / (2 * np.pi), rel=1e-5)
        assert zi == pytest.approx(-lam.real / abs(lam), rel=1e-3)
    assert zeta[0] == pytest.approx(C / (2 * np.sqrt((K + kt) * M)), rel=1e-9)     # stuck: linear
    assert zeta[2] > 5 * zeta[0]                                                     # slipping: damped


def test_a_level_s_modal_fit_gives_the_linear_pole_of_its_frf():
    """A response level of a linear SDOF (its FRF written out here): the fit returns the pole."""
    f = np.linspace(9.0, 11.0, 81)
    w = 2 * np.pi * f
    wn, zeta = 2 * np.pi * 10.0, 0.01
    h = 1.0 / (M * (wn ** 2 - w ** 2 + 2j * zeta * wn * w))
    force = 0.002 * M * np.abs(wn ** 2 - w ** 2 + 2j * zeta * wn * w)    # what a 2 mm level needs
    run = SineRun("sine_x_0.002m_up", float(np.median(force)), "up", "x", ["x"], f, h[:, None],
                  force_achieved=force, control=Control("response", "x", "displacement", 0.002))
    (bb,) = measured_backbone([run])
    (p,) = bb.points
    assert p.frequency == pytest.approx(10.0, rel=1e-6) and p.damping == pytest.approx(0.01, rel=1e-4)
    assert p.amplitude == pytest.approx(0.002, rel=1e-9) and bb.runs == ("sine_x_0.002m_up",)
    assert measured_backbone([SineRun("sine_1N_up", 1.0, "up", "x", ["x"], f, h[:, None])]) == []
    down = SineRun("sine_x_0.002m_down", run.force, "down", "x", ["x"], f[::-1], h[::-1, None],
                   force_achieved=force[::-1], control=run.control)
    assert measured_backbone([down])[0].points[0].frequency == pytest.approx(10.0, rel=1e-6)
