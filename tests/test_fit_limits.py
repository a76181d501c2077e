"""A law the data cannot tell from one of its limits is fitted and read in that limit (analysis/fitting/limits.py,
docs/fitting.md "Limits the data cannot tell apart").

Truth: kbar samples of an Iwan joint from its describing function (checked against quadrature in
tests/test_laws.py) with 0.5-2 % noise, and the dissipation per cycle at the largest amplitude from its
definition, D = pi X_max^2 Im kbar(X_max)."""
import numpy as np
import pytest

from analysis.fitting.fit import fit_laws
from analysis.fitting.limits import fit_in_limits, settle_in_limits
from analysis.laws import LAWS
from analysis.laws.iwan import SLIP_RANGE_BEYOND, MicroSlip, slip_range
from analysis.mechanics.elements import LawTerm

TRUTH = {"kt": 2.0e5, "fs": 40.0, "chi": -0.3, "beta": 0.5}
W = 600.0


def _samples(law, values, X, noise, seed):
    rng = np.random.default_rng(seed)
    w = np.full_like(X, W)
    kbar = law.describing_function(X, w, **values)
    sigma = noise * np.abs(kbar)
    kbar = kbar + sigma / np.sqrt(2) * (rng.standard_normal(X.size) + 1j * rng.standard_normal(X.size))
    return w, kbar, sigma


def _settled(law, X, w, kbar, sigma, start):
    terms = [LawTerm(law, dict(start))]
    fit = fit_laws(terms, X, w, kbar, sigma)
    return fit, settle_in_limits(fit, terms, X, w, kbar, sigma, false_alarm=1e-3)


def _dissipation(law, values, X_max):
    return np.pi * X_max ** 2 * law.describing_function(X_max, W, **values).imag


@pytest.mark.parametrize("seed", [3, 4])
def test_an_iwan_element_that_never_slips_through_is_fitted_as_its_micro_slip_limit(seed):
    iwan = LAWS["iwan"]
    X = np.geomspace(1e-7, 5e-5, 40)
    assert slip_range(TRUTH["fs"] / TRUTH["kt"], TRUTH["chi"], TRUTH["beta"]) > 5 * X.max()
    w, kbar, sigma = _samples(iwan, TRUTH, X, 0.005, seed)
    for start in ({"fs": 10.0, "chi": 0.0, "beta": 0.1}, {"fs": 500.0, "chi": -0.8, "beta": 20.0}):
        _, settled = _settled(iwan, X, w, kbar, sigma, start)
        own, term = settled.terms[0], settled.terms[0].limit
        assert isinstance(term.law, MicroSlip) and term.undetermined == ()
        # the law itself, placed in the limit: what the limit leaves open has no error and is not determined
        assert own.law is iwan and own.undetermined == ("fs", "beta")
        assert own.stderr["chi"] == term.stderr["chi"] and not np.isfinite(own.stderr["fs"])
        truth = {"kt": TRUTH["kt"], "chi": TRUTH["chi"], "D": _dissipation(iwan, TRUTH, X.max())}
        for name, value in truth.items():
            assert abs(term.params[name] - value) < 4 * term.stderr[name], name
        # the model's Iwan sits in the limit, with the form's kbar, and reads as it with the form's values
        placed = settled.terms[0].params
        assert placed["beta"] == 0.0
        assert iwan.describing_function(X, w, **placed) == pytest.approx(term.describing_function(X, w), rel=1e-9)
        reading = iwan.reading(placed, X.min(), X.max())
        assert reading.limit == "micro-slip"
        assert {k: reading.values[k] for k in term.params} == pytest.approx(term.params, rel=1e-9)


@pytest.mark.parametrize("seed", [11, 12])
def test_a_fit_on_part_of_the_amplitudes_keeps_the_limit_the_whole_test_took(seed):
    """A refit on part of the levels fits a law as the limit form the whole test's fit took it in
    (``fit_in_limits``): on the whole samples it is the settled fit itself; on the lower amplitudes alone it
    still places an Iwan that does not slip through at the whole test's largest amplitude, and its combination
    is the truth's within its errors."""
    iwan = LAWS["iwan"]
    X = np.geomspace(1e-7, 5e-5, 40)
    w, kbar, sigma = _samples(iwan, TRUTH, X, 0.005, seed)
    _, settled = _settled(iwan, X, w, kbar, sigma, {"fs": 10.0, "chi": 0.0, "beta": 0.1})
    form = settled.terms[0].limit.law
    placed = LawTerm(iwan, settled.terms[0].params)
    again = fit_in_limits([placed], {0: form}, X, w, kbar, sigma)
    assert again.terms[0].params == pytest.approx(settled.terms[0].params, rel=1e-6)
    assert again.terms[0].undetermined == settled.terms[0].undetermined

    low = X < 5e-6
    part = fit_in_limits([placed], {0: form}, X[low], w[low], kbar[low], sigma[low])
    own, term = part.terms[0], part.terms[0].limit
    assert own.law is iwan and term.law is form and {"fs", "beta"} <= set(own.undetermined)
    assert slip_range(own.params["fs"] / own.params["kt"], own.params["chi"], own.params["beta"]) >= X.max()
    truth = {"kt": TRUTH["kt"], "chi": TRUTH["chi"], "D": _dissipation(iwan, TRUTH, X.max())}
    for name, value in truth.items():
        assert abs(term.params[name] - value) < 4 * term.stderr[name], name


def test_measured_from_the_reference_the_micro_slip_limit_is_the_dissipation_law_alone():
    iwan = LAWS["iwan"].relative()
    X = np.geomspace(1e-7, 5e-5, 40)
    w, kbar, sigma = _samples(iwan, TRUTH, X, 0.02, 5)
    _, settled = _settled(iwan, X, w, kbar, sigma, {"fs": 10.0, "chi": 0.0, "beta": 0.1})
    term = settled.terms[0].limit
    assert set(term.params) == {"chi", "D"} and term.undetermined == ()
    assert settled.terms[0].undetermined == ("kt", "fs", "beta")
    assert abs(term.params["chi"] - TRUTH["chi"]) < 4 * term.stderr["chi"]
    D = _dissipation(iwan, TRUTH, X.max())
    assert abs(term.params["D"] - D) < 4 * term.stderr["D"]
    placed = settled.terms[0].params
    assert slip_range(placed["fs"] / placed["kt"], placed["chi"], placed["beta"]) == \
        pytest.approx(SLIP_RANGE_BEYOND * X.max())
    assert iwan.describing_function(X, w, **placed) == pytest.approx(term.describing_function(X, w), rel=1e-9)
    reading = iwan.reading(placed, X.min(), X.max())
    assert reading.undetermined == ("kt", "fs", "beta")
    assert {k: reading.values[k] for k in term.params} == pytest.approx(term.params)


def test_an_iwan_element_that_slips_through_keeps_its_own_fit():
    iwan = LAWS["iwan"]
    values = dict(TRUTH, fs=4.0)
    X = np.geomspace(1e-6, 2e-4, 40)
    assert slip_range(values["fs"] / values["kt"], values["chi"], values["beta"]) < 0.5 * X.max()
    w, kbar, sigma = _samples(iwan, values, X, 0.005, 6)
    fit, settled = _settled(iwan, X, w, kbar, sigma, {"fs": 10.0, "chi": 0.0, "beta": 0.1})
    assert settled is fit
    assert iwan.reading(settled.terms[0].params, X.min(), X.max()) is None


def test_a_micro_slip_form_that_asks_for_more_dissipation_than_its_stiffness_allows_has_no_iwan():
    # with kt given, the continuum's slip range follows from D; below the largest amplitude no Iwan is in the limit
    form = MicroSlip(1e-4)
    assert form.law_values({"kt": 1e5, "chi": 0.0, "D": 1e-5}) is not None
    assert form.law_values({"kt": 1e5, "chi": 0.0, "D": 10.0}) is None


def test_a_micro_slip_form_whose_slip_range_is_beyond_any_number_has_no_iwan():
    """Near chi = -1 the slip range (kt (chi + 1) / R)^(1 / (chi + 1)) overflows a float: no Iwan, no error."""
    form = MicroSlip(1e-4)
    assert form.law_values({"kt": 1e9, "chi": -1.0 + 1e-4, "D": 1e-6}) is None


def test_the_lab_shows_a_law_taken_in_its_limit_as_the_combination_with_the_errors_of_the_limit_s_fit():
    from types import SimpleNamespace

    from app.gui.results import _law_view

    iwan = LAWS["iwan"].relative()
    X = np.geomspace(1e-7, 5e-5, 40)
    w, kbar, sigma = _samples(iwan, TRUTH, X, 0.02, 7)
    _, settled = _settled(iwan, X, w, kbar, sigma, {"fs": 10.0, "chi": 0.0, "beta": 0.1})
    term = LawTerm(iwan, settled.terms[0].params)
    report = SimpleNamespace(fit=settled, reading=lambda t: t.law.reading(t.values, X.min(), X.max()))
    view = _law_view(report, 0, term, rotational=False)
    assert view.limit == "micro-slip" and "kt, fs, beta not determined apart" in view.why
    shown = {p.name: p for p in view.params}
    assert set(shown) == {"chi", "nu", "D"}                     # the combination, not kt, fs, beta
    form = settled.terms[0].limit
    assert shown["D"].stderr == form.stderr["D"] and shown["D"].unit == "N·m" and not shown["D"].undetermined
    assert "±" in shown["chi"].text()


def test_beside_a_linear_spring_the_stuck_stiffness_is_placed_and_the_spring_keeps_the_sum_the_data_determine():
    """A linear spring and an Iwan joint in micro-slip add the same constant to kbar: the data determine k + kt,
    not each. The form places the Iwan's slip range a decade beyond the largest amplitude and the spring takes the
    difference, so the model's kbar is the form fit's at every sample."""
    iwan, linear = LAWS["iwan"], LAWS["linear"]
    X = np.geomspace(1e-6, 7e-3, 60)
    truth = {"kt": 152.0, "fs": 3.0, "chi": -0.5, "beta": 0.1}
    assert slip_range(truth["fs"] / truth["kt"], truth["chi"], truth["beta"]) > 5 * X.max()
    rng = np.random.default_rng(8)
    w = np.full_like(X, 330.0)
    kbar = iwan.describing_function(X, w, **truth) + linear.describing_function(X, w, k=-50.0, c=0.0)
    sigma = 0.003 * np.abs(kbar)
    kbar = kbar + sigma / np.sqrt(2) * (rng.standard_normal(X.size) + 1j * rng.standard_normal(X.size))
    terms = [LawTerm(linear, {}), LawTerm(iwan, {})]
    fit = fit_laws(terms, X, w, kbar, sigma)
    settled = settle_in_limits(fit, terms, X, w, kbar, sigma, false_alarm=1e-3)
    form = settled.terms[1].limit
    assert form is not None and "kt" in form.undetermined and {"chi", "D"}.isdisjoint(form.undetermined)
    for name, value in (("chi", truth["chi"]), ("D", _dissipation(iwan, truth, X.max()))):
        assert abs(form.params[name] - value) < 4 * form.stderr[name], name
    spring, joint = (t.params for t in settled.terms)
    assert slip_range(joint["fs"] / joint["kt"], joint["chi"], joint["beta"]) == \
        pytest.approx(SLIP_RANGE_BEYOND * X.max())
    (combination,) = next(d for d in settled.degeneracies if "iwan.kt" in d.parameters).determined
    assert spring["k"] + joint["kt"] == pytest.approx(combination.value, rel=1e-9)
    model = linear.describing_function(X, w, **spring) + iwan.describing_function(X, w, **joint)
    # the residuals of the form's fit are the model's: nothing of the fit moved in placing it
    assert np.abs(model - kbar - settled.residuals).max() < 1e-9 * np.abs(kbar).max()
