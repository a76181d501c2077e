"""The kbar the closed form identifies where a joint's motion is not sinusoidal, and the fit's correction of it on
data without harmonics (docs/fitting.md, "The fundamental's bias"): the fundamental's force over the
fundamental's motion by multi-harmonic balance against the identification of the balance's own FRFs, and laws
refitted to RK4 receptances of a friction joint (an integrator written in the tests, sharing no code with the
project) against the rig's values."""
import tomllib

import numpy as np
import pytest

from analysis import load_elements, load_structure
from analysis.prediction.comparison import HarmonicCriterion, Predictor
from analysis.common.statistics import capped_chi_square
from analysis.prediction.harmonic_balance import predict_sweep
from analysis.prediction.multiharmonic import predict_multiharmonic
from analysis.identification.identify import identify_complex_stiffness
from analysis.common.measurements import Measurements, SineRun
from analysis.mechanics.model import load_model
from analysis.loop.workbench import Workbench
from test_auto import FREQS, LUMPED, element, steady_receptance

CHAIN = {"type": "lumped", "dofs": ["x1", "x2"], "mass": [[1.0, 0.0], [0.0, 1.0]],
         "stiffness": [[3000.0, -1000.0], [-1000.0, 2000.0]], "damping": [[0.6, -0.1], [-0.1, 0.5]]}
JOINT = [{"name": "a", "dof": "x1", "laws": [{"law": "linear", "k": -300.0, "c": 0.0}, {"law": "coulomb", "fs": 0.3}]}]


def test_the_fundamental_force_over_motion_is_the_kbar_identified_from_the_balance_s_own_frfs():
    s = load_structure(CHAIN)
    els = load_elements({"element": JOINT}, s, None, True)
    w = 2 * np.pi * np.linspace(5.0, 8.0, 7)
    single = predict_sweep(s, els, "x2", w, 1.0)
    mh = predict_multiharmonic(s, els, "x2", w, 1.0, 7, 512, y_start=single.y[:, 0])
    assert mh.converged.all()
    ident = identify_complex_stiffness(s, mh.receptance(1.0), ["x1", "x2"], "x2", els, w=w, force=1.0)
    own = mh.element_forces[:, 1, 0] / mh.element_harmonics[:, 1, 0]
    np.testing.assert_allclose(ident.kbar[:, 0], own, rtol=1e-6)
    # the joint's motion is far from sinusoidal there: the describing function misses the identified kbar
    df = els[0].describing_function(np.abs(mh.element_harmonics[:, 1, 0]), w)
    assert np.abs(own - df).max() > 0.03 * np.abs(df).max()


def test_the_bias_is_zero_where_the_balance_needs_no_harmonics():
    model = load_model(tomllib.loads(LUMPED + element("a", "x1", '{ law = "linear", k = 50.0, c = 0.1 }')))
    lines = FREQS[:4]
    H = np.ones((len(lines), 2), complex)
    p = Predictor(model, Measurements(sine=[SineRun("sine", 1.0, "up", "x2", ["x1", "x2"], lines, H)]))
    assert not np.any(p.fundamental_bias(HarmonicCriterion()).bias["sine"])


FS, KJ, V0 = 0.2, -300.0, 5e-4          # the RK4 rig's joint at x1: linear spring and Coulomb friction as a steep tanh


@pytest.fixture(scope="module")
def friction_runs():
    freqs = np.arange(5.0, 11.01, 0.3)
    forces = (0.5, 2.0)
    # 40 s: mode 1 decays in 6.7 s with the joint stuck; 96 steps per period keep the tanh's fs / v0 stable
    H = steady_receptance(freqs, forces, settle_seconds=40.0, per_period=96,
                          joint=lambda x, v: KJ * x + FS * np.tanh(v / V0))
    rng = np.random.default_rng(11)
    runs = []
    for F, h in zip(forces, H):
        std = 2e-3 * np.abs(h)
        noisy = h + std / np.sqrt(2) * (rng.normal(size=h.shape) + 1j * rng.normal(size=h.shape))
        runs.append(SineRun(f"sine_{F:g}N_up", F, "up", "x2", ["x1", "x2"], freqs, noisy, std))
    return Measurements(sine=runs)


def _capped(wb: Workbench) -> float:
    """The joint's laws against all its samples, each sample's share capped as on data without harmonics."""
    return capped_chi_square(np.abs(wb.reports["a"].fit.normalized_residuals) ** 2)


def _fitted(measurements) -> Workbench:
    wb = Workbench(load_model(tomllib.loads(LUMPED + element("a", "x1", '"linear", "coulomb"'))), measurements)
    wb.start()
    return wb


@pytest.mark.slow
def test_friction_laws_refitted_without_their_harmonics_keep_the_rig_s_values(friction_runs, monkeypatch):
    # friction slipping at 40 % of the lower force: the joint's motion carries harmonics at most lines, which
    # the imported FRFs do not; without them the laws fit the samples better (capped chi-square 422 against 441)
    corrected = _fitted(friction_runs)
    values = {t.law.name: t.values for t in corrected.model.element("a").laws}
    with monkeypatch.context() as m:
        m.setattr(Workbench, "_corrected_is_kept", lambda self, before, corrected: False)
        refused = _fitted(friction_runs)
    monkeypatch.setattr(Workbench, "_correct_fundamental_bias", lambda self, unsettled: None)
    plain = _fitted(friction_runs)
    assert values["linear"]["k"] == pytest.approx(KJ, rel=0.01)
    assert values["coulomb"]["fs"] == pytest.approx(FS, rel=0.02)
    assert _capped(corrected) < _capped(plain)
    # the correction is kept only where the FRFs with harmonics are not worse by a law's margin; refused, the plain
    # fit stays whole
    assert corrected.compare().error <= 1.05 * plain.compare().error
    assert [t.values for t in refused.model.element("a").laws] == [t.values for t in plain.model.element("a").laws]
    assert refused._kbar_bias == {} and _capped(refused) == _capped(plain)


@pytest.mark.slow
def test_a_joint_without_laws_leaves_the_others_corrected(friction_runs, monkeypatch):
    # a joint the model gives no law exerts no force in it: the model's harmonics, and so the bias, are as known
    # with it as without it, and the friction joint's laws are corrected: they keep the rig's values and fit their
    # samples better than uncorrected
    text = LUMPED + element("a", "x1", '"linear", "coulomb"') + element("b", "x2", "")
    beside = Workbench(load_model(tomllib.loads(text)), friction_runs)
    beside.start()
    assert any(np.any(bias) for bias in beside._kbar_bias.values())
    values = {t.law.name: t.values for t in beside.model.element("a").laws}
    assert values["linear"]["k"] == pytest.approx(KJ, rel=0.01)
    assert values["coulomb"]["fs"] == pytest.approx(FS, rel=0.02)
    monkeypatch.setattr(Workbench, "_correct_fundamental_bias", lambda self, unsettled: None)
    plain = Workbench(load_model(tomllib.loads(text)), friction_runs)
    plain.start()
    assert _capped(beside) < _capped(plain)


def _contact_runs() -> Measurements:
    """A one-sided contact at x1 (closing at 0.4 mm), two levels of single-harmonic receptances with 0.2 % noise:
    data without harmonics, on which each fit corrects the bias and a clearance's fit may restart."""
    truth = load_model(tomllib.loads(LUMPED + element("a", "x1", '{ law = "unilateral", k = 800.0, gap = 4e-4 }')))
    freqs = np.arange(5.0, 11.01, 0.5)
    rng = np.random.default_rng(5)
    runs = []
    for F in (0.5, 2.0):
        h = predict_sweep(truth.structure, truth.elements, "x2", 2 * np.pi * freqs, F).receptance[:, 0]
        std = 2e-3 * np.abs(h)
        noisy = h + std / np.sqrt(2) * (rng.normal(size=h.shape) + 1j * rng.normal(size=h.shape))
        runs.append(SineRun(f"sine_{F:g}N_up", F, "up", "x2", ["x1", "x2"], freqs, noisy, std))
    return Measurements(sine=runs)


def test_a_clearance_restarts_from_its_frf_refined_laws_once(monkeypatch):
    # docs/fitting.md, "The restart chooses a clearance's basin once for a set of laws"
    runs = _contact_runs()
    restarts = []
    refined = Workbench._refined_against_frfs
    monkeypatch.setattr(Workbench, "_refined_against_frfs", lambda self, i: restarts.append(i) or refined(self, i))
    wb = Workbench(load_model(tomllib.loads(LUMPED + element("a", "x1", '"unilateral"'))), runs)
    wb.start()
    assert restarts == [0]                          # a law just added: its values are no restart's
    wb.fit()
    assert restarts == [0]                          # started at the values it settled
    given = wb.model.copy()
    Workbench(given, runs).start()
    assert restarts == [0, 0]                       # values given with the model are not settled
    Workbench(given, runs, started_at_fit=True).start()
    assert restarts == [0, 0]                       # a refit on part of the test starts at the whole test's fit
    with wb.read_as("a", ("unilateral", "cubic")):
        assert restarts == [0, 0, 0]                # a law beside it moves its fixed points: judged anew
    wb.fit()
    assert restarts == [0, 0, 0]                    # back to the laws and values judged before


def test_the_fit_s_own_comparison_is_the_model_s():
    wb = Workbench(load_model(tomllib.loads(LUMPED + element("a", "x1", '"unilateral"'))), _contact_runs())
    wb.start()
    kept = wb.compare()
    again = wb.predictor.compare(locate_folds=True, harmonics=wb.harmonics)
    assert not kept.jumps and sum(m.sum() for m in kept.multiharmonic.values()) > 0
    assert kept.error == pytest.approx(again.error, rel=1e-9)
    for run, compared in kept.compared.items():
        np.testing.assert_allclose(compared, again.compared[run], rtol=1e-9, atol=0)
