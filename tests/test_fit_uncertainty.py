"""Standard errors that mean something: over many noise seeds of one set of samples the 95 % intervals cover
the true parameters about 95 % of the time; parameters the samples do not determine are said to be so, with
the combination they do determine; the outlier-excluding fit leaves a clean set of samples alone."""
import math
from pathlib import Path

import numpy as np
import pytest

from analysis.mechanics.elements import LawTerm
from analysis.common.statistics import outlier_limit
from analysis.fitting.fit import CORRELATION_LIMIT, UNDETERMINED_Z, fit_laws
from analysis.laws import get_law

SEEDS = 200
Z95 = 1.959964
# binomial: 3 standard deviations of a coverage estimated from SEEDS intervals whose true coverage is 95 %
MARGIN = 3 * math.sqrt(0.95 * 0.05 / SEEDS)

# the paper's two elements (a friction law among them) and a law whose shape is searched; true values
CASES = {
    "cubic+quadratic_damping": ({"cubic": {"k3": -500.0}, "quadratic_damping": {"c2": 1.0}}, (1e-3, 0.15)),
    "cubic+coulomb": ({"cubic": {"k3": -750.0}, "coulomb": {"fs": 0.1}}, (1e-3, 0.15)),
}


def samples(laws, amplitudes, n=40):
    X = np.geomspace(*amplitudes, n)
    w = np.linspace(6.0, 20.0, n)
    kbar = sum(LawTerm(get_law(name), values).describing_function(X, w) for name, values in laws.items())
    return X, w, kbar


def coverage(laws, amplitudes, sigma_given=True, exclude_outliers=False, relative_noise=0.01, seed=1):
    """Fraction of SEEDS fits whose 95 % interval holds the truth, per parameter; and how many fits left a
    sample out."""
    X, w, kbar = samples(laws, amplitudes)
    sigma = relative_noise * np.median(np.abs(kbar))
    rng = np.random.default_rng(seed)
    hits = {(law, p): 0 for law, values in laws.items() for p in values}
    lost = 0
    for _ in range(SEEDS):
        noisy = kbar + sigma / np.sqrt(2) * (rng.normal(size=kbar.shape) + 1j * rng.normal(size=kbar.shape))
        fit = fit_laws(list(laws), X, w, noisy, sigma if sigma_given else None, exclude_outliers=exclude_outliers)
        for term in fit.terms:
            for p, true in laws[term.law.name].items():
                hits[(term.law.name, p)] += abs(term.params[p] - true) <= Z95 * term.stderr[p]
        lost += fit.excluded is not None and bool(fit.excluded.any())
    return {k: v / SEEDS for k, v in hits.items()}, lost / SEEDS


@pytest.mark.parametrize("case", list(CASES))
@pytest.mark.parametrize("sigma_given", [True, False], ids=["sigma", "noise-estimated"])
def test_95_percent_intervals_cover_the_truth_95_percent_of_the_time(case, sigma_given):
    laws, amplitudes = CASES[case]
    measured, _ = coverage(laws, amplitudes, sigma_given)
    for key, c in measured.items():
        assert abs(c - 0.95) <= MARGIN, (key, c)


@pytest.mark.slow
def test_the_outlier_excluding_fit_leaves_clean_samples_alone_and_still_covers():
    laws, amplitudes = CASES["cubic+coulomb"]
    measured, lost = coverage(laws, amplitudes, exclude_outliers=True, seed=2)
    for key, c in measured.items():
        assert abs(c - 0.95) <= MARGIN, (key, c)
    # Bonferroni at 1 %: about one clean set in a hundred loses a sample
    assert lost <= 0.04


def test_outliers_are_left_out_and_the_fit_recovers_the_truth():
    laws, amplitudes = CASES["cubic+coulomb"]
    X, w, kbar = samples(laws, amplitudes)
    sigma = 0.01 * np.median(np.abs(kbar))
    rng = np.random.default_rng(5)
    noisy = kbar + sigma / np.sqrt(2) * (rng.normal(size=kbar.shape) + 1j * rng.normal(size=kbar.shape))
    bad = np.array([3, 11, 12, 30])
    noisy[bad] += 40 * sigma * np.exp(1j * np.array([0.3, 2.0, -1.0, 3.0]))     # lines that follow another law
    plain = fit_laws(list(laws), X, w, noisy, sigma)
    robust = fit_laws(list(laws), X, w, noisy, sigma, exclude_outliers=True)
    assert np.flatnonzero(robust.excluded).tolist() == bad.tolist()
    assert robust.n_samples == len(X) - len(bad) and robust.residuals.shape == X.shape
    assert any("4 of 40 samples left out" in n for n in robust.notes)
    assert outlier_limit(40) == pytest.approx(-2 * math.log(0.01 / 40))
    fs = robust.terms[1]
    assert abs(fs.params["fs"] - 0.1) <= 3 * fs.stderr["fs"]
    assert abs(plain.terms[1].params["fs"] - 0.1) > 3 * plain.terms[1].stderr["fs"]


# ------------------------------------------------------------------ what the samples do not determine
IWAN = {"kt": 152.0, "fs": 3.0, "chi": -0.5, "beta": 0.1}      # the paper-beam rig's tangential joint


def micro_slip_samples():
    """Iwan samples below macro-slip (phi_max = 0.05 here: X up to 0.02), 0.3 % noise."""
    X = np.geomspace(1e-3, 0.02, 40)
    w = np.linspace(60.0, 120.0, 40)
    kbar = LawTerm(get_law("iwan"), IWAN).describing_function(X, w)
    sigma = 0.003 * np.abs(kbar)
    rng = np.random.default_rng(0)
    return X, w, kbar + sigma / np.sqrt(2) * (rng.normal(size=40) + 1j * rng.normal(size=40)), sigma


def test_iwan_fs_and_beta_over_micro_slip_are_reported_undetermined():
    X, w, kbar, sigma = micro_slip_samples()
    fit = fit_laws(["iwan"], X, w, kbar, sigma)
    iwan = fit.terms[0]
    assert iwan.undetermined == ("fs", "beta")
    for p in ("kt", "chi"):                      # what micro-slip does determine, and right
        assert abs(iwan.params[p] - IWAN[p]) <= 3 * iwan.stderr[p]
    # the combination the samples fix (slip displacement and spike ratio together) is named
    assert any("iwan.xs" in str(d) and "iwan.beta" in str(d) for d in fit.degeneracies)


def test_a_linear_spring_beside_an_iwan_kt_is_reported_as_a_correlated_pair_with_their_sum():
    X, w, kbar, sigma = micro_slip_samples()
    fit = fit_laws(["linear", "iwan"], X, w, kbar, sigma)
    linear, iwan = fit.terms
    assert "k" in linear.undetermined and "kt" in iwan.undetermined
    # the pair is found either as correlated beyond the limit or, where the rank test already finds the direction
    # flat (it does with some LAPACK builds), as part of a degeneracy: both name the sum the samples determine
    pair = next((c for c in fit.correlated if c.parameters == ("linear.k", "iwan.kt")), None)
    if pair is not None:
        assert abs(pair.correlation) > CORRELATION_LIMIT
        determined, where = pair.determined, pair
    else:
        where = next(d for d in fit.degeneracies if {"linear.k", "iwan.kt"} <= set(d.parameters))
        determined = next(c for c in where.determined if set(c.coefficients) == {"linear.k", "iwan.kt"})
    coef = determined.coefficients
    assert coef["linear.k"] == pytest.approx(1.0, abs=0.02) and coef["iwan.kt"] == pytest.approx(1.0, abs=0.02)
    # k + kt is the stuck stiffness the samples see: the rig's 152, within its own (small) interval
    assert abs(determined.value - 152.0) <= 3 * determined.stderr
    assert determined.stderr < 0.01 * 152.0
    assert any(str(where) == n for n in fit.notes)
    assert "linear.k + iwan.kt" in str(where)


def test_well_determined_parameters_are_not_marked():
    laws, amplitudes = CASES["cubic+coulomb"]
    X, w, kbar = samples(laws, amplitudes)
    fit = fit_laws(list(laws), X, w, kbar * (1 + 1e-3), 1e-3 * np.abs(kbar))
    assert all(t.undetermined == () for t in fit.terms) and fit.correlated == []


def test_a_parameter_whose_interval_holds_zero_is_undetermined():
    # a cubic at amplitudes where 0.75 k3 X^2 hides under the noise: k3 = -6e5 +- 5.7e5 on a true -750 is
    # not a finding; the linear spring beside it is
    laws = {"linear": {"k": 100.0, "c": 0.5}, "cubic": {"k3": -750.0}}
    X, w, kbar = samples(laws, (1e-4, 1e-3))
    sigma = 0.01 * np.abs(kbar)
    for seed in range(6):
        rng = np.random.default_rng(seed)
        noise = sigma / np.sqrt(2) * (rng.normal(size=40) + 1j * rng.normal(size=40))
        fit = fit_laws(list(laws), X, w, kbar + noise, sigma)
        cubic = fit.terms[1]
        assert abs(cubic.params["k3"]) < UNDETERMINED_Z * cubic.stderr["k3"]
        assert cubic.undetermined == ("k3",) and fit.terms[0].undetermined == ()
    # with amplitudes that reach the cubic, it is determined
    X, w, kbar = samples(laws, (1e-2, 0.2))
    fit = fit_laws(list(laws), X, w, kbar * (1 + 1e-3), 0.01 * np.abs(kbar))
    assert fit.terms[1].undetermined == ()


@pytest.mark.slow
def test_coverage_of_a_friction_law_with_a_searched_shape():
    # jenkins: kt linear, the slip displacement searched; fs carried through fit_jacobian
    measured, _ = coverage({"jenkins": {"kt": 1.0e4, "fs": 2.0}}, (5e-5, 2e-3))
    for key, c in measured.items():
        assert abs(c - 0.95) <= MARGIN, (key, c)


def test_analyze_says_which_parameters_the_data_do_not_determine():
    """One mass on a spring and an iwan joint driven below macro-slip, receptance from the exact single-harmonic
    balance (X = F / |k - w^2 m + kbar(X)| solved per line); the model puts a linear spring beside the iwan."""
    import json

    from analysis.common.measurements import Measurements, SineRun
    from analysis.mechanics.model import load_model
    from analysis.loop.workbench import Workbench
    from app.analyze import report_text

    iwan = LawTerm(get_law("iwan"), IWAN)
    f = np.concatenate([np.linspace(1.0, 4.0, 8), np.linspace(7.0, 10.0, 8)])
    w, force = 2 * np.pi * f, 5.0
    X = np.full(len(f), 1e-3)
    for _ in range(200):
        X = force / np.abs(1000.0 - w ** 2 + iwan.describing_function(X, w))
    H = (X / force * np.exp(-1j * np.angle(1000.0 - w ** 2 + iwan.describing_function(X, w))))[:, None]
    assert X.max() < 0.4 * 0.0501                        # micro-slip only: phi_max = 0.0501
    run = SineRun("sine_5N_up", force, "up", "x1", ["x1"], f, H, 1e-4 * np.abs(H), distortion=np.zeros(len(f)))
    model = {"structure": {"type": "lumped", "dofs": ["x1"], "mass": [[1.0]], "stiffness": [[1000.0]]},
             "element": [{"name": "joint", "dof": "x1", "laws": ["linear", "iwan"]}]}
    wb = Workbench(load_model(model), Measurements([run]))
    wb.identify()
    wb.fit()
    text = report_text(wb, [])
    assert "law linear: k: not determined by the data" in text
    assert "linear.k + iwan.kt = 152" in text
    joint = json.loads(json.dumps(wb.to_json()))["elements"][0]
    linear, iwan_json = joint["laws"]
    assert "k" in linear["undetermined"] and {"kt", "fs", "beta"} <= set(iwan_json["undetermined"])
    # at 0.01 % noise the pair is exactly degenerate (not merely correlated): its sum is the combination named
    combos = [c for d in joint["not_identifiable"] for c in d["determined"]]
    combos += [c for c in joint["correlated"]]
    pair = next(c for c in combos if set(c["combination"]) == {"linear.k", "iwan.kt"})
    assert pair["combination"]["linear.k"] == pytest.approx(pair["combination"]["iwan.kt"], rel=1e-3)
    assert abs(pair["value"] - 152.0) <= 3 * pair["stderr"] + 1e-6 * 152.0


# ------------------------------------------------------------------ a law that acts on a few lines alone
def _rk4_kbar(name: str) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """An element's kbar samples identified from RK4 receptances (tests/data): X, w, kbar, its std."""
    table = np.loadtxt(Path(__file__).parent / "data" / name, delimiter=",", skiprows=3)
    return table[:, 0], table[:, 1], table[:, 2] + 1j * table[:, 3], table[:, 4]


def test_the_lines_a_clearance_acts_on_alone_are_kept_as_its_evidence(monkeypatch):
    # a grounded clearance, identified from RK4 receptances without harmonics: it closes at three lines of the
    # higher level only, where its formula misses the samples by 37-390 sigma (the contact's harmonics move the
    # structure). Leaving them all out would leave its stiffness without a finite error.
    import analysis.fitting.robust as robust_module
    X, w, kbar, std = _rk4_kbar("gap_kbar_rk4.csv")
    robust = fit_laws(["gap"], X, w, kbar, std, exclude_outliers=True)
    k = robust.terms[0]
    assert np.isfinite(k.stderr["k"]) and abs(k.params["k"] / 991.8 - 1) < 0.02
    assert abs(k.params["gap"] / 7.723e-3 - 1) < 0.05
    assert robust.excluded.sum() < 3 and not robust.excluded[np.argmax(X)]
    monkeypatch.setattr(robust_module, "_sizes_determined", lambda fit: 0)     # without the rule
    assert not np.isfinite(fit_laws(["gap"], X, w, kbar, std, exclude_outliers=True).terms[0].stderr["k"])


def test_a_law_keeps_the_lines_that_show_its_size_not_only_a_finite_error(monkeypatch):
    # a hardening law fitted to a clearance's kbar (RK4, no harmonics): the clearance closes at the two
    # largest-amplitude lines of the higher level only (90 and 600 N/m against a noise of 1.7). Leaving them out one
    # pass after another leaves the quintic a finite error about a size of the other sign (-3.7e9 +- 1.2e9, a
    # softening law for a contact that stiffens); the lines that determine a law's size stay in.
    import analysis.fitting.robust as robust_module
    X, w, kbar, std = _rk4_kbar("clearance_kbar_rk4_3dof.csv")
    top = np.argsort(X)[-2:]
    fit = fit_laws(["quintic"], X, w, kbar, std, exclude_outliers=True)
    k5 = fit.terms[0]
    assert not k5.size_unseen and k5.params["k5"] > 0
    assert not fit.excluded[top].any()
    # with a finite standard error counted as a determined size (the rule before)
    monkeypatch.setattr(robust_module, "_sizes_determined", lambda f: sum(
        int(np.isfinite(t.stderr.get(n, np.inf))) for t in f.terms for n in t.law.linear))
    finite_only = fit_laws(["quintic"], X, w, kbar, std, exclude_outliers=True)
    assert finite_only.terms[0].params["k5"] < 0 and finite_only.excluded[top].all()


def test_a_clearance_keeps_the_only_line_it_acts_on(monkeypatch):
    # the same kbar fitted by a clearance: the best fit by the kbar closes it at the largest amplitude only, which
    # it fits exactly (stiffness and clearance tied: neither determined apart). Left out, that line would leave a
    # clearance open at every sample kept, at no stiffness: nothing of the law in the fit.
    import analysis.fitting.robust as robust_module
    X, w, kbar, std = _rk4_kbar("clearance_kbar_rk4_3dof.csv")
    largest = np.argmax(X)
    fit = fit_laws(["gap"], X, w, kbar, std, exclude_outliers=True)
    assert fit.terms[0].params["k"] > 0 and not fit.excluded[largest]
    assert fit.describing_function(X[largest], w[largest]).real > 0
    monkeypatch.setattr(robust_module, "_acts_only_on", lambda f, data, left_out: False)     # without the rule
    without = fit_laws(["gap"], X, w, kbar, std, exclude_outliers=True)
    assert without.terms[0].params["k"] == 0 and without.excluded[largest]
