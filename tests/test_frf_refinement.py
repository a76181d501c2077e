"""A law set's parameters refined against the FRFs (analysis/prediction/frf_refinement.py): against the analytic receptance
of a linear chain, and against RK4 receptances of a cubic joint (an integrator written in the tests)."""
import tomllib

import numpy as np
import pytest

from analysis.prediction.comparison import Predictor
from analysis.mechanics.elements import LawTerm
from analysis.prediction.frf_refinement import refine_against_frfs
from analysis.laws import get_law
from analysis.common.measurements import Measurements, SineRun
from analysis.mechanics.model import load_model
from test_auto import FREQS, LUMPED, element, steady_receptance

M = np.eye(2)
K = np.array([[3000.0, -1000.0], [-1000.0, 2000.0]])
C = 0.3 * M + 1.0e-4 * K                   # LUMPED's Rayleigh damping
E1 = np.diag([1.0, 0.0])


def _noisy(H: np.ndarray, rel: float, seed: int) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    std = rel * np.abs(H)
    return H + std / np.sqrt(2) * (rng.normal(size=H.shape) + 1j * rng.normal(size=H.shape)), std


def _predictor(runs: list[SineRun]) -> Predictor:
    model = load_model(tomllib.loads(LUMPED + element("a", "x1", '"linear"')))
    return Predictor(model, Measurements(sine=runs))


def test_a_linear_joint_refined_against_its_analytic_receptance():
    kj, cj = -300.0, 0.05
    w = 2 * np.pi * FREQS
    H = np.array([np.linalg.solve(K + kj * E1 - x ** 2 * M + 1j * x * (C + cj * E1), [0.0, 1.0]) for x in w])
    noisy, std = _noisy(H, 2e-3, 5)
    p = _predictor([SineRun("sine", 1.0, "up", "x2", ["x1", "x2"], FREQS, noisy, std)])
    start = [LawTerm(get_law("linear"), {"k": -200.0, "c": 0.02})]
    out = refine_against_frfs(p, 0, start, [["k", "c"]], {})
    k, c = out.terms[0].values["k"], out.terms[0].values["c"]
    assert abs(k - kj) < 3 * out.stderr[0]["k"] and out.stderr[0]["k"] < 0.01 * abs(kj)
    assert abs(c - cj) < 3 * out.stderr[0]["c"] and out.stderr[0]["c"] < 0.2 * cj
    assert out.size_seen(0, 1.96)
    # the reduced chi-square of the noise alone
    assert out.chi_square / (out.n_residuals - 2) == pytest.approx(1.0, abs=0.35)


def test_a_law_the_frfs_do_not_need_is_not_seen():
    w = 2 * np.pi * FREQS
    H = np.array([np.linalg.solve(K - x ** 2 * M + 1j * x * C, [0.0, 1.0]) for x in w])
    noisy, std = _noisy(H, 2e-3, 6)
    p = _predictor([SineRun("sine", 1.0, "up", "x2", ["x1", "x2"], FREQS, noisy, std)])
    out = refine_against_frfs(p, 0, [LawTerm(get_law("velocity_stiffness"), {"gamma": 0.5})], [["gamma"]], {})
    assert not out.size_seen(0, 1.96)


def test_nothing_free_is_evaluated_once():
    w = 2 * np.pi * FREQS
    H = np.array([np.linalg.solve(K - x ** 2 * M + 1j * x * C, [0.0, 1.0]) for x in w])
    p = _predictor([SineRun("sine", 1.0, "up", "x2", ["x1", "x2"], FREQS, H, 1e-3 * np.abs(H))])
    out = refine_against_frfs(p, 0, [], [], {})
    assert out.evaluations == 1 and out.chi_square < 1e-12


@pytest.mark.slow
def test_a_cubic_joint_refined_against_rk4_receptances():
    k3 = 3.0e5                               # test_auto's hardening joint
    forces = (0.5, 2.0)
    H = steady_receptance(FREQS, forces, k3=k3)
    runs = []
    for j, (F, h) in enumerate(zip(forces, H)):
        noisy, std = _noisy(h, 1e-3, 10 + j)
        runs.append(SineRun(f"sine_{F:g}N_up", F, "up", "x2", ["x1", "x2"], FREQS, noisy, std))
    out = refine_against_frfs(_predictor(runs), 0, [LawTerm(get_law("cubic"), {"k3": 0.6 * k3})], [["k3"]], {})
    assert out.terms[0].values["k3"] == pytest.approx(k3, rel=0.03)
    assert out.size_seen(0, 1.96)


def test_a_law_s_range_holds_where_the_frfs_pull_beyond_it():
    # a softer joint (-300 N/m) refined as a clearance, whose stiffness cannot go below zero: the search stays in
    # range and ends at its edge instead of asking the law for a value it refuses
    kj = -300.0
    w = 2 * np.pi * FREQS
    H = np.array([np.linalg.solve(K + kj * E1 - x ** 2 * M + 1j * x * C, [0.0, 1.0]) for x in w])
    noisy, std = _noisy(H, 2e-3, 7)
    p = _predictor([SineRun("sine", 1.0, "up", "x2", ["x1", "x2"], FREQS, noisy, std)])
    out = refine_against_frfs(p, 0, [LawTerm(get_law("gap"), {"k": 50.0, "gap": 1e-5})], [["k", "gap"]], {})
    assert out.terms[0].values["k"] >= 0.0 and out.terms[0].values["gap"] >= 0.0
    assert out.terms[0].values["k"] < 1.0


def _stepped_predictions(forces, monkeypatch):
    """Predictions of a hardening joint's sweeps both ways at ``forces``: at k3, at k3 one percent up swept, and at
    k3 one percent up started from the first (``near``); and the sweeps the last one made."""
    import analysis.prediction.harmonic_balance as hb

    runs = [SineRun(f"sine_{F:g}N_{d}", F, d, "x2", ["x1", "x2"], FREQS, np.ones((len(FREQS), 2), complex), None)
            for F in forces for d in ("up", "down")]
    p = _predictor(runs)
    base = p.predict([LawTerm(get_law("cubic"), {"k3": 3.0e5}).describing_function])
    stepped = [LawTerm(get_law("cubic"), {"k3": 3.0e5 * 1.01}).describing_function]
    swept = p.predict(stepped)
    sweeps = []
    for name in ("_speculative_sweep", "_march_step"):
        monkeypatch.setattr(hb, name, lambda *a, f=getattr(hb, name): sweeps.append(a) or f(*a))
    return base, swept, p.predict(stepped, near=base), sweeps


def _alike(near, swept):
    for name, s in swept.items():
        for got, want in ((near[name].swept, s.swept), (near[name].opposite, s.opposite)):
            assert np.abs(got - want).max() <= 1e-6 * np.abs(want).max(), name      # Newton's tolerance
        assert (near[name].swept_ok == s.swept_ok).all() and (near[name].opposite_ok == s.opposite_ok).all()


def test_a_prediction_started_a_hair_away_is_the_swept_one_without_a_sweep(monkeypatch):
    """A finite difference's step predicted from the prediction at the point it steps from (``near``): where that
    converged at every line, Newton from it at every line at once gives what the whole sweep gives."""
    base, swept, near, sweeps = _stepped_predictions((0.5, 2.0), monkeypatch)
    assert all(b.swept_ok.all() and b.opposite_ok.all() for b in base.values())
    assert not sweeps
    _alike(near, swept)
    # the step moved the solutions by far more than the solver's tolerance
    moved = [np.abs(swept[n].swept - base[n].swept).max() / np.abs(base[n].swept).max() for n in base]
    assert max(moved) > 1e-4


def test_a_sweep_that_failed_a_hair_away_is_swept_again(monkeypatch):
    # at 10 N the down sweep jumps and fails a line: in each group of runs (up, down) that sweep alone of the four
    # (two levels, both ways) is swept again
    base, swept, near, sweeps = _stepped_predictions((2.0, 10.0), monkeypatch)
    assert not all(b.opposite_ok.all() for b in base.values())
    assert sweeps and all(force.shape[1] == 1 for _, _, force, *_ in sweeps)
    _alike(near, swept)
