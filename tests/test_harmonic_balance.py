"""Harmonic-balance prediction against the explicit single-element relation, the full (uncondensed)
equations and time integration."""
import numpy as np
import pytest
from scipy.integrate import solve_ivp

from analysis import load_elements, load_structure
from analysis.harmonic_balance import (continue_response, predict_multiharmonic, predict_sweep,
                                       single_element_force)

SDOF = {"type": "lumped", "dofs": ["x"], "mass": [[1.0]], "stiffness": [[100.0]], "damping": [[0.2]]}


def sdof(laws, damping=0.2):
    s = load_structure({**SDOF, "damping": [[damping]]})
    return s, load_elements({"element": [{"name": "e", "dof": "x", "laws": laws}]}, s, None, True)


def test_continuation_points_satisfy_the_explicit_relation_and_find_both_folds():
    s, els = sdof([{"law": "cubic", "k3": 1e4}])
    curve = continue_response(s, els, "x", 1.0, 5.0, 25.0)
    h = s.frf(curve.w)[:, 0, 0]
    X = np.abs(curve.y[:, 0])
    F = single_element_force(h, h, els[0].describing_function(X, curve.w)) * X
    np.testing.assert_allclose(F, 1.0, rtol=1e-7)
    assert len(curve.folds) == 2
    upper, lower = curve.w[curve.folds]
    assert upper > lower
    assert not curve.stable[curve.folds[0] + 1: curve.folds[1]].any()   # middle branch
    assert curve.stable[: curve.folds[0]].all() and curve.stable[curve.folds[1] + 1:].all()
    # backbone check: the upper fold sits near w^2 = w0^2 + 3 k3 X^2 / 4
    Xf = X[curve.folds[0]]
    assert upper == pytest.approx(np.sqrt(100 + 0.75 * 1e4 * Xf**2), rel=0.01)


def test_sweeps_jump_at_the_folds_up_and_down():
    s, els = sdof([{"law": "cubic", "k3": 1e4}])
    curve = continue_response(s, els, "x", 1.0, 5.0, 25.0)
    upper, lower = curve.w[curve.folds]
    w = np.linspace(5.0, 25.0, 801)
    up = np.abs(predict_sweep(s, els, "x", w, 1.0, "up").y[:, 0, 0])
    down = np.abs(predict_sweep(s, els, "x", w, 1.0, "down").y[:, 0, 0])
    # both jumps are drops when read in increasing w: the resonant branch ends at the upper fold going up,
    # and going down the response rises onto it at the lower fold
    jump_up = w[np.argmax(-np.diff(up))]
    jump_down = w[np.argmax(-np.diff(down))]
    step = w[1] - w[0]
    assert abs(jump_up - upper) <= step and abs(jump_down - lower) <= 2 * step
    both = (w < lower - step) | (w > upper + step)
    np.testing.assert_allclose(up[both], down[both], rtol=1e-8)


def test_sweep_solves_the_full_equations_for_several_elements_and_levels():
    s = load_structure({"type": "lumped", "dofs": ["a", "b", "c"],
                        "mass": [[1.0, 0, 0], [0, 1.5, 0], [0, 0, 0.8]],
                        "stiffness": [[300.0, -100, 0], [-100, 250, -120], [0, -120, 220]],
                        "rayleigh": [0.05, 0.001]})
    els = load_elements({"element": [
        {"name": "ground", "dof": "a", "laws": [{"law": "cubic", "k3": 2e4}, {"law": "quadratic_damping", "c2": 0.5}]},
        {"name": "link", "between": ["b", "c"], "laws": [{"law": "cubic", "k3": -3e3}, {"law": "linear", "k": 0.0, "c": 0.3}]},
        {"name": "rub", "dof": "c", "laws": [{"law": "coulomb", "fs": 0.01}]},
    ]}, s, None, True)
    w = 2 * np.pi * np.linspace(0.5, 4.0, 60)
    F = np.array([0.2, 0.5, 1.0])
    pred = predict_sweep(s, els, "b", w, F, "up")
    assert pred.converged.all()
    E = np.stack([el.vector(s) for el in els], axis=1)
    for b, f in enumerate(F):
        x = pred.receptance[:, b, :] * f                          # (L, n)
        y = x @ E
        kb = np.stack([el.describing_function(np.abs(y[:, i]), w) for i, el in enumerate(els)], axis=1)
        lhs = np.einsum("lij,lj->li", s.dynamic_stiffness(w), x) + (kb * y) @ E.T
        rhs = np.zeros_like(lhs)
        rhs[:, s.index("b")] = f
        np.testing.assert_allclose(lhs, rhs, atol=1e-9 * f)


def _steady_state(rhs, w, periods_settle, n_per_period=512):
    T = 2 * np.pi / w
    sol = solve_ivp(rhs, (0, periods_settle * T), [0.0, 0.0], rtol=1e-10, atol=1e-12, method="DOP853")
    t = periods_settle * T + np.arange(n_per_period) * T / n_per_period
    last = solve_ivp(rhs, (periods_settle * T, t[-1]), sol.y[:, -1], t_eval=t, rtol=1e-11, atol=1e-13,
                     method="DOP853")
    x = last.y[0]
    theta = w * t
    spectrum = {k: 2 / n_per_period * np.sum(x * (np.sin(k * theta) + 1j * np.cos(k * theta)))
                for k in range(1, 6)}
    spectrum[0] = x.mean()
    return spectrum


def test_multiharmonic_duffing_matches_time_integration():
    # near the 1/3 superharmonic resonance the third harmonic is ~15 % of the fundamental
    k3, c, w, F = 4e4, 2.0, 3.4, 5.0
    s, els = sdof([{"law": "cubic", "k3": k3}], damping=c)
    ref = _steady_state(lambda t, z: [z[1], F * np.sin(w * t) - c * z[1] - 100 * z[0] - k3 * z[0] ** 3],
                        w, 60)
    mh = predict_multiharmonic(s, els, "x", [w], F, n_harmonics=7, n_time=128)
    assert mh.converged.all()
    got = mh.harmonics[0, :, 0]
    assert abs(ref[3]) > 0.1 * abs(ref[1])
    assert abs(got[1] - ref[1]) < 1e-3 * abs(ref[1])
    assert abs(got[3] - ref[3]) < 1e-2 * abs(ref[3])
    single = predict_sweep(s, els, "x", [w], F).y[0, 0, 0]
    assert abs(single - ref[1]) > 5 * abs(got[1] - ref[1])   # one harmonic is visibly worse here


def test_multiharmonic_bilinear_predicts_mean_and_even_harmonics():
    kp, kn, c, w, F = 300.0, 0.0, 3.0, 9.0, 1.0
    s, els = sdof([{"law": "bilinear", "k_pos": kp, "k_neg": kn}], damping=c)

    def rhs(t, z):
        spring = kp * z[0] if z[0] > 0 else kn * z[0]
        return [z[1], F * np.sin(w * t) - c * z[1] - 100 * z[0] - spring]

    ref = _steady_state(rhs, w, 150)
    mh = predict_multiharmonic(s, els, "x", [w], F, n_harmonics=8, n_time=512)
    got = mh.harmonics[0, :, 0]
    assert abs(got[1] - ref[1]) < 1e-3 * abs(ref[1])
    assert got[0].real == pytest.approx(ref[0].real, rel=0.02)
    assert abs(got[2] - ref[2]) < 0.03 * abs(ref[2])
    assert abs(ref[0]) > 0.05 * abs(ref[1])                  # the mean is what reveals bilinearity


def test_one_harmonic_aft_equals_describing_function_balance():
    s = load_structure({"type": "lumped", "dofs": ["x1", "x2"], "mass": [[1, 0], [0, 2]],
                        "stiffness": [[200, -100], [-100, 200]], "rayleigh": [0.0, 0.01]})
    els = load_elements({"element": [{"name": "l", "dof": "x1", "laws": [{"law": "cubic", "k3": -500.0}]},
                                     {"name": "r", "dof": "x2", "laws": [{"law": "cubic", "k3": -750.0}]}]},
                        s, None, True)
    w = 2 * np.pi * np.linspace(0.8, 3.2, 9)
    single = predict_sweep(s, els, "x2", w, 0.3)
    mh = predict_multiharmonic(s, els, "x2", w, 0.3, n_harmonics=1, n_time=64)
    np.testing.assert_allclose(mh.receptance(0.3), single.receptance[:, 0, :], rtol=1e-8, atol=1e-12)


def test_bad_direction_is_refused():
    s, els = sdof([{"law": "cubic", "k3": 1e4}])
    with pytest.raises(ValueError, match="direction"):
        predict_sweep(s, els, "x", [10.0], 1.0, "sideways")


# --------------------------------------------------------------------------- the paper's 2-DOF model at 0.8 N
PAPER = {"type": "lumped", "dofs": ["x1", "x2"], "mass": [[1.0, 0.0], [0.0, 2.0]],
         "stiffness": [[200.0, -100.0], [-100.0, 200.0]]}
PAPER_ELEMENTS = {"element": [
    {"name": "left", "dof": "x1", "laws": [{"law": "cubic", "k3": -500.0}, {"law": "quadratic_damping", "c2": 1.0}]},
    {"name": "right", "dof": "x2", "laws": [{"law": "cubic", "k3": -750.0}, {"law": "coulomb", "fs": 0.1}]}]}
HZ = 2 * np.pi


def paper():
    s = load_structure(PAPER)
    return s, load_elements(PAPER_ELEMENTS, s, None, True)


@pytest.fixture(scope="module")
def paper_curve():
    s, els = paper()
    return continue_response(s, els, "x2", 0.8, HZ * 0.8, HZ * 3.2)


def test_continuation_of_the_paper_model_passes_both_folds_and_reaches_the_end(paper_curve):
    curve = paper_curve
    assert curve.complete and curve.w[-1] == pytest.approx(HZ * 3.2, rel=1e-12)
    assert curve.w.min() >= HZ * 0.8 * (1 - 1e-12)                         # never runs off the span
    upper, lower = curve.fold_frequencies / HZ
    assert upper == pytest.approx(1.21185, abs=2e-5) and lower == pytest.approx(1.15363, abs=2e-5)
    # the folds against an independent solver: a sweep with 1e-5 Hz lines keeps the branch up to the fold
    # and has lost it one line past it
    s, els = paper()
    for k, (fold, direction, approach) in enumerate(((upper, "up", 1.0), (lower, "down", 1.4))):
        side = np.sign(fold - approach)
        w = HZ * np.r_[np.arange(approach, fold - side * 5e-4, side * 1e-3), fold - side * 1e-5, fold + side * 1e-5]
        near = np.abs(predict_sweep(s, els, "x2", w, 0.8, direction).y[-2:, 0, 0])
        at_fold = np.abs(curve.y[curve.folds[k], 0])
        assert near[0] == pytest.approx(at_fold, rel=0.02) and abs(near[1] - at_fold) > 0.2 * at_fold
    # the resonant branch peaks where the swept-down prediction does (the upper branch of the softening pair)
    down = predict_sweep(s, els, "x2", HZ * np.arange(1.4, 1.0, -0.001), 0.8, "down")
    assert np.abs(curve.y[:, 0]).max() == pytest.approx(np.abs(down.y[:, 0, 0]).max(), rel=5e-3)
    assert np.abs(curve.y[:, 0]).max() > 0.14
    # unstable exactly between the folds
    middle = np.arange(curve.folds[0] + 1, curve.folds[1])
    assert not curve.stable[middle].any() and curve.stable[: curve.folds[0] + 1].all()
    assert curve.stable[curve.folds[1]:].all()


def test_continuation_downwards_and_with_a_small_step_stays_in_the_span():
    s, els = paper()
    down = continue_response(s, els, "x2", 0.8, HZ * 1.4, HZ * 1.0)
    assert down.complete and len(down.w) < 1000
    np.testing.assert_allclose(np.sort(down.fold_frequencies / HZ), [1.15363, 1.21185], atol=2e-5)
    unstable = down.w[~down.stable] / HZ
    assert unstable.min() > 1.1536 and unstable.max() < 1.2119
    fine = continue_response(s, els, "x2", 0.8, HZ * 1.1, HZ * 1.3, step=0.002)
    assert fine.complete and fine.w.min() >= HZ * 1.1 * (1 - 1e-12) and len(fine.folds) == 2


def _rk4(rhs, z0, dt, steps):
    z = np.array(z0, float)
    for i in range(steps):
        t = i * dt
        k1 = rhs(t, z)
        k2 = rhs(t + dt / 2, z + dt / 2 * k1)
        k3 = rhs(t + dt / 2, z + dt / 2 * k2)
        k4 = rhs(t + dt, z + dt * k3)
        z = z + dt / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
    return z


def test_stability_of_each_branch_at_1_18_hz_against_time_integration(paper_curve):
    # three solutions at 1.18 Hz: the outer two are held by the time-domain system started on them, the middle
    # one (marked unstable) is left for another
    curve, w = paper_curve, HZ * 1.18
    cross = np.flatnonzero(np.diff(np.sign(curve.w - w)) != 0)
    assert len(cross) == 3
    y, stable = [], []
    for i in cross:
        f = (w - curve.w[i]) / (curve.w[i + 1] - curve.w[i])
        y.append(curve.y[i] + f * (curve.y[i + 1] - curve.y[i]))
        stable.append(curve.stable[i] and curve.stable[i + 1])
    y = np.array(y)                                       # (3, 2): x1, x2 phasors (grounded elements)

    def rhs(t, z):                                        # the three starts at once; Coulomb as 0.1 tanh(v/1e-4)
        x1, x2, v1, v2 = z.reshape(4, -1)
        f1 = 200 * x1 - 100 * x2 - 500 * x1 ** 3 + v1 * np.abs(v1)
        f2 = -100 * x1 + 200 * x2 - 750 * x2 ** 3 + 0.1 * np.tanh(v2 / 1e-4)
        return np.concatenate([v1, v2, -f1, (0.8 * np.sin(w * t) - f2) / 2.0])

    periods, per_period = 40, 400
    T = 2 * np.pi / w
    z0 = np.concatenate([y[:, 0].imag, y[:, 1].imag, w * y[:, 0].real, w * y[:, 1].real])
    end = _rk4(rhs, z0, T / per_period, periods * per_period).reshape(4, -1)
    start = z0.reshape(4, -1)
    moved = np.hypot(end[0] - start[0], end[2] / w - start[2] / w) / np.abs(y[:, 0])   # x1 state after whole periods
    assert stable == [True, False, True]
    assert moved[0] < 0.05 and moved[2] < 0.05 and moved[1] > 0.5, moved
