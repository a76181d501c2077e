"""The measured natural frequency and damping against amplitude as a judge of the loop (analysis/missing/modal_judge.py).

The measured curves here are the Duffing oscillator's analytic ones: phase-resonance points on its first-order
backbone w^2 = (k + 3/4 k3 a^2) / m, each at the force that balances its damping, F = c w a. Candidate laws are
real fits to the element's exact describing function, not made-up records."""
import numpy as np
import pytest

from analysis.missing.diagnosis import Candidate
from analysis.mechanics.elements import load_elements
from analysis.fitting.fit import fit_laws
from analysis.common.measurements import Measurements, PhaseRun
from analysis.missing.modal_judge import (ModalChange, ModalRules, ModalYardstick, judge_by_modes, measures_modes,
                                         model_error)
from analysis.prediction.backbone import Backbone, ModalError, ModalPoint, scatter_between_levels
from analysis.mechanics.model import Model
from analysis.mechanics.structures import Structure

M, K, C, K3 = 2.0, 5000.0, 0.8, 3.0e8
AMPLITUDES = np.array([2e-4, 1e-3, 2e-3, 4e-3])


def duffing_phase_run() -> PhaseRun:
    w = np.sqrt((K + 0.75 * K3 * AMPLITUDES ** 2) / M)
    return PhaseRun("phase_x_90deg", "x", 90.0, w / (2 * np.pi), C * w * AMPLITUDES, AMPLITUDES,
                    np.ones(len(w), bool), "x")


def model_with(laws: list) -> Model:
    s = Structure(["x"], np.array([[M]]), np.array([[K]]), np.array([[C]]))
    els = load_elements({"element": [{"name": "joint", "dof": "x", "laws": laws}]}, s, complete=True)
    return Model({}, s, els)


def candidate(law: str, kbar_of, significant: bool, gain: float) -> Candidate:
    """A candidate ``law`` fitted to the kbar ``kbar_of(X)`` over the measured amplitudes."""
    X = np.geomspace(1e-4, 5e-3, 12)
    w = np.full_like(X, 2 * np.pi * 8.0)
    fit = fit_laws([law], X, w, kbar_of(X).astype(complex))
    return Candidate("joint", law, 1.0 / gain, 1.0, 0.0, significant, "", evidence=1.0, supported=True,
                     significant=significant, fit=fit)


def test_the_true_model_has_no_modal_error_and_a_linear_one_misses_the_backbone():
    m = Measurements(phase=[duffing_phase_run()])
    assert measures_modes(m) and not measures_modes(Measurements())
    true = model_error(model_with([{"law": "cubic", "k3": K3}]), m)
    assert true.frequency < 1e-9 and true.damping < 1e-9
    assert model_error(model_with([]), m).frequency > 0.05


def test_a_law_that_bends_the_backbone_wrong_is_vetoed_and_one_that_follows_it_is_admitted():
    m = Measurements(phase=[duffing_phase_run()])
    model = model_with([])                          # the joint without a law: the backbone is flat
    cubic = candidate("cubic", lambda X: 0.75 * K3 * X ** 2, significant=False, gain=1.1)
    # a softening law fitted to the opposite kbar: the FRFs liked it (significant), the backbone falls instead
    soft = candidate("cubic", lambda X: -0.5 * 0.75 * K3 * X ** 2, significant=True, gain=2.0)
    unsupported = candidate("cubic", lambda X: 0.75 * K3 * X ** 2, significant=False, gain=1.1)
    unsupported.supported = False
    worse_frf = candidate("cubic", lambda X: 0.75 * K3 * X ** 2, significant=False, gain=0.9)
    judge_by_modes(model, m, [cubic, soft, unsupported, worse_frf], min_gain=1.3)
    assert cubic.significant and "call for it" in cubic.by_modes and "backbone error" in cubic.by_modes
    assert not soft.significant and "worse by more than x1.3" in soft.held_back
    assert not unsupported.significant and not worse_frf.significant
    assert cubic.to_json()["by_modes"] == cubic.by_modes


def test_nothing_is_judged_where_no_curve_is_measured():
    c = candidate("cubic", lambda X: 0.75 * K3 * X ** 2, significant=False, gain=1.1)
    judge_by_modes(model_with([]), Measurements(), [c], min_gain=1.3)
    assert not c.significant and not c.by_modes


def test_errors_below_the_floor_are_the_same_and_an_unmeasured_damping_judges_nothing():
    rules = ModalRules()
    same = ModalChange.of(ModalError(1e-4, 0.01), ModalError(5e-5, 0.015), rules)
    assert not same.worse(1.3) and not same.better(1.3)
    better = ModalChange.of(ModalError(0.02, float("nan")), ModalError(0.001, float("nan")), rules)
    assert better.better(1.3) and better.words() == "backbone error 0.02 -> 0.001"
    mixed = ModalChange.of(ModalError(0.02, 0.05), ModalError(0.001, 0.2), rules)
    assert mixed.worse(1.3) and not mixed.better(1.3)
    assert ModalChange.of(ModalError(0.02, 0.05), ModalError(0.02, 0.05), rules).frequency_gain == pytest.approx(1)


def test_locked_points_are_kbar_samples_where_one_harmonic_describes_them():
    """The locked points of a phase-resonance run are identified from like lines (each at its own force), the
    Duffing's kbar 3/4 k3 X^2 recovered at each; a point beyond 1 % displacement THD is left out as distorted."""
    from analysis.common.measurements import SineRun
    from analysis.loop.workbench import Workbench

    run = duffing_phase_run()
    w = 2 * np.pi * run.frequency_hz
    k_eq = K + 0.75 * K3 * AMPLITUDES ** 2
    h = 1.0 / (k_eq - M * w ** 2 + 1j * C * w)                   # the locked lines' first-harmonic receptance
    run.lines = SineRun(run.name, float(run.force[0]), "up", "x", ["x"], run.frequency_hz, h[:, None],
                        np.abs(h)[:, None] * 1e-4, run.force, np.array([0.001, 0.002, 0.005, 0.02]))
    f = np.linspace(7.5, 8.5, 11)
    sweep = SineRun("sine_x_0.0002m_up", 1.0, "up", "x", ["x"], f,
                    (1.0 / (K + 0.75 * K3 * 4e-8 - M * (2 * np.pi * f) ** 2 + 2j * np.pi * f * C))[:, None])
    wb = Workbench(model_with([]), Measurements(sine=[sweep], phase=[run]))
    report = wb.identify()["joint"]
    locked = np.isin(report.samples.level, run.force)
    np.testing.assert_allclose(report.samples.X[locked], AMPLITUDES[:3], rtol=1e-9)
    np.testing.assert_allclose(report.samples.kbar[locked].real, 0.75 * K3 * AMPLITUDES[:3] ** 2, rtol=1e-6)
    assert report.lines_flagged == 1 and report.lines_used == len(f) + 3


def _curve(amplitudes, frequencies, damping) -> Backbone:
    points = [ModalPoint(a, f, z) for a, f, z in zip(amplitudes, frequencies, damping)]
    return Backbone("x", "displacement", points, "measured")


@pytest.mark.parametrize("seed", [1, 2, 3, 4])
def test_the_scatter_between_levels_is_read_from_the_measured_curve_itself(seed):
    """The Duffing backbone and a damping ratio growing as the amplitude's square root, at 16 levels over a factor
    of four, each point moved by a relative scatter of 1e-3 (frequency) and 2 % (damping): the windows of four
    within a factor of two leave that scatter, and the exact curves little: the backbone's cubic term in ln a, which
    the windows do not cancel, 5.6e-5 where the frequency rises by 28 % over the factor of four."""
    a = np.geomspace(1e-3, 4e-3, 16)
    f = np.sqrt((K + 0.75 * K3 * a ** 2) / M) / (2 * np.pi)
    z = 0.01 * np.sqrt(a / a[0])
    exact = scatter_between_levels([_curve(a, f, z)])
    assert exact.frequency < 1e-4 and exact.damping < 1e-12
    rng = np.random.default_rng(seed)
    moved = scatter_between_levels([_curve(a, f * (1 + 1e-3 * rng.standard_normal(16)),
                                           z * (1 + 0.02 * rng.standard_normal(16)))])
    assert 0.5 < moved.frequency / 1e-3 < 1.8 and 0.5 < moved.damping / 0.02 < 1.8
    # points a factor of two or more apart in amplitude give no window
    assert np.isnan(scatter_between_levels([_curve(a[::6], f[::6], z[::6])]).frequency)


def test_the_measured_modes_are_judged_against_the_larger_of_resolution_and_scatter():
    stick = ModalYardstick(ModalRules(frequency_floor=2e-4, damping_floor=0.02), ModalError(5e-4, 0.011))
    assert stick.rules == ModalRules(frequency_floor=5e-4, damping_floor=0.02)
    assert stick.to_json()["frequency_ruled_by"] == "scatter_between_levels"
    assert stick.to_json()["damping_ruled_by"] == "resolution"
    unknown = ModalYardstick(ModalRules(), ModalError(float("nan"), float("nan")))
    assert unknown.rules == ModalRules() and unknown.to_json()["frequency_scatter"] is None
    # two errors apart by less than the scatter are the same; apart by more, one is better
    assert not ModalChange.of(ModalError(4e-4, 0.1), ModalError(2e-4, 0.1), stick.rules).better(1.3)
    assert ModalChange.of(ModalError(2e-3, 0.1), ModalError(5e-4, 0.1), stick.rules).better(1.3)
