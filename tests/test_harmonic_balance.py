"""Harmonic-balance prediction against the explicit single-element relation, the full (uncondensed)
equations and time integration."""
import numpy as np
import pytest
from scipy.integrate import solve_ivp

from analysis import load_elements, load_structure
from analysis.prediction.comparison import HarmonicCriterion
from analysis.prediction.harmonic_balance import continue_response, predict_sweep, predict_sweeps
from analysis.prediction.multiharmonic import (HARMONIC_TRUNCATION, _AFT, omitted_harmonics, predict_multiharmonic,
                                               predict_multiharmonic_converged, single_harmonic_distortion)

SDOF = {"type": "lumped", "dofs": ["x"], "mass": [[1.0]], "stiffness": [[100.0]], "damping": [[0.2]]}


def sdof(laws, damping=0.2):
    s = load_structure({**SDOF, "damping": [[damping]]})
    return s, load_elements({"element": [{"name": "e", "dof": "x", "laws": laws}]}, s, None, True)


def test_continuation_points_satisfy_the_explicit_relation_and_find_both_folds():
    s, els = sdof([{"law": "cubic", "k3": 1e4}])
    curve = continue_response(s, els, "x", 1.0, 5.0, 25.0)
    h = s.frf(curve.w)[:, 0, 0]
    X = np.abs(curve.y[:, 0])
    # one grounded element at the driven DOF: y (1 + h kbar(X, w)) = h F, explicit in X on every branch
    F = X * np.abs(1.0 + h * els[0].describing_function(X, curve.w)) / np.abs(h)
    np.testing.assert_allclose(F, 1.0, rtol=1e-7)
    assert len(curve.folds) == 2
    upper, lower = curve.w[curve.folds]
    assert upper > lower
    assert not curve.stable[curve.folds[0] + 1: curve.folds[1]].any()   # middle branch
    assert curve.stable[: curve.folds[0]].all() and curve.stable[curve.folds[1] + 1:].all()
    # backbone check: the upper fold sits near w^2 = w0^2 + 3 k3 X^2 / 4
    Xf = X[curve.folds[0]]
    assert upper == pytest.approx(np.sqrt(100 + 0.75 * 1e4 * Xf**2), rel=0.01)


@pytest.mark.slow
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


@pytest.mark.slow
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


@pytest.mark.slow
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


@pytest.mark.slow
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


@pytest.mark.slow
def test_continuation_downwards_and_with_a_small_step_stays_in_the_span():
    s, els = paper()
    down = continue_response(s, els, "x2", 0.8, HZ * 1.4, HZ * 1.0)
    assert down.complete and len(down.w) < 1000
    np.testing.assert_allclose(np.sort(down.fold_frequencies / HZ), [1.15363, 1.21185], atol=2e-5)
    unstable = down.w[~down.stable] / HZ
    assert unstable.min() > 1.1536 and unstable.max() < 1.2119
    fine = continue_response(s, els, "x2", 0.8, HZ * 1.1, HZ * 1.3, step=0.002)
    assert fine.complete and fine.w.min() >= HZ * 1.1 * (1 - 1e-12) and len(fine.folds) == 2


@pytest.mark.slow
def test_continuation_until_the_first_fold_ends_there(paper_curve):
    s, els = paper()
    first = continue_response(s, els, "x2", 0.8, HZ * 0.8, HZ * 3.2, until_fold=True)
    assert not first.complete and list(first.folds) == [len(first.w) - 1]
    # the same curve as the whole one up to its first fold, which it ends on
    k = paper_curve.folds[0]
    assert first.fold_frequencies[0] == paper_curve.fold_frequencies[0]
    np.testing.assert_array_equal(first.w, paper_curve.w[: k + 1])


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


@pytest.mark.slow
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


def _paper_period(z0, w):
    """One period of the paper's 2-DOF system at 0.8 N with Coulomb friction exact: the sliding direction
    flips where v2 crosses zero (the integrator's event search); returns the end state and the segments."""
    T = 2 * np.pi / w
    t, z, sgn, segments = 0.0, np.array(z0, float), np.sign(z0[3]), []
    while t < T:
        def rhs(t, z, sgn=sgn):
            x1, x2, v1, v2 = z
            f1 = 200 * x1 - 100 * x2 - 500 * x1 ** 3 + v1 * abs(v1)
            f2 = -100 * x1 + 200 * x2 - 750 * x2 ** 3 + 0.1 * sgn
            return [v1, v2, -f1, (0.8 * np.sin(w * t) - f2) / 2.0]

        def reversal(t, z):
            return z[3]

        reversal.terminal, reversal.direction = True, -sgn
        sol = solve_ivp(rhs, (t, T), z, method="DOP853", rtol=1e-12, atol=1e-14, events=reversal,
                        dense_output=True)
        segments.append(sol)
        t, z = sol.t[-1], sol.y[:, -1]
        if sol.status == 1:
            held = 0.8 * np.sin(w * t) + 100 * z[0] - 200 * z[1] + 750 * z[1] ** 3
            assert abs(held) > 0.1                    # the contact slides on: no stick to model
            sgn = -sgn
    return z, segments


def _orbit_fundamental(period, w, X, tol=1e-12, floor=1e-3):
    """Fundamental phasors of x1, x2 on a periodic orbit: shooting (Newton on one period, ``period(z0)`` ->
    (end state, segments)) from the phasors ``X``; finite-difference steps 1e-7 of each state, at least of
    ``floor``."""
    z0 = np.array([X[0].imag, X[1].imag, w * X[0].real, w * X[1].real])
    for _ in range(10):
        zT, _ = period(z0)
        if np.linalg.norm(zT - z0) < tol * np.linalg.norm(z0):
            break
        J = np.empty((4, 4))
        for j in range(4):
            dz = np.zeros(4)
            dz[j] = 1e-7 * max(abs(z0[j]), floor)
            J[:, j] = (period(z0 + dz)[0] - zT) / dz[j]
        z0 = z0 - np.linalg.solve(J - np.eye(4), zT - z0)
    _, segments = period(z0)
    n = 4096
    t = np.arange(n) * 2 * np.pi / w / n
    x = np.concatenate([seg.sol(t[(t >= seg.t[0]) & ((t < seg.t[-1]) | (k == len(segments) - 1))])[:2]
                        for k, seg in enumerate(segments)], axis=1)
    return 2 / n * (x * (np.sin(w * t) + 1j * np.cos(w * t))).sum(axis=1)


def _paper_orbit_fundamental(w, X):
    return _orbit_fundamental(lambda z: _paper_period(z, w), w, X)


@pytest.mark.parametrize("f_hz, direction, single_off, limits, falling", [
    (0.8, "up", (0.014, 0.018), {3: 7.5e-3, 5: 5.2e-3, 7: 4.2e-3}, True),    # 3rd harmonic on mode 2 (2.45 Hz)
    # resonant branch near its fold: from 3 harmonics on the error is that of the friction force's slowly
    # converging Fourier series (2e-5 .. 3e-5, not falling with every harmonic)
    (1.18, "down", (0.016, 0.020), {3: 5e-5, 7: 5e-5}, False),
])
@pytest.mark.slow
def test_multiharmonic_on_the_paper_model_against_its_periodic_orbit(f_hz, direction, single_off, limits, falling):
    s, els = paper()
    w = HZ * f_hz
    lines = HZ * (np.arange(0.8, f_hz + 1e-9, 0.01) if direction == "up" else np.arange(1.4, f_hz - 1e-9, -0.01))
    single = predict_sweep(s, els, "x2", lines, 0.8, direction)
    y1, x1 = single.y[-1:, 0], single.receptance[-1, 0] * 0.8
    ref = _paper_orbit_fundamental(w, predict_multiharmonic(s, els, "x2", [w], 0.8, 7, 1024, y_start=y1).harmonics[0, 1])
    off = {H: np.linalg.norm(predict_multiharmonic(s, els, "x2", [w], 0.8, H, 1024, y_start=y1).harmonics[0, 1] - ref)
           / np.linalg.norm(ref) for H in limits}
    single_err = np.linalg.norm(x1 - ref) / np.linalg.norm(ref)
    assert single_off[0] < single_err < single_off[1]
    assert all(off[H] < limit for H, limit in limits.items()), off
    assert not falling or list(off.values()) == sorted(off.values(), reverse=True)
    # what the comparison uses (7 harmonics, 512 points per period) is as close
    used = predict_multiharmonic(s, els, "x2", [w], 0.8, HarmonicCriterion().n_harmonics, HarmonicCriterion().n_time,
                                 y_start=y1).harmonics[0, 1]
    assert np.linalg.norm(used - ref) / np.linalg.norm(ref) < max(limits.values()) * 1.5


def test_the_harmonic_criterion_selects_the_third_harmonic_on_mode_2_and_the_fold():
    s, els = paper()
    w = HZ * np.array([0.8, 1.18, 1.6])
    up, down = predict_sweeps(s, els, "x2", HZ * np.r_[np.arange(0.8, 1.6, 0.01), 1.6], 0.8)
    rows = [0, 38, 80]
    implied = single_harmonic_distortion(s, els, "x2", w, 0.8, up.y[rows, 0]).max(axis=1)
    multivalued = np.abs(up.y[rows, 0] - down.y[rows, 0]).max(axis=1) > 1e-9
    assert implied[0] > 0.1 and implied[1] < 0.01 and implied[2] < 0.01       # the fold shows no harmonics
    assert multivalued.tolist() == [False, True, False]
    assert HarmonicCriterion().selects(None, implied, multivalued).tolist() == [True, True, False]
    # measured distortion counts too
    assert HarmonicCriterion().selects(np.array([0.0, 0.0, 0.02]), implied, multivalued).tolist() == [True] * 3


# --------------------------------------------------------------------------- a friction force's jump in the AFT
@pytest.mark.parametrize("law, fundamental", [
    # fs sgn(x') along x = X sin(u): (4 fs / pi) cos(u) + harmonics, a jump where x' changes sign
    ({"law": "coulomb", "fs": 0.1}, lambda X, w: 4 * 0.1 / np.pi * 1j * X / abs(X)),
    # (pi/2) gamma |x'| sgn(x): gamma w X sin(u) + harmonics, a jump where x changes sign
    ({"law": "velocity_stiffness", "gamma": 4.0}, lambda X, w: 4.0 * w * X),
])
def test_aft_of_a_jumping_force_follows_its_fourier_series_at_any_phase(law, fundamental):
    """The fundamental of a force that jumps must follow the phase of the motion smoothly, not in steps of a
    sample: exact against the describing function of the law (its fundamental over a harmonic motion)."""
    _, els = sdof([law])
    H, w = 7, 10.0
    worst = {}
    for n in (64, 256):
        aft = _AFT(els, H, n)
        worst[n] = 0.0
        for phi in np.linspace(0.0, 2 * np.pi / n, 9):    # the jump moved across one sampling interval
            Yk = np.zeros((H + 1, 1), complex)
            Yk[1] = 1e-3 * np.exp(1j * phi)
            exact = fundamental(Yk[1, 0], w)
            worst[n] = max(worst[n], abs(aft.forces(Yk, w)[1, 0] - exact) / abs(exact))
    # the jump left on the grid misses the fundamental by up to pi/n (4.9 % at 64 points); placed where the
    # sign changes, by the aliasing of the samples: O(1/n^2) (measured 0.16 % and 0.010 % for Coulomb)
    assert worst[64] < 2.5e-3 and worst[256] < 1.5e-4 and worst[64] / worst[256] > 10, worst


def _af_rig():
    """The 2-DOF rig with Anderson-Ferri friction at x2 (a = 0.1 N, b = 30 N/m), Rayleigh damping."""
    s = load_structure({"type": "lumped", "dofs": ["x1", "x2"], "mass": [[1.0, 0.0], [0.0, 1.0]],
                        "stiffness": [[3000.0, -1000.0], [-1000.0, 2000.0]], "rayleigh": [0.3, 1.0e-4]})
    return s, load_elements({"element": [{"name": "b", "dof": "x2", "laws": [
        {"law": "anderson_ferri", "a": 0.1, "b": 30.0, "c": 0.0}]}]}, s, None, True)


def _af_period(z0, w, force):
    """One period of the Anderson-Ferri rig, the sliding direction flipped at each reversal of v2 (event)."""
    M, K = np.eye(2), np.array([[3000.0, -1000.0], [-1000.0, 2000.0]])
    C = 0.3 * M + 1e-4 * K
    T = 2 * np.pi / w
    t, z, sgn, segments = 0.0, np.array(z0, float), np.sign(z0[3]), []
    while t < T:
        def rhs(t, z, sgn=sgn):
            x, v = z[:2], z[2:]
            f = K @ x + C @ v + np.array([0.0, (np.pi / 4 * 0.1 + np.pi / 2 * 30.0 * abs(x[1])) * sgn])
            return np.r_[v, np.array([0.0, force * np.sin(w * t)]) - f]

        def reversal(t, z):
            return z[3]

        reversal.terminal, reversal.direction = True, -sgn
        sol = solve_ivp(rhs, (t, T), z, method="DOP853", rtol=1e-11, atol=1e-14, events=reversal, dense_output=True)
        segments.append(sol)
        t, z = sol.t[-1], sol.y[:, -1]
        if sol.status == 1:
            held = force * np.sin(w * t) - (K @ z[:2] + C @ z[2:])[1]
            assert abs(held) > np.pi / 4 * 0.1 + np.pi / 2 * 30.0 * abs(z[1])     # slides on: no stick
            sgn = -sgn
    return z, segments


@pytest.mark.slow
def test_multiharmonic_converges_on_anderson_ferri_friction_and_matches_its_periodic_orbit():
    """The friction force is comparable with what moves x2 at 0.5 N: its harmonics shift the reversals and give
    the fundamental a part in phase with the motion that the single-harmonic balance misses (by 1-3 % below
    the antiresonance of x2 at 8.7 Hz). The multi-harmonic balance of the comparison (7 harmonics, 512 points)
    must converge at every line of a sweep (with the jump on the sampling grid: 23 of 31) and find the
    periodic orbit, to what 7 harmonics of a jumping force can give."""
    s, els = _af_rig()
    w = HZ * np.arange(5.0, 11.01, 0.2)
    single = predict_sweep(s, els, "x2", w, 0.5)
    mh = predict_multiharmonic(s, els, "x2", w, 0.5, 7, 512, y_start=single.y[:, 0])
    assert mh.converged.all(), w[~mh.converged] / HZ
    for i in (5, 12, 16):                                   # 6.0, 7.4 and 8.2 Hz
        ref = _orbit_fundamental(lambda z: _af_period(z, w[i], 0.5), w[i], mh.harmonics[i, 1], 1e-11, 1e-6)
        single_off = np.linalg.norm(single.receptance[i, 0] * 0.5 - ref) / np.linalg.norm(ref)
        off = np.linalg.norm(mh.harmonics[i, 1] - ref) / np.linalg.norm(ref)
        assert off < 0.3 * single_off, (w[i] / HZ, single_off, off)


@pytest.mark.parametrize("lines", [6, 25, 200])      # marched (<= MARCHED_STEPS), and solved all at once
def test_each_line_is_predicted_at_its_own_measured_force(lines):
    """A force per line (L, B): every line solves the explicit single-element relation at its own force, and a
    sweep at a constant force per line is the sweep at that force."""
    s, els = sdof([{"law": "cubic", "k3": 1e3}])
    w = np.linspace(6.0, 14.0, lines)
    force = np.stack([0.2 * (1 + 0.25 * np.sin(np.arange(lines))), np.full(lines, 0.5)], axis=1)    # (L, 2)
    pred = predict_sweep(s, els, "x", w, force)
    assert pred.converged.all()
    h = s.frf(w)[:, 0, 0]
    X = np.abs(pred.y[:, :, 0])
    implied = X * np.abs(1.0 + h[:, None] * els[0].describing_function(X, w[:, None])) / np.abs(h)[:, None]
    np.testing.assert_allclose(implied, force, rtol=1e-8)
    held = predict_sweep(s, els, "x", w, [0.5])
    np.testing.assert_allclose(pred.receptance[:, 1], held.receptance[:, 0], rtol=1e-10)


# ----------------------------------------------------------------------------- long sweeps (batch-solved)
def _duffing_amplitudes(w, force, k=100.0, m=1.0, c=0.2, k3=1e4):
    """Every real single-harmonic amplitude of m x'' + c x' + k x + k3 x^3 = F sin(wt) at each w: the real
    positive roots u = X^2 of (9/16) k3^2 u^3 + (3/2) k3 (k - m w^2) u^2 + ((k - m w^2)^2 + (c w)^2) u - F^2."""
    out = []
    for wl in w:
        d = k - m * wl**2
        u = np.roots([9 / 16 * k3**2, 1.5 * k3 * d, d**2 + (c * wl) ** 2, -force**2])
        real = u[(np.abs(u.imag) < 1e-9 * np.abs(u)) & (u.real > 0)].real
        out.append(np.sqrt(np.sort(real)))
    return out


@pytest.mark.slow
def test_a_long_sweep_follows_the_branch_a_stepped_sine_measures_by_the_analytic_relation():
    """2000 lines (solved all at once and checked against the march, harmonic_balance._speculative_sweep): a
    hardening Duffing oscillator's up sweep stays on the largest amplitude until its fold, the down sweep on the
    smallest, at every line and level -- the roots of the amplitude cubic, independently of the solver."""
    s, els = sdof([{"law": "cubic", "k3": 1e4}])
    w = np.linspace(5.0, 25.0, 2000)
    forces = [0.3, 1.0, 2.0]
    up, down = predict_sweeps(s, els, "x", w, forces, ("up", "down"))
    assert up.converged.all() and down.converged.all()
    for b, force in enumerate(forces):
        roots = _duffing_amplitudes(w, force)
        assert max(len(r) for r in roots) == 3                     # the response is multivalued somewhere
        np.testing.assert_allclose(np.abs(up.y[:, b, 0]), [r[-1] for r in roots], rtol=1e-7)
        np.testing.assert_allclose(np.abs(down.y[:, b, 0]), [r[0] for r in roots], rtol=1e-7)


@pytest.mark.parametrize("laws", [
    [{"law": "cubic", "k3": -3e3}],                                          # softening: jumps the other way
    pytest.param([{"law": "coulomb", "fs": 0.6}], marks=pytest.mark.slow),   # sticks at 0.5 N: no solution
    [{"law": "cubic", "k3": 1e4}, {"law": "quadratic_damping", "c2": 0.05}],
])
@pytest.mark.parametrize("lines", [120, 20])      # both > MARCHED_STEPS: batch-solved
def test_a_long_sweep_solved_at_once_is_the_line_by_line_march(laws, lines, monkeypatch):
    """The batch solution of a sweep and the march line by line give the same phasors, convergence and
    stability flags (to Newton's tolerance), also where lines have no solution and across jumps."""
    import analysis.prediction.harmonic_balance as hb

    s, els = sdof(laws)
    w = np.linspace(5.0, 25.0, lines)
    forces = [0.5, 2.0]
    fast = predict_sweeps(s, els, "x", w, forces)
    monkeypatch.setattr(hb, "MARCHED_STEPS", len(w))
    marched = predict_sweeps(s, els, "x", w, forces)
    for a, b in zip(fast, marched):
        assert (a.converged == b.converged).all() and (a.stable == b.stable).all()
        scale = np.abs(b.y).max(axis=0, keepdims=True)
        assert np.abs(a.y - b.y).max() <= 1e-9 * scale.max()
        assert (np.abs(a.y - b.y) <= 1e-9 * scale).all()


def _one_restart_after_another(sys_, fns, F, orders, step, items, y, converged, tried):
    """The march's line as its rule states it, one Newton solve per start: from the previous line's solution,
    then each restart of ``_restarts`` in order until one converges (after a line with no solution only the
    linear response); ``tried`` counts the restarts solved."""
    import analysis.prediction.harmonic_balance as hb

    for b in items:
        line = orders[b, step]
        balance = hb._LineBalances.at(sys_, fns, np.array([line]), F[[line], [b]])
        if step == 0:
            starts = [balance.gF]
        else:
            prev = orders[b, step - 1]
            restarts = list(hb._restarts(y[[prev], b], balance.gF))
            starts = [y[[prev], b]] + (restarts if converged[prev, b] else restarts[:1])
        for attempt, start in enumerate(starts):
            sol, ok = balance.solve(start, np.array([0]))
            tried[0] += attempt > 0
            if attempt == 0 or ok[0]:
                y[line, b] = sol[0]
            if ok[0]:
                break
        converged[line, b] = ok[0]


@pytest.mark.parametrize("laws, force", [
    pytest.param([{"law": "coulomb", "fs": 0.6}], 0.5, marks=pytest.mark.slow),   # sticks: no solution at any line
    ([{"law": "cubic", "k3": 1e4}], 2.0),                                  # jumps off its fold
    ([{"law": "cubic", "k3": -3e3}, {"law": "quadratic_damping", "c2": 0.05}], 2.0),
])
def test_restarts_solved_as_one_batch_are_the_restarts_tried_one_after_another(laws, force, monkeypatch):
    """A line that does not converge from the previous one solves all its restarts in one batch and takes the
    first in order that converges: the phasors and flags of trying them one after another."""
    import analysis.prediction.harmonic_balance as hb

    s, els = sdof(laws)
    w = np.linspace(5.0, 25.0, 60)
    monkeypatch.setattr(hb, "MARCHED_STEPS", len(w))                        # every line marched
    batch = predict_sweeps(s, els, "x", w, [force, 0.5 * force])
    tried = [0]
    monkeypatch.setattr(hb, "_march_step", lambda *a: _one_restart_after_another(*a, tried))
    spec = predict_sweeps(s, els, "x", w, [force, 0.5 * force])
    assert tried[0] > 0                                                     # restarts were needed
    for a, b in zip(batch, spec):
        assert (a.converged == b.converged).all() and (a.stable == b.stable).all()
        np.testing.assert_allclose(a.y, b.y, rtol=0, atol=1e-12 * np.abs(b.y).max())


def test_attempts_after_an_items_first_converged_one_are_needless_and_stop_where_they_are():
    """Restarts in one batch: once an attempt of an item converges, its later attempts stop (their answer is
    never taken) while its earlier ones go on to their end, so the first converged attempt is what solving
    every attempt to its end gives."""
    from analysis.prediction.harmonic_balance import _after_the_first, _newton

    which = np.array([0, 1, 0, 1, 0])                     # attempt by attempt: item 0 at rows 0, 2, 4
    needless = _after_the_first(which)
    assert needless(np.array([False, True, True, False, True])).tolist() == [False, False, False, True, True]
    assert not needless(np.zeros(5, bool)).any()

    # three attempts of one item: x^2 = 4 from far (slow) and from near (fast), and z = 0 with a Jacobian 100 x
    # too steep (1 % closer per step, all 30 steps when solved to its end); once the second has converged the
    # first goes on to its end and the third stops
    calls = []

    def fun(z, idx):
        calls.append(idx.copy())
        return np.where(idx[:, None] == 2, z, z ** 2 - 4.0)

    def jac(z, idx):
        return np.where(idx[:, None, None] == 2, 100.0, 2 * z[:, :, None])

    z0 = np.array([[1e3], [3.0], [1.0]])
    z, converged = _newton(fun, jac, z0, needless=_after_the_first(np.zeros(3, int)))
    alone, _ = _newton(fun, jac, z0[:1])
    assert converged.tolist() == [True, True, False] and z[0, 0] == alone[0, 0] == pytest.approx(2.0)
    second_done = next(k for k, idx in enumerate(calls) if k > 0 and 1 not in idx)
    assert all(2 not in idx for idx in calls[second_done:]) and 0 in calls[-1]
    solved_to_its_end, _ = _newton(fun, jac, z0)
    assert abs(solved_to_its_end[2, 0]) < abs(z[2, 0])                  # it did stop early


def test_newton_takes_a_stalled_residual_as_a_solution_only_below_its_stall_tolerance():
    """An item whose function is exact only to 5e-11 stops where no step lowers it and converges if that is
    below ``stalled_tol``; an item with no root stops too and never converges; an exact one meets ``tol``."""
    from analysis.prediction.harmonic_balance import _newton

    def each(z):
        exact = z[:, 0] - 1.0
        rounded = 1e-10 * (np.floor((z[:, 1] - 1.0) / 1e-10) + 0.5)       # |f| >= 5e-11 everywhere
        rootless = z[:, 2] ** 2 + 1.0
        return exact, rounded, rootless

    def fun(z, idx):
        return np.stack(each(np.repeat(z, 3, axis=1)), axis=1)[np.arange(len(idx)), idx][:, None]

    def jac(z, idx):
        slope = np.where(idx == 2, 2 * z[:, 0], 1.0)
        return np.where(slope == 0, 1e-300, slope)[:, None, None]

    z0 = np.array([[3.0], [3.0], [0.5]])
    for stalled_tol, expected in ((1e-8, [True, True, False]), (0.0, [True, False, False])):
        z, converged = _newton(fun, jac, z0, tol=1e-11, max_iter=60, stalled_tol=stalled_tol)
        assert converged.tolist() == expected
        assert abs(z[0, 0] - 1) < 1e-11 and abs(z[1, 0] - 1) < 1e-9


CHAIN2 = {"type": "lumped", "dofs": ["x1", "x2"], "mass": [[1.0, 0.0], [0.0, 1.0]],
          "stiffness": [[3000.0, -1000.0], [-1000.0, 2000.0]], "rayleigh": [0.3, 1.0e-4]}


@pytest.mark.parametrize("laws, second", [
    ([{"law": "anderson_ferri", "a": 0.1, "b": 30.0, "c": 0.0}], None),
    ([{"law": "jenkins", "kt": 500.0, "fs": 0.2}], [{"law": "cubic", "k3": 3e6}]),
    ([{"law": "gap", "k": 3000.0, "gap": 0.002}], None),
    ([{"law": "iwan", "kt": 800.0, "fs": 0.3, "chi": -0.5, "beta": 0.1}], None),
])
def test_the_lines_solved_all_at_once_are_each_line_solved_on_its_own(laws, second):
    """Started from the single-harmonic solution, each line's multi-harmonic balance is independent of the
    others': the batch (Broyden from a difference Jacobian) lands where scipy's hybr lands from the same start,
    line by line, to the balance's tolerance."""
    from analysis.prediction.multiharmonic import _MultiharmonicLines
    s = load_structure(CHAIN2)
    spec = [{"name": "b", "dof": "x2", "laws": laws}] + ([{"name": "a", "dof": "x1", "laws": second}] if second else [])
    els = load_elements({"element": spec}, s, None, True)
    w = 2 * np.pi * np.arange(5.0, 11.01, 0.4)
    single = predict_sweep(s, els, "x2", w, 0.5)
    mh = predict_multiharmonic(s, els, "x2", w, 0.5, 7, 512, y_start=single.y[:, 0])
    lines = _MultiharmonicLines(s, els, "x2", w, np.full(len(w), 0.5), 7, 512)
    start = np.zeros((len(w), 8, len(els)), complex)
    start[:, 1] = single.y[:, 0]
    alone = np.array([lines.solve_one(i, start[i]) for i in range(len(w))])
    ok = np.linalg.norm(lines.residual(alone, np.arange(len(w))), axis=1) < 1e-8
    assert mh.converged[ok].all() and ok.sum() >= len(w) - 1
    each = lines.unpack(alone, np.arange(len(w)))
    scale = np.abs(mh.element_harmonics[:, 1]).max()
    np.testing.assert_allclose(mh.element_harmonics[ok], each[ok], rtol=0, atol=1e-7 * scale)


@pytest.mark.parametrize("name, values", [("jenkins", {"kt": 500.0, "fs": 0.2}),
                                          ("iwan", {"kt": 1e4, "fs": 0.5, "chi": -0.3, "beta": 0.5})])
@pytest.mark.parametrize("relative", [False, True])
def test_a_hysteretic_periodic_march_through_the_first_periods_turning_points_is_the_full_march_bit_for_bit(
        name, values, relative):
    """A rate-independent hysteretic law's first period is marched through its turning points alone
    (:func:`analysis.laws.base._periodic_marcher`): its state after them is the one the march through every sample
    leaves, so the kept period is the same to the bit -- on motions with a mean, up to nine harmonics (many
    turns a period), a flat row, a plateau and a NaN."""
    from analysis.laws import LAWS
    rng = np.random.default_rng(7)
    n = 128
    theta = 2 * np.pi * np.arange(n) / n
    rows = []
    for _ in range(60):
        order = int(rng.integers(1, 10))
        size = rng.normal(size=order + 1) * np.logspace(-4, -2, order + 1)[rng.permutation(order + 1)]
        phase = rng.uniform(0, 2 * np.pi, order + 1)
        rows.append(size[0] + sum(size[k] * np.sin(k * theta + phase[k]) for k in range(1, order + 1)))
    x = np.array(rows)
    x[0] = 0.0
    x[1, :9] = x[1, 9]
    x[2, 40] = np.nan
    v = np.gradient(x, axis=1)
    law = LAWS[name].relative() if relative else LAWS[name]
    p = law.parameter_vector(**values)
    kept = law.march_periodic(x, v, p)
    for b in range(len(x)):
        twice = law.march(np.tile(x[b], 2), np.tile(v[b], 2), p)[n:]
        assert np.array_equal(kept[b], twice, equal_nan=True), b


def test_a_periodic_march_is_the_second_period_of_the_motion_marched_twice_from_rest():
    """Rows are independent periodic motions: each is marched from rest, its last period kept; a law without
    state needs one period."""
    from analysis.laws import LAWS
    theta = 2 * np.pi * np.arange(64) / 64
    X = np.array([[0.5e-3], [2e-3], [4e-3]])
    x, v = X * np.sin(theta), 30.0 * X * np.cos(theta)
    for name, values in (("jenkins", {"kt": 500.0, "fs": 0.2}), ("cubic", {"k3": 3e6})):
        law = LAWS[name]
        p = law.parameter_vector(**values)
        rows = law.march_periodic(x, v, p)
        for b in range(len(X)):
            twice = law.march(np.tile(x[b], 2), np.tile(v[b], 2), p)
            np.testing.assert_allclose(rows[b], twice[64:], rtol=0, atol=1e-14)


def test_the_line_search_takes_the_step_that_halving_one_at_a_time_takes_in_three_calls_at_most():
    """Each item takes the first of dz, dz/2, ... that lowers its residual norm, and the caller hears of the steps
    taken: the same as trying them one after the other, in at most three calls of the residual."""
    from analysis.prediction.harmonic_balance import _line_search
    rng = np.random.default_rng(7)
    B, halvings = 60, 12
    target = rng.normal(size=(B, 2))

    def fun(z, idx):
        d = z - target[idx]
        return np.stack([d[:, 0] + 0.3 * d[:, 1] ** 3, d[:, 1] + np.sin(3 * d[:, 0])], axis=1)

    z0 = target + rng.normal(size=(B, 2))
    # Newton-like directions overshooting by 2^k: the step that lowers the norm is found after k halvings or so
    dz = -(z0 - target) * 2.0 ** rng.integers(0, 14, B)[:, None]
    active = np.flatnonzero(rng.random(B) < 0.8)

    def one_at_a_time():
        z, R = z0.copy(), fun(z0, np.arange(B))
        norm = np.linalg.norm(R, axis=1)
        alpha, improved, steps = np.ones(len(active)), np.zeros(len(active), bool), {}
        for _ in range(halvings):
            left = np.flatnonzero(~improved)
            items = active[left]
            z_try = z[items] + alpha[left, None] * dz[left]
            R_try = fun(z_try, items)
            ok = np.linalg.norm(R_try, axis=1) < norm[items]
            for i, zz in zip(items[ok], z_try[ok]):
                steps[i] = zz - z[i]
            z[items[ok]], norm[items[ok]] = z_try[ok], np.linalg.norm(R_try[ok], axis=1)
            improved[left[ok]] = True
            alpha[left[~ok]] *= 0.5
        return z, norm, improved, steps

    z_ref, norm_ref, improved_ref, steps_ref = one_at_a_time()
    z, R = z0.copy(), fun(z0, np.arange(B))
    norm, calls, heard = np.linalg.norm(R, axis=1), [], {}

    def counted(zz, idx):
        calls.append(len(idx))
        return fun(zz, idx)

    def taken(items, step, change):
        heard.update(zip(items.tolist(), step))
        np.testing.assert_allclose(change, fun(z[items] + step, items) - R[items], atol=1e-12)

    improved = _line_search(counted, z, R, norm, active, dz, halvings, taken)
    assert improved.tolist() == improved_ref.tolist() and 0 < improved.sum() < len(active)
    np.testing.assert_array_equal(z, z_ref)
    np.testing.assert_array_equal(norm, norm_ref)
    np.testing.assert_allclose(R, fun(z, np.arange(B)), atol=0)
    assert sorted(heard) == sorted(steps_ref)
    for i in heard:
        np.testing.assert_array_equal(heard[i], steps_ref[i])
    assert len(calls) <= 3


@pytest.mark.parametrize("meets", [False, True])
def test_a_multiharmonic_batch_whose_probed_lines_meet_no_balance_solves_no_other_line(meets, monkeypatch):
    """The lines whose single-harmonic start is nearest a balance are solved first; where none of them converges no
    other line is solved (each is left at its start), and where one does every line is solved, as the batch alone
    would be."""
    from analysis.prediction import multiharmonic as mh_module
    from analysis.prediction.multiharmonic import PROBED_LINES, _MultiharmonicLines
    s = load_structure(CHAIN2)
    els = load_elements({"element": [{"name": "b", "dof": "x2", "laws": [{"law": "cubic", "k3": 3e6}]}]}, s, None,
                        True)
    w = 2 * np.pi * np.arange(5.0, 11.01, 0.1)
    single = predict_sweep(s, els, "x2", w, 0.5)
    lines = _MultiharmonicLines(s, els, "x2", w, np.full(len(w), 0.5), 5, 128)
    start = np.zeros((len(w), 6, 1), complex)
    start[:, 1] = single.y[:, 0]
    z0 = lines.pack(start, np.arange(len(w)))
    nearest = np.argsort(np.linalg.norm(lines.residual(z0, np.arange(len(w))), axis=1))[:PROBED_LINES]
    solver, solved = mh_module._quasi_newton, []

    def recorded(fun, jac, z, tol, stalled_tol, max_iter=40):
        solved.append(z.copy())
        if meets:
            return solver(fun, jac, z, tol, stalled_tol, max_iter)
        return z, np.zeros(len(z), bool)                    # a force with no smooth balance: nothing met

    monkeypatch.setattr(mh_module, "_quasi_newton", recorded)
    mh = predict_multiharmonic(s, els, "x2", w, 0.5, 5, 128, y_start=single.y[:, 0])
    assert len(solved[0]) == PROBED_LINES < len(w)
    np.testing.assert_array_equal(solved[0], z0[np.sort(nearest)])          # the lines nearest a balance first
    if not meets:
        others = np.setdiff1d(np.arange(len(w)), nearest)
        assert len(solved) == 1
        # left at the start
        np.testing.assert_allclose(mh.element_harmonics[others, 1, 0], single.y[others, 0, 0], rtol=1e-14)
        return
    assert sum(len(z) for z in solved) == len(w) and mh.converged.all()
    z, _ = solver(lines.residual, lines.jacobian, z0, 1e-12, 1e-8)
    # the same balance to the batch's rounding (a batch's products may be summed in another order)
    np.testing.assert_allclose(mh.element_harmonics, lines.unpack(z, np.arange(len(w))), rtol=0,
                               atol=1e-12 * np.abs(single.y).max())


def _contact_chain():
    """A one-sided contact between the first two masses of a chain driven at the third (modes 1.49, 4.25 and
    8.39 Hz); its mass and stiffness matrices and damping."""
    M = np.diag([0.695, 1.875, 1.982])
    K = np.array([[1820.0, -658.0, 0.0], [-658.0, 1247.0, -589.0], [0.0, -589.0, 589.0]])
    s = load_structure({"type": "lumped", "dofs": ["x1", "x2", "x3"], "mass": M.tolist(), "stiffness": K.tolist(),
                        "rayleigh": [0.452, 0.0018]})
    els = load_elements({"element": [{"name": "a", "between": ["x1", "x2"],
                                      "laws": [{"law": "unilateral", "k": 3376.0, "gap": 0.0285}]}]}, s, None, True)
    return s, els, M, K


def _swept_start(s, els, f_hz, force):
    """Single-harmonic element phasors at lines ``f_hz``, swept up to them from 1.1 Hz."""
    sweep = 2 * np.pi * np.union1d(np.arange(1.1, max(f_hz), 0.0148), f_hz)
    return predict_sweep(s, els, "x3", sweep, force, "up").y[np.searchsorted(sweep, 2 * np.pi * np.asarray(f_hz)), 0]


def test_a_criterion_resolves_a_tenth_of_the_error_the_test_allows_and_never_coarser_than_its_tolerance():
    assert HarmonicCriterion().truncation == HARMONIC_TRUNCATION
    assert HarmonicCriterion().resolving(None).truncation == HARMONIC_TRUNCATION
    assert HarmonicCriterion().resolving(2e-3).truncation == HARMONIC_TRUNCATION        # a test that repeats well
    resolved = HarmonicCriterion(limit=0.02, n_harmonics=5).resolving(0.176)
    assert resolved.truncation == pytest.approx(0.0176)
    assert (resolved.limit, resolved.n_harmonics) == (0.02, 5)


def test_the_estimate_of_what_the_harmonics_left_out_move_flags_every_line_they_move():
    # lines of a contact about the first resonance, balanced with 7 and with 28 harmonics: wherever the fundamental
    # moves by more than the tolerance between the two, the estimate made from the 7 says so
    s, els, _, _ = _contact_chain()
    f = np.array([1.25, 1.3963, 1.45, 1.5, 1.5444, 1.6])
    w, y0 = 2 * np.pi * f, _swept_start(s, els, f, 3.68)
    seven = predict_multiharmonic(s, els, "x3", w, 3.68, 7, 512, y_start=y0)
    many = predict_multiharmonic(s, els, "x3", w, 3.68, 28, 512, y_start=y0)
    assert seven.converged.all() and many.converged.all()
    moved = np.abs(seven.element_harmonics[:, 1, 0] / many.element_harmonics[:, 1, 0] - 1)
    estimate = omitted_harmonics(s, els, "x3", w, seven.element_harmonics, 14, 512)
    assert (moved > HARMONIC_TRUNCATION).sum() >= 4
    assert (estimate[moved > HARMONIC_TRUNCATION] > HARMONIC_TRUNCATION).all()
    assert estimate[0] == moved[0] == 0.0                       # below the contact's closing: no harmonics


def test_a_line_takes_no_more_harmonics_than_the_forces_samples_resolve():
    # 64 points a period resolve 15 harmonics (n_time >= 4 H + 2): a line that would take 28 stops at 15
    s, els, _, _ = _contact_chain()
    w = 2 * np.pi * np.array([1.5444])
    balanced = predict_multiharmonic_converged(s, els, "x3", w, 3.68, _swept_start(s, els, [1.5444], 3.68), 7, 64, 28)
    assert balanced.converged.all() and 7 < balanced.n_used[0] <= 15


@pytest.mark.slow
def test_a_line_takes_the_harmonics_its_motion_needs_and_meets_the_time_march():
    # the contact chain at its first resonance: the contact's harmonics fall off slowly, and seven of them miss
    # the fundamental by percents where the harmonics left out still move it; the balance taken to the harmonics
    # the line needs meets the time march (solve_ivp, no code of the project) to the tolerance, and a line where
    # the contact stays open keeps seven
    s, els, M, K = _contact_chain()
    a, b, kc, gap, F = 0.452, 0.0018, 3376.0, 0.0285, 3.68

    def rhs(t, z, w):
        x, v = z[:3], z[3:]
        fc = kc * max(x[1] - x[0] - gap, 0.0)
        return np.concatenate([v, (np.array([fc, -fc, F * np.sin(w * t)]) - (a * M + b * K) @ v - K @ x) / np.diag(M)])

    def fundamental(w, periods=60, n=256):
        T = 2 * np.pi / w
        settled = solve_ivp(rhs, (0, periods * T), np.zeros(6), args=(w,), rtol=1e-9, atol=1e-12, method="DOP853")
        t = periods * T + np.arange(n) * T / n
        last = solve_ivp(rhs, (periods * T, t[-1]), settled.y[:, -1], t_eval=t, args=(w,), rtol=1e-10, atol=1e-13,
                         method="DOP853")
        return 2 / n * np.sum(last.y[:3] * (np.sin(w * t) + 1j * np.cos(w * t)), axis=1)

    w, y0 = 2 * np.pi * np.array([1.25, 1.5444]), _swept_start(s, els, [1.25, 1.5444], F)
    seven = predict_multiharmonic(s, els, "x3", w, F, 7, 512, y_start=y0)
    needed = predict_multiharmonic_converged(s, els, "x3", w, F, y0, 7, 512, 28)
    assert needed.converged.all() and needed.n_used.tolist()[0] == 7 and needed.n_used[1] > 7
    for line in range(2):
        ref = fundamental(w[line])
        miss = lambda X: np.linalg.norm(X - ref) / np.linalg.norm(ref)         # noqa: E731
        assert miss(needed.harmonics[line, 1]) < 3 * HARMONIC_TRUNCATION
        if line:
            assert miss(seven.harmonics[line, 1]) > 0.02
            assert needed.harmonics.shape[1] == needed.n_used[1] + 1
            np.testing.assert_array_equal(needed.harmonics[0, 8:], 0.0)
