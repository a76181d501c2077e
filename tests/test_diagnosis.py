"""The named decisions of the missing-effect ranking (support, significance, order) on hand-made candidates,
and the per-run samples joined into one set."""
import math
from types import SimpleNamespace

import numpy as np
import pytest
import scipy.stats

from analysis.missing.diagnosis import (Candidate, ElementSamples, RankingRules, Signature, _beside_above_noise,
                                _fits_only_departing_lines, _Leader, _rank_key, _significant, _supported, explain)
from analysis.mechanics.elements import LawTerm
from analysis.fitting.fit import fit_laws
from analysis.fitting.results import TermFit
from analysis.laws import LAWS

RULES = RankingRules()


def candidate(law, error=0.1, bic=100.0, evidence=50.0, supported=True, above_noise=True, element="e"):
    c = Candidate(element, law, error, 0.5, bic, above_noise, "", evidence)
    c.supported = supported
    return c


def test_support_near_the_best_evidence_or_as_good_in_the_frfs():
    slack = scipy.stats.chi2.ppf(1 - RULES.false_alarm, 1)          # one parameter (cubic)
    assert _supported(candidate("cubic", evidence=100.0 - 0.99 * slack), 100.0, 0.1, False, RULES)
    assert not _supported(candidate("cubic", evidence=100.0 - slack - 0.1, error=0.2), 100.0, 0.1, False, RULES)
    # far from the best evidence, but at least half of it and within frf_tie of the best FRF error
    assert _supported(candidate("cubic", evidence=50.0, error=0.104), 100.0, 0.1, False, RULES)
    assert not _supported(candidate("cubic", evidence=49.0, error=0.1), 100.0, 0.1, False, RULES)
    assert not _supported(candidate("cubic", evidence=0.0), 0.0, 0.1, False, RULES)
    # a linear verdict supports only laws without amplitude dependence
    assert not _supported(candidate("cubic", evidence=100.0), 100.0, 0.1, True, RULES)
    assert _supported(candidate("linear", evidence=100.0), 100.0, 0.1, True, RULES)
    # the tie is a rule: a retune is one field
    loose = RankingRules(frf_tie=0.1)
    assert _supported(candidate("cubic", evidence=50.0, error=0.109), 100.0, 0.1, False, loose)
    assert not _supported(candidate("cubic", evidence=50.0, error=0.109), 100.0, 0.1, False, RULES)


def test_significant_needs_support_the_noise_and_the_gain():
    assert _significant(candidate("cubic", error=0.5 / 1.31), RULES)
    assert not _significant(candidate("cubic", error=0.5 / 1.29), RULES)
    assert not _significant(candidate("cubic", error=0.1, supported=False), RULES)
    assert not _significant(candidate("cubic", error=0.1, above_noise=False), RULES)


def test_rank_key_orders_elements_ties_simplicity_evidence_then_the_unsupported():
    leaders = {"a": _Leader(bic=10.0, error=0.1), "b": _Leader(bic=20.0, error=0.1)}
    ranked = [
        candidate("iwan", error=0.101, bic=12.0, element="a"),                  # tied, 4 parameters
        candidate("coulomb", error=0.104, bic=11.0, evidence=5.0, element="a"),  # tied, 1 parameter, less evidence
        candidate("cubic", error=0.104, bic=11.0, evidence=9.0, element="a"),   # tied, 1 parameter
        candidate("linear", error=0.102, bic=13.0, element="a"),                 # tied, 2, amplitude independent
        candidate("jenkins", error=0.102, bic=14.0, element="a"),                # tied, 2, amplitude dependent
        candidate("gap", error=0.2, bic=30.0, element="a"),                      # not tied: by its own BIC
        candidate("quintic", error=0.3, bic=15.0, element="a"),
        candidate("coulomb", error=0.1, bic=20.0, element="b"),                  # the next element
        candidate("cubic", error=0.05, bic=1.0, supported=False, element="b"),  # unsupported: last, by BIC
        candidate("quintic", error=0.05, bic=0.5, supported=False, element="a"),
    ]
    shuffled = [ranked[i] for i in np.random.default_rng(1).permutation(len(ranked))]
    keys = [_rank_key(c, leaders.get(c.element), RULES.frf_tie) for c in shuffled]
    assert all(isinstance(v, (int, float)) for key in keys for v in key)
    order = sorted(shuffled, key=lambda c: _rank_key(c, leaders.get(c.element), RULES.frf_tie))
    expected = [ranked[i] for i in (2, 1, 3, 4, 0, 6, 5, 7, 9, 8)]
    assert [(c.element, c.law) for c in order] == [(c.element, c.law) for c in expected]


def test_samples_of_several_runs_join_into_one_set():
    a = ElementSamples("e", np.array([1.0, 2.0]), np.array([3.0, 3.0]), np.array([1 + 1j, 2 + 0j]),
                       np.array([0.1, 0.2]), np.array([0.5, 0.5]), rotational=True)
    b = ElementSamples("e", np.array([4.0]), np.array([5.0]), np.array([3j]), np.array([0.3]), np.array([2.0]),
                       rotational=True)
    joined = ElementSamples.joined([a, b])
    assert joined.name == "e" and joined.rotational and joined.units == ("N·m/rad", "rad")
    np.testing.assert_array_equal(joined.X, [1.0, 2.0, 4.0])
    np.testing.assert_array_equal(joined.w, [3.0, 3.0, 5.0])
    np.testing.assert_array_equal(joined.kbar, [1 + 1j, 2, 3j])
    np.testing.assert_array_equal(joined.kbar_std, [0.1, 0.2, 0.3])
    np.testing.assert_array_equal(joined.level, [0.5, 0.5, 2.0])
    b.kbar_std = None
    assert ElementSamples.joined([a, b]).kbar_std is None           # a std for only part of the set is none


def test_rules_default_to_the_documented_thresholds():
    assert RULES == RankingRules(min_gain=1.3, tie=1e-3, false_alarm=1e-3, frf_tie=0.05)
    with pytest.raises(AttributeError):
        RULES.min_gain = 2.0                                         # frozen: a retune is a new record


def test_a_candidate_explanation_marks_the_parameters_the_data_do_not_determine():
    # the slip range (0.0242 rad) inside the amplitudes: an Iwan element read as itself
    sig = Signature(0.5, None, 0.8, -20.0, 10.0, -5.0, 2.0, 0.0, -20.0, 0.5, 6.0, (1e-5, 5e-2), False)
    term = _iwan_term(undetermined=("fs", "beta"))
    text = explain("tangential", "iwan", sig, term, ("N·m/rad", "rad"))
    assert "kt = 98.3, fs: not determined by the data, chi = -0.5, beta: not determined by the data" in text


def test_a_candidate_explanation_gives_the_combination_a_law_in_its_limit_leaves_determined():
    # the slip range beyond every amplitude: micro-slip, whose dissipation fixes fs and beta only together
    sig = Signature(0.5, None, 0.8, -20.0, 10.0, -5.0, 2.0, 0.0, -20.0, 0.5, 6.0, (1e-5, 7e-3), False)
    term = _iwan_term(undetermined=("fs", "beta"))
    text = explain("tangential", "iwan", sig, term, ("N·m/rad", "rad"))
    assert "fitted as micro-slip: kt = 98.3 ± 0.98 N·m/rad, chi = -0.5 ± 0.005, nu = " in text
    assert "(fs, beta not determined apart)" in text and "fs = 0.85" not in text


def test_a_limit_the_fit_leaves_a_value_of_open_words_it_as_not_determined():
    # micro-slip beside a linear spring that shares its stiffness: kt at 1e26 is where the fit left it, no finding
    sig = Signature(0.5, None, 0.8, -20.0, 10.0, -5.0, 2.0, 0.0, -20.0, 0.5, 6.0, (1e-5, 7e-3), False)
    term = _iwan_term(kt=1.27e26, fs=0.85 * 1.27e26 / 98.3, undetermined=("kt", "fs", "beta"))
    text = explain("tangential", "iwan", sig, term, ("N·m/rad", "rad"))
    assert "fitted as micro-slip: kt: not determined by the data, chi = -0.5 ± 0.005, nu = " in text
    assert "1.27e+26" not in text


def _iwan_term(kt: float = 98.3, fs: float = 0.85, undetermined: tuple[str, ...] = ()) -> TermFit:
    """A fitted Iwan element, its errors 1 % except where ``undetermined``."""
    params = {"kt": kt, "fs": fs, "chi": -0.5, "beta": 0.039}
    stderr = {k: math.inf if k in undetermined else 0.01 * abs(v) for k, v in params.items()}
    return TermFit(LAWS["iwan"], "iwan", params, stderr, dict(params), undetermined)


def _cubic_samples(c3: float, departing: int, seed: int = 4) -> ElementSamples:
    """kbar of a cubic spring (k3 = 1e6) with cubic damping c3 over 60 lines, 0.5 % noise; the ``departing``
    largest amplitudes carry an extra Im kbar no describing function of the two follows (a contact's lines on
    data without harmonics)."""
    rng = np.random.default_rng(seed)
    X, w = np.geomspace(1e-4, 1e-2, 60), np.linspace(30.0, 40.0, 60)
    kbar = 0.75e6 * X ** 2 + 0.75j * c3 * w ** 3 * X ** 2
    std = 0.005 * np.abs(kbar) + 1e-3
    kbar = kbar + std / np.sqrt(2) * (rng.standard_normal(60) + 1j * rng.standard_normal(60))
    if departing:
        kbar[-departing:] += 1j * 0.3 * np.abs(kbar[-departing:])
    return ElementSamples("e", X, w, kbar, std, np.ones(60))


@pytest.mark.parametrize("c3, departing, expected", [(0.0, 3, False), (0.05, 0, True)])
def test_a_law_beside_laws_present_must_lower_the_capped_chi_square_above_the_noise(c3, departing, expected):
    """On data without harmonics a law beside the element's laws is significant only where it fits more than the
    few lines that follow no describing function: there cubic damping bends to them (and cuts the plain
    chi-square), but the capped chi-square, which charges each such line the outlier limit, falls within the
    noise; cubic damping the kbar has on every line is taken."""
    s = _cubic_samples(c3, departing)
    current = fit_laws(["cubic"], s.X, s.w, s.kbar, s.kbar_std, exclude_outliers=True)
    el = SimpleNamespace(samples=s, terms=[LawTerm(LAWS["cubic"], dict(current.terms[0].params))])
    assert _beside_above_noise(el, candidate("cubic_damping"), current, None, RULES.false_alarm) is expected
    if departing:     # the plain chi-square, which the kbar evidence uses, does fall well above the noise
        plain = fit_laws(["cubic", "cubic_damping"], s.X, s.w, s.kbar, s.kbar_std)
        alone = fit_laws(["cubic"], s.X, s.w, s.kbar, s.kbar_std)
        assert alone.chi_square - plain.chi_square > 10 * scipy.stats.chi2.ppf(1 - RULES.false_alarm, 1)


@pytest.mark.parametrize("error, held_back", [(0.2, True), (0.02, False)])
def test_a_law_that_gains_beyond_doubt_in_the_frfs_is_not_held_back_by_the_capped_kbar(error, held_back):
    """The cubic damping that fits only three departing lines, x2.5 in the FRFs: held back; x25, as a clearance
    closing at a few lines near a resonance gains (random case 27 of seed 266231, x29), it is not -- the
    model-form check judges it with harmonics. An element's first law is not asked."""
    s = _cubic_samples(0.0, 3)
    current = fit_laws(["cubic"], s.X, s.w, s.kbar, s.kbar_std, exclude_outliers=True)
    el = SimpleNamespace(samples=s, terms=[LawTerm(LAWS["cubic"], dict(current.terms[0].params))])
    c = candidate("cubic_damping", error=error)
    assert _fits_only_departing_lines(el, c, current, None, RULES) is held_back
    assert not _fits_only_departing_lines(el, c, None, None, RULES)


@pytest.mark.parametrize("law, expected", [("tanh_softening", False), ("velocity_stiffness", False),
                                           ("cubic", True)])
def test_beside_friction_the_loop_asks_a_law_to_beat_the_force_that_turns_its_fundamental(law, expected):
    """Coulomb friction beside a spring whose fundamental turned by 4 % (Re kbar = -0.04 * 4 fs / (pi X)), as on
    data without harmonics, with a cubic spring where ``cubic`` is expected: a saturating spring or a velocity
    stiffness beside them fits that force and nothing more and is refused; the cubic the kbar has is taken
    (the same rule as model discovery's, docs/workbench.md)."""
    X, w, fs = np.geomspace(2e-4, 5e-2, 80), np.linspace(8.0, 20.0, 80), 0.1
    truth = (130.0 + LAWS["coulomb"].describing_function(X, w, fs=fs) - 0.04 * 4 * fs / (np.pi * X)
             + (LAWS["cubic"].describing_function(X, w, k3=3e6) if expected else 0.0))
    std = 0.005 * np.abs(truth) + 0.05
    rng = np.random.default_rng(3)
    kbar = truth + std / np.sqrt(2) * (rng.normal(size=X.size) + 1j * rng.normal(size=X.size))
    s = ElementSamples("joint", X, w, kbar, std, np.ones(X.size))
    current = fit_laws(["linear", "coulomb"], X, w, kbar, std, exclude_outliers=True)
    el = SimpleNamespace(samples=s, terms=[LawTerm(LAWS[t.law.name], dict(t.params)) for t in current.terms])
    assert _beside_above_noise(el, candidate(law), current, None, RULES.false_alarm) is expected
