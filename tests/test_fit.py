"""Fitting laws to complex-stiffness samples (analysis/fitting/fit.py).

Truth comes from each law's own describing function: samples generated from known
parameters must give those parameters back (exactly without noise, within three
standard errors with seeded noise), the standard errors must match the analytic
covariance of a linear least-squares problem, and the information criteria must
prefer the law that made the data.
"""
import math

import numpy as np
import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st

from analysis import LAWS, LawTerm, get_law
from analysis.common.errors import InputError
from analysis.fitting.fit import fit_laws, unit_exponents

# Several frequencies so that w-dependent laws (damping, velocity stiffness) are separable from X.
FREQUENCIES = np.array([20.0, 60.0, 200.0])   # rad/s
AMPLITUDES_PER_DECADE = 8
NOISE = 0.01
# The paper's elements (§4) and a stuck-then-slipping joint.
SUMS = [
    ("cubic", "coulomb"),
    ("cubic", "quadratic_damping"),
    ("tanh_softening", "velocity_stiffness", "anderson_ferri"),
    ("linear", "jenkins"),
]
# Exactly-collinear fit parameter pairs per law (the rest of each law is identifiable).
COLLINEAR = {"bilinear": ("k_pos", "k_neg")}


def grid(laws):
    """Sample points (X, w), shape (N,): X log-spaced over the laws' example amplitudes."""
    lo = min(law.example_amplitude[0] for law in laws)
    hi = max(law.example_amplitude[1] for law in laws)
    n = max(12, int(round(AMPLITUDES_PER_DECADE * math.log10(hi / lo))) + 1)
    X, w = np.meshgrid(np.geomspace(lo, hi, n), FREQUENCIES)
    return X.ravel(), w.ravel()


def samples(names, seed=None):
    """Samples of the example values of ``names`` (optionally with 1 % complex noise) and sigma."""
    laws = [get_law(n) for n in names]
    X, w = grid(laws)
    kbar = sum(law.describing_function(X, w, **law.example) for law in laws)
    if seed is None:
        return X, w, kbar, None
    # 1 % of each sample's magnitude, that magnitude floored at 1 % of the largest so that zero
    # samples (a gap's dead zone) get noise too
    sigma = NOISE * np.maximum(np.abs(kbar), 0.01 * np.abs(kbar).max())
    rng = np.random.default_rng(seed)
    noise = sigma / math.sqrt(2) * (rng.standard_normal(X.size) + 1j * rng.standard_normal(X.size))
    return X, w, kbar + noise, sigma


def check_recovery(names, fit, exact):
    """Every identifiable parameter at its example value: to 1e-6 (exact) or within 3 stderr."""
    for name, term in zip(names, fit.terms):
        truth = get_law(name).example
        collinear = COLLINEAR.get(name, ())
        for p, value in term.params.items():
            if p in collinear:
                assert term.stderr[p] == math.inf, (name, p)
                continue
            err = abs(value - truth[p])
            if exact:
                assert err <= 1e-6 * abs(truth[p]), (name, p, value, truth[p])
            else:
                assert math.isfinite(term.stderr[p]) and err <= 3 * term.stderr[p], \
                    (name, p, value, truth[p], term.stderr[p])
        if collinear:
            check_collinear(name, term, fit, exact)


def check_collinear(name, term, fit, exact):
    """Of a collinear pair only the sum is determined: recovered, to 1e-6 or within three times the noise of a
    mean over the samples, and the degeneracy noted."""
    a, b = COLLINEAR[name]
    truth = get_law(name).example
    total = truth[a] + truth[b]
    err = abs(term.params[a] + term.params[b] - total)
    assert err <= (1e-6 if exact else 3 * NOISE / math.sqrt(fit.n_samples)) * abs(total)
    assert fit.degeneracies and any("not separately identifiable" in note for note in fit.notes)


@pytest.mark.parametrize("name", sorted(LAWS))
def test_single_law_noise_free_recovers_example(name):
    X, w, kbar, _ = samples([name])
    fit = fit_laws([name], X, w, kbar)
    check_recovery([name], fit, exact=True)
    # the reported residuals are the fitted model minus the samples
    np.testing.assert_allclose(fit.residuals, fit.describing_function(X, w) - kbar,
                               atol=1e-9 * np.abs(kbar).max())
    assert fit.identifiable == (name not in COLLINEAR)
    # the fitted terms are complete law terms (e.g. for a fitted model file)
    assert all(term.complete and term.law.name == name for term in fit.law_terms())


@pytest.mark.parametrize("name", sorted(LAWS))
def test_single_law_with_noise_within_three_standard_errors(name):
    X, w, kbar, sigma = samples([name], seed=sorted(LAWS).index(name))
    fit = fit_laws([name], X, w, kbar, sigma=sigma)
    check_recovery([name], fit, exact=False)
    # the right model with the true sigma: chi-square consistent with its dof (6 sigma band)
    assert abs(fit.chi_square - fit.dof) < 6 * math.sqrt(2 * fit.dof)


@pytest.mark.parametrize("names", SUMS, ids="+".join)
def test_sum_of_laws_recovers_each_term(names):
    X, w, kbar, _ = samples(names)
    check_recovery(names, fit_laws(list(names), X, w, kbar), exact=True)
    X, w, kbar, sigma = samples(names, seed=SUMS.index(names))
    check_recovery(names, fit_laws(list(names), X, w, kbar, sigma=sigma), exact=False)


def wrong_law_for(X, w, kbar):
    """A law that cannot explain these samples: linear, or cubic when linear can."""
    exact = fit_laws(["linear"], X, w, kbar)
    return "cubic" if exact.chi_square <= 1e-18 * np.sum(np.abs(kbar) ** 2) else "linear"


@pytest.mark.parametrize("name", sorted(LAWS))
def test_information_criteria_prefer_the_true_law(name):
    X, w, exact_kbar, _ = samples([name])
    wrong = wrong_law_for(X, w, exact_kbar)
    X, w, kbar, sigma = samples([name], seed=100 + sorted(LAWS).index(name))
    true_fit = fit_laws([name], X, w, kbar, sigma=sigma)
    wrong_fit = fit_laws([wrong], X, w, kbar, sigma=sigma)
    assert true_fit.aic < wrong_fit.aic
    assert true_fit.bic < wrong_fit.bic
    # also without sigma (criteria from the residual sum of squares)
    assert fit_laws([name], X, w, kbar).aic < fit_laws([wrong], X, w, kbar).aic


# Laws whose describing functions look alike (same part of kbar, similar trend in X or w).
SIMILAR = [("tanh_softening", "arctan_softening"), ("arctan_softening", "tanh_softening"),
           ("coulomb", "quadratic_damping"), ("quadratic_damping", "cubic_damping"),
           ("cubic", "quintic"), ("iwan", "jenkins")]


@pytest.mark.parametrize("true, wrong", SIMILAR, ids=[f"{a}-vs-{b}" for a, b in SIMILAR])
def test_information_criteria_separate_similar_laws(true, wrong):
    """As when ranking candidates: the linear-correction term is kept in both models."""
    X, w, kbar, sigma = samples([true], seed=200 + SIMILAR.index((true, wrong)))
    true_fit = fit_laws(["linear", true], X, w, kbar, sigma=sigma)
    wrong_fit = fit_laws(["linear", wrong], X, w, kbar, sigma=sigma)
    assert true_fit.aic < wrong_fit.aic and true_fit.bic < wrong_fit.bic


def test_information_criteria_penalise_needless_parameters():
    """jenkins is a limit of iwan (all slip force in the spike): on jenkins samples iwan fits as
    well but pays for its two extra parameters."""
    X, w, kbar, sigma = samples(["jenkins"], seed=300)
    jenkins = fit_laws(["jenkins"], X, w, kbar, sigma=sigma)
    iwan = fit_laws(["iwan"], X, w, kbar, sigma=sigma)
    assert iwan.chi_square <= jenkins.chi_square + 1.0
    assert jenkins.bic < iwan.bic


def test_standard_errors_match_weighted_least_squares_formula():
    """cubic alone is y = 0.75 X^2 k3: var(k3) = 1 / sum (0.75 X^2 / std_re)^2, and the fitted k3
    is the weighted mean (imaginary parts carry no information)."""
    rng = np.random.default_rng(7)
    X = np.geomspace(1e-3, 1e-1, 25)
    w = np.full(X.size, 30.0)
    sigma = 2.0 + X * 1e3
    kbar = 0.75 * 3e5 * X**2 + sigma * (rng.standard_normal(X.size) + 1j * rng.standard_normal(X.size))
    fit = fit_laws(["cubic"], X, w, kbar, sigma=sigma)
    basis = 0.75 * X**2 / (sigma / math.sqrt(2))
    k3 = np.sum(basis * kbar.real / (sigma / math.sqrt(2))) / np.sum(basis**2)
    assert fit.terms[0].params["k3"] == pytest.approx(k3, rel=1e-12)
    assert fit.terms[0].stderr["k3"] == pytest.approx(1 / math.sqrt(np.sum(basis**2)), rel=1e-9)
    model = 0.75 * k3 * X**2
    std = sigma / math.sqrt(2)
    chi2 = np.sum(((model - kbar.real) / std) ** 2 + (kbar.imag / std) ** 2)
    assert fit.chi_square == pytest.approx(chi2, rel=1e-10)
    assert fit.dof == 2 * X.size - 1
    assert fit.aic == pytest.approx(chi2 + 2)
    assert fit.bic == pytest.approx(chi2 + math.log(2 * X.size))
    # without sigma: unit weights, errors scaled by the reduced chi-square; Gaussian AIC with the variance
    plain = fit_laws(["cubic"], X, w, kbar)
    rss = np.sum((model_plain := 0.75 * plain.terms[0].params["k3"] * X**2 - kbar.real) ** 2 + kbar.imag**2)
    assert plain.chi_square == pytest.approx(rss, rel=1e-10)
    n = 2 * X.size
    assert plain.aic == pytest.approx(n * math.log(rss / n) + 2 * 2)
    assert plain.terms[0].stderr["k3"] == pytest.approx(
        math.sqrt(rss / (n - 1) / np.sum((0.75 * X**2) ** 2)), rel=1e-9)
    np.testing.assert_allclose(plain.residuals.real, model_plain, rtol=1e-10, atol=0)


@pytest.mark.slow
def test_standard_errors_of_a_shape_law_match_monte_carlo_scatter():
    """jenkins: kt linear, xs = fs/kt searched, fs carried through fit_jacobian. The scatter of
    repeated noisy fits must match the reported standard errors (150 fits: ~6 % sampling error),
    and the mean must sit on the truth."""
    law = get_law("jenkins")
    X, w, _, sigma = samples(["jenkins"], seed=0)
    exact = law.describing_function(X, w, **law.example)
    truth = [law.example["kt"], law.example["fs"]]
    rng = np.random.default_rng(42)
    estimates, stderrs = [], []
    for _ in range(150):
        noise = sigma / math.sqrt(2) * (rng.standard_normal(X.size) + 1j * rng.standard_normal(X.size))
        fit = fit_laws(["jenkins"], X, w, exact + noise, sigma=sigma, start=[law.example], n_starts=0)
        estimates.append([fit.terms[0].params[p] for p in ("kt", "fs")])
        stderrs.append([fit.terms[0].stderr[p] for p in ("kt", "fs")])
    scatter = np.std(estimates, axis=0, ddof=1)
    np.testing.assert_allclose(scatter, np.median(stderrs, axis=0), rtol=0.2)
    assert np.all(np.abs(np.mean(estimates, axis=0) - truth) < 4 * scatter / math.sqrt(len(estimates)))


def test_sigma_per_part_equals_complex_sigma_split_evenly():
    X, w, kbar, sigma = samples(["linear", "cubic"], seed=3)
    whole = fit_laws(["linear", "cubic"], X, w, kbar, sigma=sigma)
    parts = fit_laws(["linear", "cubic"], X, w, kbar, sigma=np.column_stack([sigma, sigma]) / math.sqrt(2))
    for a, b in zip(whole.terms, parts.terms):
        assert a.params == pytest.approx(b.params, rel=1e-12)
        assert a.stderr == pytest.approx(b.stderr, rel=1e-9)
    assert whole.chi_square == pytest.approx(parts.chi_square, rel=1e-12)


def test_weighting_follows_sigma_per_part():
    """Corrupt the imaginary parts and declare them unreliable (huge sigma): k stays exact from
    the real parts, and c (seen only in the imaginary parts) gets a correspondingly huge error."""
    X, w, kbar, _ = samples(["linear"])
    corrupted = kbar.real + 1j * (kbar.imag + 1e3)
    sigma = np.column_stack([np.ones(X.size), np.full(X.size, 1e12)])
    fit = fit_laws(["linear"], X, w, corrupted, sigma=sigma)
    assert fit.terms[0].params["k"] == pytest.approx(get_law("linear").example["k"], rel=1e-9)
    assert fit.terms[0].stderr["c"] > 1e6 * fit.terms[0].stderr["k"]


@pytest.mark.parametrize("name", sorted(LAWS))
def test_fitted_values_stay_admissible_when_samples_push_past_a_bound(name):
    """Negated samples ask for negative stiffness / slip force: bounded linear parameters stop at
    their bound (strictly inside an open one) with a note, and the result is a valid law term."""
    law = get_law(name)
    X, w, kbar, sigma = samples([name], seed=400)
    fit = fit_laws([name], X, w, -kbar, sigma=sigma)
    law.check_params(fit.terms[0].params, complete=True)
    fit.describing_function(X, w)
    bounded = [p for p in law.params if p.name in law.linear and math.isfinite(p.lower)]
    if bounded:
        assert any("ended on its bound" in note for note in fit.notes), fit.notes


def test_identical_laws_are_reported_not_identifiable():
    X, w, kbar, sigma = samples(["cubic"], seed=11)
    fit = fit_laws(["cubic", "cubic"], X, w, kbar, sigma=sigma)
    assert [t.stderr["k3"] for t in fit.terms] == [math.inf, math.inf]
    (group,) = fit.degeneracies
    assert group.parameters == ("cubic[0].k3", "cubic[1].k3")
    (combo,) = group.determined
    single = fit_laws(["cubic"], X, w, kbar, sigma=sigma).terms[0]
    assert combo.value == pytest.approx(single.params["k3"], rel=1e-9)
    assert combo.stderr == pytest.approx(single.stderr["k3"], rel=1e-6)
    assert fit.effective_parameters == 1 and fit.dof == 2 * X.size - 1
    assert "cubic[0].k3" in fit.notes[0] and "cubic[1].k3" in fit.notes[0]


def test_laws_with_no_effect_in_the_samples_are_reported():
    """A cubic term on samples at an amplitude so small its basis vanishes in double precision."""
    X = np.full(6, 1e-170)
    w = np.linspace(10, 60, 6)
    kbar = 1e4 + 1j * 5.0 * w
    fit = fit_laws(["linear", "cubic"], X, w, kbar)
    assert fit.terms[1].stderr == {"k3": math.inf}
    assert fit.degeneracies[0].parameters == ("cubic.k3",) and not fit.degeneracies[0].determined
    assert fit.terms[0].params == pytest.approx({"k": 1e4, "c": 5.0}, rel=1e-12)


@pytest.mark.parametrize("name", sorted(n for n, law in LAWS.items() if law.shape))
def test_starting_values_are_used(name):
    """n_starts=0 with every shape parameter given skips the grid: with a one-evaluation budget
    the result is the start itself (from a LawTerm or from ``start``), with a normal budget the
    start converges to the truth where the formula determines the shape (bilinear's ratio it leaves open)."""
    law = get_law(name)
    X, w, kbar, _ = samples([name])
    linear, shape = law.to_fit(law.example)
    moved = {p: 1.1 * v for p, v in shape.items()}
    start = law.from_fit(linear, moved)
    for fit in (fit_laws([LawTerm(law, start)], X, w, kbar, n_starts=0, max_evaluations=1),
                fit_laws([name], X, w, kbar, start=[start], n_starts=0, max_evaluations=1)):
        assert {p: fit.terms[0].fit_params[p] for p in moved} == pytest.approx(moved, rel=1e-12)
        # a shape its formula leaves open (bilinear's ratio) stays where it starts, converged at once
        assert any("stopped after 1 evaluations" in note for note in fit.notes) == law.visible_in_kbar
    if law.visible_in_kbar:
        fit = fit_laws([name], X, w, kbar, start=[start], n_starts=0)
        assert fit.terms[0].params == pytest.approx(law.example, rel=1e-6)


@settings(max_examples=25, deadline=None)
@given(k=st.floats(-1e6, 1e6), c=st.floats(-1e3, 1e3), k3=st.floats(-1e9, 1e9))
@example(k=0.0, c=0.0, k3=5e-324)
def test_linear_laws_are_exact_for_any_values(k, c, k3):
    X, w = grid([get_law("linear"), get_law("cubic")])
    kbar = k + 1j * c * w + 0.75 * k3 * X**2
    fit = fit_laws(["linear", "cubic"], X, w, kbar)
    # a kbar below the smallest normal number holds no value to find (k3 = 5e-324 leaves every sample 0)
    scale = max(np.abs(kbar).max(), np.finfo(float).tiny)
    assert fit.terms[0].params["k"] == pytest.approx(k, abs=1e-9 * scale)
    assert fit.terms[0].params["c"] == pytest.approx(c, abs=1e-9 * scale / w.max())
    assert fit.terms[1].params["k3"] == pytest.approx(k3, abs=1e-9 * scale / (0.75 * X.max() ** 2))


def test_unit_exponents():
    assert unit_exponents("{F}/{L}^3") == (1.0, -3.0)
    assert unit_exponents("1/{L}") == (0.0, -1.0)
    assert unit_exponents("{L}") == (0.0, 1.0)
    assert unit_exponents("{F}·s^2/{L}^2") == (1.0, -2.0)
    assert unit_exponents("1") == (0.0, 0.0)


@pytest.mark.parametrize("change, field", [
    (dict(laws=["no_such_law"]), "laws[0]"),
    (dict(laws=[42]), "laws[0]"),
    (dict(laws=[]), "laws"),
    (dict(laws=[LawTerm(get_law("cubic"), {"k5": 1.0})]), "laws[0].k5"),
    (dict(start=[{}, {}]), "start"),
    (dict(start=[{"k7": 1.0}]), "laws[0].k7"),
    (dict(X=np.ones(3)), "X"),
    (dict(w=np.ones((2, 2))), "w"),
    (dict(kbar=np.ones((4, 2))), "kbar"),
    (dict(kbar=np.array([1.0, np.nan, 2.0, 3.0, 4.0, 5.0])), "kbar"),
    (dict(X=np.array([1.0, 2.0, -1.0, 3.0, 4.0, 5.0])), "X"),
    (dict(X=np.array([1.0, 2.0, np.inf, 3.0, 4.0, 5.0])), "X"),
    (dict(sigma=np.zeros(6)), "sigma"),
    (dict(sigma=np.ones(5)), "sigma"),
    (dict(sigma=np.ones((6, 3))), "sigma"),
    (dict(laws=["linear"] * 6), "kbar"),
])
def test_bad_input_is_a_one_line_error(change, field):
    args = dict(laws=["cubic"], X=np.geomspace(1e-3, 1e-2, 6), w=np.full(6, 10.0), kbar=np.ones(6, complex),
                sigma=None, start=None)
    args.update(change)
    with pytest.raises(InputError) as err:
        fit_laws(**args)
    assert err.value.field == field
    assert "\n" not in str(err.value)
