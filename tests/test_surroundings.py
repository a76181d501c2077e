"""A one-sided contact placed in its structure: its mean and harmonics against the static balance in closed form
and against time integration written here (solve_ivp), and the fit that finds it back."""
import numpy as np
import pytest
from scipy.integrate import solve_ivp
from scipy.optimize import brentq

from analysis import load_elements, load_structure
from analysis.fitting.fit import fit_laws
from analysis.prediction.harmonic_balance import predict_sweep
from analysis.laws import get_law
from analysis.laws.base import Law, Param
from analysis.laws.unilateral import unilateral_force
from analysis.common.small_solve import NOT_FINITE, SINGULAR, SOLVED, solve_small
from analysis.mechanics import surroundings
from analysis.mechanics.surroundings import _cycle, placed_kbar

UNILATERAL = get_law("unilateral")
K_S, M_S, C_S = 1000.0, 1.0, 2 * 0.02 * np.sqrt(1000.0)
CONTACT = {"k": 800.0, "gap": 0.004}


def sdof(laws):
    s = load_structure({"type": "lumped", "dofs": ["x"], "mass": [[M_S]], "stiffness": [[K_S]],
                        "damping": [[C_S]]})
    return s, load_elements({"element": [{"name": "c", "dof": "x", "laws": laws}]}, s, None, True)


def contact(x, k=CONTACT["k"], gap=CONTACT["gap"]):
    return np.where(x > gap, k * (x - gap), 0.0)


def test_mean_alone_is_the_static_balance_in_closed_form():
    """Without harmonics the mean solves x0 = -f0(x0, X) / k_s, with the mean force of the contact over a cycle
    f0 = (k X / pi)(sqrt(1 - u^2) - u acos u), u = (gap - x0) / X, and kbar is the describing function at u."""
    s, (el,) = sdof([{"law": "unilateral", **CONTACT}])
    k, gap = CONTACT["k"], CONTACT["gap"]
    X = np.array([0.005, 0.01, 0.03])

    def placed(x0, amplitude):
        u = np.clip((gap - x0) / amplitude, -1.0, 1.0)
        return k * amplitude / np.pi * (np.sqrt(1 - u * u) - u * np.arccos(u))

    expected = []
    for amplitude in X:
        x0 = brentq(lambda x0: K_S * x0 + placed(x0, amplitude), -amplitude, 0.0, xtol=1e-15)
        u = (gap - x0) / amplitude
        expected.append(k / 2 * (1 - 2 / np.pi * (np.arcsin(u) + u * np.sqrt(1 - u * u))))
    got = placed_kbar([(UNILATERAL, CONTACT)], X, 20.0, el.surroundings, n_harmonics=1, n_time=4096)
    np.testing.assert_allclose(got.real, expected, rtol=2e-4)
    assert np.all(got.real < 0.9 * UNILATERAL.describing_function(X, 20.0, **CONTACT).real)


def integrated_kbar(w, force, periods=40, contact=contact):
    """kbar of the contact from a time integration of the SDOF from rest: fundamental of its force over the
    fundamental of its displacement, over the last ten periods; returns the amplitude and kbar."""
    T = 2 * np.pi / w

    def rhs(t, y):
        return [y[1], (force * np.sin(w * t) - C_S * y[1] - K_S * y[0] - contact(y[0])) / M_S]

    sol = solve_ivp(rhs, [0, periods * T], [0.0, 0.0], rtol=1e-9, atol=1e-12, dense_output=True, max_step=T / 100)
    t = np.linspace((periods - 10) * T, periods * T, 2000, endpoint=False)
    x = sol.sol(t)[0]
    phasor = lambda s: 2 * np.mean(s * np.exp(-1j * w * t))   # noqa: E731
    X1, f1 = phasor(x), phasor(contact(x))
    return abs(X1), f1 / X1


@pytest.mark.slow
def test_placed_kbar_is_the_fundamental_of_a_time_integration():
    """The contact's mean and its harmonics move the mass; kbar placed in the structure is the integration's,
    the describing function alone is 15-25 % off near resonance, and the mean alone without the harmonics 4-6 %."""
    s, (el,) = sdof([{"law": "unilateral", **CONTACT}])
    for hz in (4.6, 5.0):
        w = 2 * np.pi * hz
        X, truth = integrated_kbar(w, 4.0)
        placed = el.describing_function(X, w)
        assert abs(placed - truth) < 5e-3 * abs(truth), (hz, placed, truth)
        alone = UNILATERAL.describing_function(X, w, **CONTACT)
        assert abs(alone - truth) > 0.1 * abs(truth)
        # the mean alone (the static balance, no harmonics) is not enough either
        mean_only = placed_kbar([(UNILATERAL, CONTACT)], X, w, el.surroundings, n_harmonics=1)
        assert abs(mean_only - truth) > 0.03 * abs(truth)


@pytest.mark.slow
def test_single_harmonic_sweep_with_a_contact_matches_time_integration():
    """A 2-DOF chain with a contact at the grounded mass, driven at the other: the fundamental amplitude of the
    single-harmonic sweep within 0.5 % of RK45 (from rest) at lines across the contact's resonance; with the
    describing function alone 5-40 % off."""
    M = np.diag([1.0, 0.8])
    K = np.array([[1500.0, -600.0], [-600.0, 600.0]])
    C = 0.002 * K + 0.2 * M
    k, gap, force = 900.0, 0.002, 3.0
    s = load_structure({"type": "lumped", "dofs": ["x1", "x2"], "mass": M.tolist(), "stiffness": K.tolist(),
                        "damping": C.tolist()})
    els = load_elements({"element": [{"name": "c", "dof": "x1", "laws": [{"law": "unilateral", "k": k,
                                                                           "gap": gap}]}]}, s, None, True)
    hz = np.linspace(2.0, 3.6, 33)
    w = 2 * np.pi * hz
    placed = np.abs(predict_sweep(s, els, "x2", w, force, "up").y[:, 0, 0])
    alone = np.abs(predict_sweep(s, els, "x2", w, force, "up",
                                 kbar_fns=[UNILATERAL.kbar_function(k=k, gap=gap)]).y[:, 0, 0])
    lines = np.array([4, 16, 24, 28])
    wl = w[lines]
    Minv = np.linalg.inv(M)

    def rhs(tau, y):
        """Every line at once in its own dimensionless time tau = w t (y: x1, x2, v1, v2 of each line)."""
        x, v = y.reshape(4, -1)[:2], y.reshape(4, -1)[2:]
        f = K @ x + C @ v
        f[0] += contact(x[0], k, gap)
        f[1] -= force * np.sin(tau)
        return np.concatenate([v / wl, -(Minv @ f) / wl]).ravel()

    # 60 periods of each from rest; at most 1/100 period a step (the contact's kink)
    sol = solve_ivp(rhs, [0, 60 * 2 * np.pi], np.zeros(4 * len(lines)), rtol=1e-9, atol=1e-12, dense_output=True,
                    max_step=2 * np.pi / 100)
    tau = np.linspace(50 * 2 * np.pi, 60 * 2 * np.pi, 2000, endpoint=False)
    X = np.abs(2 * np.mean(sol.sol(tau)[:len(lines)] * np.exp(-1j * tau), axis=1))
    for i, Xi in zip(lines, X):
        assert placed[i] == pytest.approx(Xi, rel=5e-3), hz[i]
        assert abs(alone[i] / Xi - 1) > 0.04, hz[i]


def test_fit_finds_a_placed_contact_back_and_the_describing_function_alone_does_not():
    s, (el,) = sdof([{"law": "unilateral", **CONTACT}])
    X = np.geomspace(2e-3, 3e-2, 24)
    w = 2 * np.pi * np.linspace(3.0, 6.0, 24)
    kbar = placed_kbar([(UNILATERAL, CONTACT)], X, w, el.surroundings)
    for robust in (False, True):
        fit = fit_laws(["unilateral"], X, w, kbar, 0.5, exclude_outliers=robust, surroundings=el.surroundings)
        assert fit.terms[0].params["k"] == pytest.approx(CONTACT["k"], rel=1e-3)
        assert fit.terms[0].params["gap"] == pytest.approx(CONTACT["gap"], rel=1e-3)
        np.testing.assert_allclose(fit.describing_function(X, w), kbar, atol=0.05)
    alone = fit_laws(["unilateral"], X, w, kbar, 0.5)
    assert abs(alone.terms[0].params["k"] / CONTACT["k"] - 1) > 0.05


def test_the_receptances_a_place_keeps_are_the_structures_in_any_order_and_any_batch():
    """A place computes each frequency's receptance once and looks the kept ones up (:meth:`Surroundings.receptance`):
    asked in any order, shape and mix of kept and new frequencies, with repeats, it gives the structure's own
    response at every one, to the bit; a NaN frequency is NaN and is never kept."""
    structure = load_structure({"type": "lumped", "dofs": ["a", "b"], "mass": [[1.0, 0.0], [0.0, 2.0]],
                                "stiffness": [[3000.0, -1000.0], [-1000.0, 1000.0]],
                                "damping": [[1.0, 0.0], [0.0, 0.5]]})
    place = surroundings.surroundings_of(structure, np.array([1.0, -1.0]))
    rng = np.random.default_rng(3)
    lines = rng.uniform(10.0, 80.0, 30)
    for _ in range(12):
        W = rng.choice(lines, size=(5, 4)) * rng.choice([1.0, 2.0, 3.0], size=(5, 4))
        direct = structure.response(W.ravel(), place.vector[:, None])[:, :, 0] @ place.vector
        assert np.array_equal(place.receptance(W), direct.reshape(W.shape))
    place.receptance(lines)
    kept = place._receptances.W.size
    with np.errstate(invalid="ignore"):
        R = place.receptance(np.array([np.nan, lines[0]]))
    assert np.isnan(R[0]) and R[1] == place.receptance(np.array([lines[0]]))[0]
    assert place._receptances.W.size == kept


def test_the_elements_linear_laws_stiffen_the_surroundings():
    """A spring on the element in parallel with the contact is a spring of the structure as the contact sees it:
    the element's kbar is the spring plus the contact placed in the structure stiffened by it."""
    spring = 400.0
    _, (el,) = sdof([{"law": "unilateral", **CONTACT}, {"law": "linear", "k": spring, "c": 0.0}])
    stiffer = load_structure({"type": "lumped", "dofs": ["x"], "mass": [[M_S]], "stiffness": [[K_S + spring]],
                              "damping": [[C_S]]})
    (alone,) = load_elements({"element": [{"name": "c", "dof": "x", "laws": [{"law": "unilateral", **CONTACT}]}]},
                             stiffer, None, True)
    X, w = np.array([0.006, 0.02]), np.array([25.0, 35.0])
    np.testing.assert_allclose(el.describing_function(X, w) - spring, alone.describing_function(X, w), rtol=1e-9)


def test_a_one_sided_law_must_have_one_scaling_parameter_and_no_state():
    with pytest.raises(TypeError, match="one linear parameter"):
        class TwoScales(Law):                                   # noqa: F841
            name, kind, summary = "two_scales", "clearance", "test"
            force_text = kbar_text = explanation = "x"
            params = (Param("k", "{F}/{L}", "a"), Param("q", "{F}/{L}", "b"))
            linear = ("k", "q")
            example = {"k": 1.0, "q": 1.0}
            kernel = unilateral_force
            placed = True

            def basis(self, X, w):
                return np.zeros((2,) + np.shape(X))


@pytest.mark.acceptance
def test_discovery_places_a_contact_and_finds_it_alone():
    """A contact's kbar placed in its structure (with noise): placed, discovery's best set is the contact alone;
    with the formula alone a law of another kind has to fill the placement's difference."""
    from analysis.missing.diagnosis import ElementSamples
    from analysis.search.discovery import search_element

    s, (el,) = sdof([{"law": "unilateral", **CONTACT}])
    X = np.geomspace(1e-3, 3e-2, 60)
    w = 2 * np.pi * np.linspace(3.0, 6.0, 60)
    truth = placed_kbar([(UNILATERAL, CONTACT)], X, w, el.surroundings)
    std = 3e-3 * np.abs(truth) + 0.05
    rng = np.random.default_rng(4)
    kbar = truth + std / np.sqrt(2) * (rng.normal(size=X.size) + 1j * rng.normal(size=X.size))
    samples = ElementSamples("c", X, w, kbar, std, np.ones(X.size))
    placed = search_element(0, samples, False, around=el.surroundings)
    assert placed.sets[0].laws == ("unilateral",)
    k = placed.sets[0].fit.terms[0].params["k"]
    assert k == pytest.approx(CONTACT["k"], rel=0.01)
    alone = search_element(0, samples, False)
    assert len(alone.sets[0].laws) > 1 or alone.sets[0].chi_square > 3 * placed.sets[0].chi_square


def test_a_model_places_its_elements_in_its_own_structure():
    """A model's elements see its structure; a copy shares what was computed of it, an updated structure is seen
    anew."""
    from analysis.mechanics.model import load_model

    table = {"type": "lumped", "dofs": ["x"], "mass": [[M_S]], "stiffness": [[K_S]], "damping": [[C_S]]}
    model = load_model({"structure": table, "element": [{"name": "c", "dof": "x",
                                                         "laws": [{"law": "unilateral", **CONTACT}]}]})
    el = model.elements[0]
    assert el.surroundings.receptance(0.0) == pytest.approx(1.0 / K_S)
    assert model.copy().elements[0].surroundings is el.surroundings
    stiffer = model.with_structure({**table, "stiffness": [[2 * K_S]]})
    assert stiffer.elements[0].surroundings.receptance(0.0) == pytest.approx(0.5 / K_S)
    X, w = 0.01, 30.0
    assert stiffer.elements[0].describing_function(X, w).real > el.describing_function(X, w).real


@pytest.mark.parametrize("n_harmonics, n_time", [(9, 128), (1, 16), (5, 64), (3, 4096)])
def test_the_tangent_blocks_from_fourier_coefficients_are_the_product_they_replace(n_harmonics, n_time):
    """``P diag(t) Phi`` from the Fourier coefficients of t is the direct product to rounding, for tangents that
    switch along the cycle as a contact's does."""
    cycle = _cycle(n_harmonics, n_time)
    rng = np.random.default_rng(n_time)
    for t in rng.random((6, n_time)) * (rng.random((6, n_time)) > 0.4) * 1e3:
        direct = cycle.P @ (t[:, None] * cycle.Phi)
        got = np.empty((cycle.size, cycle.size))
        surroundings._tangent_block(t, cycle.trig, cycle.first, cycle.first_sign, cycle.second,
                                    cycle.second_sign, np.empty(cycle.trig.shape[1]), got)
        np.testing.assert_allclose(got, direct, rtol=0, atol=1e-12 * np.max(np.abs(direct)))


def test_the_small_solve_of_the_balance_and_the_simulator_is_lapacks():
    """The compiled loops' own elimination (partial pivoting) against numpy's solve, on random systems of the
    balance's size and on ones as ill-conditioned as a contact at a mode makes them; an exactly singular one and
    a non-finite one are reported."""
    rng = np.random.default_rng(3)
    for size, condition in [(17, 1.0), (17, 1e-8), (9, 1.0), (2, 1.0)]:
        A = np.eye(size) + rng.normal(size=(size, size))
        A[:, 0] = A[:, 1] + condition * A[:, 0]
        b = rng.normal(size=size)
        x = np.empty(size)
        assert solve_small(A.copy(), b.copy(), x, size) == SOLVED
        np.testing.assert_allclose(A @ x, b, atol=1e-9 * np.abs(A).max() * np.abs(x).max())
        np.testing.assert_allclose(x, np.linalg.solve(A, b), rtol=1e-6 if condition < 1 else 1e-12)
    assert solve_small(np.ones((4, 4)), np.ones(4), np.empty(4), 4) == SINGULAR
    assert solve_small(np.full((2, 2), np.nan), np.ones(2), np.empty(2), 2) == NOT_FINITE
    assert solve_small(np.array([[1.0, 0.0], [0.0, np.inf]]), np.ones(2), np.empty(2), 2) == NOT_FINITE


def test_a_sample_of_bad_numbers_is_nan_and_the_others_are_as_alone():
    """One amplitude NaN among the samples: that sample's kbar is NaN, every other one is the kbar it has asked
    alone, and the place's next balance at the same samples starts the bad one from nothing."""
    _, (el,) = sdof([{"law": "unilateral", **CONTACT}])
    w0 = np.sqrt(K_S / M_S)
    X = np.array([0.01, 0.02, 0.005, np.nan])
    w = np.array([0.7, 0.9, 1.2, 1.0]) * w0
    with np.errstate(invalid="ignore"):
        got = placed_kbar([(UNILATERAL, CONTACT)], X, w, el.surroundings)
        again = placed_kbar([(UNILATERAL, CONTACT)], X, w, el.surroundings)
    assert np.isnan(got[3]) and np.isnan(again[3])
    for i in range(3):
        _, (alone,) = sdof([{"law": "unilateral", **CONTACT}])
        np.testing.assert_allclose(got[i], placed_kbar([(UNILATERAL, CONTACT)], X[i], w[i], alone.surroundings),
                                   rtol=1e-9)
    np.testing.assert_allclose(again[:3], got[:3], rtol=1e-9)


def test_placed_laws_of_one_element_act_together():
    """Two one-sided contacts at the same gap are one of the summed stiffness; at different gaps their balance
    is not the sum of each one's alone (they share the mean), and it is the fundamental of a time integration."""
    split = [(UNILATERAL, {"k": 300.0, "gap": CONTACT["gap"]}), (UNILATERAL, {"k": 500.0, "gap": CONTACT["gap"]})]
    _, (el,) = sdof([{"law": "unilateral", **CONTACT}])
    w0 = np.sqrt(K_S / M_S)
    X, w = np.array([0.006, 0.01, 0.02]), np.array([0.8, 1.1, 0.95]) * w0
    np.testing.assert_allclose(placed_kbar(split, X, w, el.surroundings),
                               placed_kbar([(UNILATERAL, CONTACT)], X, w, el.surroundings), rtol=1e-9)
    apart = [(UNILATERAL, {"k": 300.0, "gap": 0.003}), (UNILATERAL, {"k": 500.0, "gap": 0.006})]
    hz = 4.6
    amplitude, expected = integrated_kbar(2 * np.pi * hz, 4.0,
                                          contact=lambda x: contact(x, 300.0, 0.003) + contact(x, 500.0, 0.006))
    both = placed_kbar(apart, amplitude, 2 * np.pi * hz, el.surroundings)
    assert abs(both - expected) < 1e-2 * abs(expected), (both, expected)
    each = sum(placed_kbar([term], amplitude, 2 * np.pi * hz, el.surroundings) for term in apart)
    assert abs(each - expected) > 5 * abs(both - expected)


def test_a_sample_without_a_balance_is_given_up_and_leaves_the_others_as_they_are(monkeypatch):
    """A contact five times as stiff as the structure, at half its natural frequency: its second harmonic meets the
    mode and the balance has no solution. The sample is given up after ``_MAX_ITERATIONS`` Newton steps with a
    finite kbar, and the samples that do balance get the kbar they get without it."""
    w0 = np.sqrt(K_S / M_S)
    stiff = {"k": 5 * K_S, "gap": 0.002}
    _, (el,) = sdof([{"law": "unilateral", **stiff}])
    X, w = np.array([0.01, 0.01, 0.01]), np.array([w0 / 2, 0.3 * w0, 1.5 * w0])
    balanced = placed_kbar([(UNILATERAL, stiff)], X[1:], w[1:], el.surroundings)
    steps = _counting_steps(monkeypatch)
    got = placed_kbar([(UNILATERAL, stiff)], X, w, el.surroundings)
    assert steps[0][0] == surroundings._MAX_ITERATIONS                  # the one without a balance
    assert max(steps[0][1:]) < surroundings._MAX_ITERATIONS
    assert np.all(np.isfinite(got))
    np.testing.assert_allclose(got[1:], balanced, rtol=1e-9)


def test_a_balance_starts_from_the_last_one_at_its_samples_and_answers_as_from_nothing(monkeypatch):
    """A fit asks the same samples at parameters a step apart: the balance starts from the one solved there last
    and takes fewer steps, and every sample gets the kbar it gets from no harmonics -- the one without a balance
    too, started again from nothing, so that no answer depends on the evaluations before it."""
    w0 = np.sqrt(K_S / M_S)
    stiff = {"k": 5 * K_S, "gap": 0.002}
    X, w = np.array([0.01, 0.01, 0.01, 0.006]), np.array([w0 / 2, 0.3 * w0, 1.5 * w0, 0.9 * w0])
    nearby = {"k": stiff["k"] * (1 + 1e-6), "gap": stiff["gap"]}
    cold = {}
    for name, values in (("stiff", stiff), ("nearby", nearby)):
        _, (fresh,) = sdof([{"law": "unilateral", **stiff}])
        cold[name] = placed_kbar([(UNILATERAL, values)], X, w, fresh.surroundings)
    _, (el,) = sdof([{"law": "unilateral", **stiff}])
    placed_kbar([(UNILATERAL, stiff)], X, w, el.surroundings)
    steps = _counting_steps(monkeypatch)
    warm = placed_kbar([(UNILATERAL, nearby)], X, w, el.surroundings)
    np.testing.assert_allclose(warm[1:], cold["nearby"][1:], rtol=1e-9)
    # the sample without a balance: its answer from nothing (a stalled Newton's last step, to its rounding)
    np.testing.assert_allclose(warm[0], cold["nearby"][0], rtol=1e-7)
    assert not np.allclose(cold["nearby"][0], cold["stiff"][0], rtol=1e-7)     # and not the start's answer
    # the warm start: the others converge within its few steps, and fewer than from nothing
    warm_steps = steps[0]
    assert np.all(warm_steps[1:] < surroundings._WARM_ITERATIONS)
    cold_steps = _counting_steps(monkeypatch)
    _, (fresh,) = sdof([{"law": "unilateral", **stiff}])
    placed_kbar([(UNILATERAL, nearby)], X, w, fresh.surroundings)
    assert np.all(warm_steps[1:] < cold_steps[0][1:])
    # and a copy of the place with laws in parallel shares what was solved
    assert el.surroundings.with_parallel(None).starts is el.surroundings.starts


def test_a_contact_that_never_acts_is_settled_in_one_step_with_no_force_and_the_others_as_alone(monkeypatch):
    """A sample whose contact stays open over the whole cycle (X below the gap) has no force and no harmonics: its
    balance holds as it starts, in one step, kbar exactly 0; the samples beside it that close are as alone."""
    w0 = np.sqrt(K_S / M_S)
    X, w = np.array([0.001, 0.01, 0.003, 0.006]), np.array([0.5 * w0, 0.9 * w0, 1.2 * w0, 1.5 * w0])
    steps = _counting_steps(monkeypatch)
    _, (el,) = sdof([{"law": "unilateral", **CONTACT}])
    both = placed_kbar([(UNILATERAL, CONTACT)], X, w, el.surroundings)
    open_ = X < CONTACT["gap"]
    assert np.all(both[open_] == 0.0) and np.all(steps[0][open_] == 1)
    for i in np.flatnonzero(~open_):
        _, (alone,) = sdof([{"law": "unilateral", **CONTACT}])
        assert placed_kbar([(UNILATERAL, CONTACT)], X[i:i + 1], w[i:i + 1], alone.surroundings)[0] == both[i]
        assert abs(both[i]) > 0.0


def _counting_steps(monkeypatch) -> list:
    """The Newton steps each sample takes in every solve of the balances made from now (one array per solve)."""
    steps = []
    solve = surroundings._Balance.solve

    def counted(self, z, active, iterations):
        left = solve(self, z, active, iterations)
        steps.append(self.steps.copy())
        return left

    monkeypatch.setattr(surroundings._Balance, "solve", counted)
    return steps


BILINEAR = get_law("bilinear")
SPRING = {"k_pos": 800.0, "k_neg": 200.0}


def bilinear(x, k_pos=SPRING["k_pos"], k_neg=SPRING["k_neg"]):
    return np.where(x > 0.0, k_pos * x, k_neg * x)


def test_a_bilinear_spring_placed_is_the_fundamental_of_a_time_integration_and_cannot_tell_its_side():
    """A spring stiffer in tension than in compression: its mean and even harmonics move the mass, so its kbar
    placed in the structure is the integration's (RK45 from rest, written here) where the formula's
    (k_pos + k_neg)/2 is 9 % off; the same spring mirrored (k_pos and k_neg swapped) has the same placed kbar, and
    amplitude scales the motion and leaves kbar as it is (a linear structure with a bilinear spring is
    homogeneous of degree one)."""
    s, (el,) = sdof([{"law": "bilinear", **SPRING}])
    w = 2 * np.pi * 5.5
    X, truth = integrated_kbar(w, 4.0, periods=100, contact=bilinear)
    placed = el.describing_function(X, w)
    assert abs(placed - truth) < 1e-4 * abs(truth), (placed, truth)
    assert abs(BILINEAR.describing_function(X, w, **SPRING) - truth) > 0.05 * abs(truth)
    mirrored = {"k_pos": SPRING["k_neg"], "k_neg": SPRING["k_pos"]}
    assert placed_kbar([(BILINEAR, mirrored)], X, w, el.surroundings) == pytest.approx(placed, rel=1e-9)
    assert placed_kbar([(BILINEAR, SPRING)], 7.0 * X, w, el.surroundings) == pytest.approx(placed, rel=1e-9)


@pytest.mark.parametrize("spring", [SPRING, {"k_pos": 200.0, "k_neg": 800.0}, {"k_pos": 500.0, "k_neg": 450.0}])
def test_fit_finds_both_stiffnesses_of_a_placed_bilinear_spring_and_the_formula_only_their_sum(spring):
    """Placed, a fit of kbar samples parts the two stiffnesses, the stiffer one given as k_pos (which side is
    which the fundamental cannot tell); the formula alone determines only their sum, and that short of theirs."""
    s, (el,) = sdof([{"law": "bilinear", **spring}])
    X = np.geomspace(2e-3, 3e-2, 24)
    w = 2 * np.pi * np.linspace(3.0, 7.0, 24)
    kbar = placed_kbar([(BILINEAR, spring)], X, w, el.surroundings)
    fit = fit_laws(["bilinear"], X, w, kbar, 0.05, surroundings=el.surroundings)
    found = fit.terms[0].params
    # within the placement's settling (its scaling parameter to 1e-3: analysis/fitting/placed.py)
    assert found["k_pos"] == pytest.approx(max(spring.values()), rel=3e-3)
    assert found["k_neg"] == pytest.approx(min(spring.values()), rel=3e-3)
    np.testing.assert_allclose(fit.describing_function(X, w), kbar, rtol=2e-3)
    # the formula alone: the sum twice the mean kbar, short of the spring's by what the harmonics return
    alone = fit_laws(["bilinear"], X, w, kbar, 0.05)
    total = sum(alone.terms[0].params.values())
    assert total == pytest.approx(2 * np.mean(kbar.real), rel=0.02)
    assert total < sum(spring.values()) * (0.95 if min(spring.values()) < 0.5 * max(spring.values()) else 1.0)
    assert set(alone.terms[0].undetermined) == {"k_pos", "k_neg"}


def test_discovery_offers_a_bilinear_spring_only_placed_and_only_where_the_kbar_does_not_move_with_amplitude():
    """On an element whose verdict is linear, a placed bilinear spring fits a kbar that moves with frequency where
    no law of its formula does; without the structure, or on an element whose kbar moves with amplitude (where a
    one-sided contact's clearance is searched instead), it is not a candidate."""
    from analysis.missing.diagnosis import ElementSamples
    from analysis.search.candidates import _candidate_laws
    from analysis.search.discovery import search_element

    assert "bilinear" in _candidate_laws(True, True)
    assert "bilinear" not in _candidate_laws(True, False) and "bilinear" not in _candidate_laws(False, True)
    s, (el,) = sdof([{"law": "bilinear", **SPRING}])
    X = np.geomspace(1e-3, 3e-2, 40)
    w = 2 * np.pi * np.linspace(3.0, 7.0, 40)
    truth = placed_kbar([(BILINEAR, SPRING)], X, w, el.surroundings)
    std = 1e-3 * np.abs(truth)
    rng = np.random.default_rng(5)
    kbar = truth + std / np.sqrt(2) * (rng.normal(size=X.size) + 1j * rng.normal(size=X.size))
    samples = ElementSamples("c", X, w, kbar, std, np.ones(X.size))
    placed = search_element(0, samples, True, around=el.surroundings)
    assert placed.sets[0].laws == ("bilinear",)
    values = placed.sets[0].fit.terms[0].params
    assert [values["k_pos"], values["k_neg"]] == pytest.approx([SPRING["k_pos"], SPRING["k_neg"]], rel=0.02)
    assert all("bilinear" not in s.laws for s in search_element(0, samples, True).sets)


def test_a_bilinear_fit_started_at_an_even_split_parts_the_two_sides_all_the_same():
    """A start at an even split (a linear spring's, which a refit of a model would give) has a placement with no
    harmonics, flat in the ratio: the placement starts from one side carrying most of it (``placed_start``)."""
    s, (el,) = sdof([{"law": "bilinear", **SPRING}])
    X = np.geomspace(2e-3, 3e-2, 24)
    w = 2 * np.pi * np.linspace(3.0, 7.0, 24)
    kbar = placed_kbar([(BILINEAR, SPRING)], X, w, el.surroundings)
    fit = fit_laws(["bilinear"], X, w, kbar, 0.05, start=[{"k_pos": 500.0, "k_neg": 500.0}],
                   surroundings=el.surroundings)
    assert [fit.terms[0].params["k_pos"], fit.terms[0].params["k_neg"]] == pytest.approx([800.0, 200.0], rel=3e-3)


def test_two_placed_laws_on_one_element_are_refused_by_the_fit():
    """Each placed law's basis is placed alone, where a model places an element's placed laws together: a fit of
    two would fit one model and report another."""
    from analysis.common.errors import InputError

    s, (el,) = sdof([{"law": "bilinear", **SPRING}])
    X, w = np.geomspace(2e-3, 3e-2, 12), 2 * np.pi * np.linspace(3.0, 7.0, 12)
    kbar = placed_kbar([(BILINEAR, SPRING)], X, w, el.surroundings)
    with pytest.raises(InputError, match="both placed"):
        fit_laws(["bilinear", "unilateral"], X, w, kbar, 0.05, surroundings=el.surroundings)
