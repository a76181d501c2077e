"""The scatter between runs (analysis/identification/between_runs.py): estimated where runs overlap, against a
drift of known size drawn in the test, and silent where the runs repeat within their line noise."""
import math

import numpy as np
import pytest

from analysis.identification.between_runs import SPAN, BetweenRuns, between_runs
from analysis.prediction.multiharmonic import HARMONIC_TRUNCATION
from test_predict import C, FREQUENCY, K, K3, M, model_text


def _law(X: np.ndarray) -> np.ndarray:
    """A micro-slip-like kbar: a softening stiffness and a dissipation growing as X^0.6, N/m."""
    x = X / 1e-4
    return 5000.0 - 800.0 * x**0.5 + 1j * 600.0 * x**0.6


def _campaign(levels: np.ndarray, noise: float, drift: float, seed: int, per_line: bool = False):
    """Samples of ``_law`` at 41 lines per run, each run at amplitude ``levels[i]`` times a resonance-like
    shape; every sample has circular noise ``noise`` (relative to |kbar|), every run a complex offset of standard
    deviation ``drift`` N/m (``per_line``: drawn anew at every line of the run)."""
    rng = np.random.default_rng(seed)
    w = 2 * np.pi * np.linspace(79.0, 81.0, 41)
    shape = 1.0 / np.sqrt(1.0 + ((w - w.mean()) / (0.3 * np.ptp(w))) ** 2)
    X, W, K, S, drawn = [], [], [], [], []
    for level in levels:
        x = 1e-4 * level * shape
        k = _law(x)
        std = noise * np.abs(k)
        circular = (rng.standard_normal(w.size) + 1j * rng.standard_normal(w.size)) / math.sqrt(2)
        size = w.size if per_line else 1
        offset = drift * (rng.standard_normal(size) + 1j * rng.standard_normal(size)) / math.sqrt(2)
        X.append(x), W.append(w), K.append(k + std * circular + offset), S.append(std), drawn.append(offset)
    return (*(np.concatenate(a) for a in (X, W, K, S)), np.concatenate(drawn))


def test_a_drift_per_line_of_known_size_is_measured_and_rules():
    """Twelve runs, a factor of 1.2 apart, every sample of every run offset by a drift of 150 N/m against a line
    noise of about 2 N/m: the estimate is within 15 % of the drift as drawn, and it rules."""
    X, w, k, s, drawn = _campaign(np.geomspace(1.0, 1.2**11, 12), 5e-4, 150.0, seed=11, per_line=True)
    found = between_runs(X, w, k, s)
    assert found.rules and found.groups >= 40
    assert found.tau == pytest.approx(np.std(drawn, ddof=1), rel=0.15)
    assert found.line_noise < 5.0
    assert np.allclose(found.combined(s), np.sqrt(s**2 + found.tau**2))
    assert "the scatter between runs" in found.text() and found.to_json()["ruled_by"] == "between_runs"


def test_one_line_measured_by_runs_whose_frequencies_differ_in_their_last_digits_is_one_line():
    """Imported runs give the same line with frequencies that differ by rounding (1e-13 here): those samples are
    one line, taken in amplitude order along it, and give as many groups as when the frequencies are equal."""
    X, w, k, s, _ = _campaign(np.geomspace(1.0, 1.2**11, 12), 5e-4, 150.0, seed=11, per_line=True)
    exact = between_runs(X, w, k, s)
    # each run's lines off by its own last digits, the smallest amplitudes the highest: w order is not X order
    runs = np.repeat(np.arange(12), w.size // 12)
    rounded = w * (1.0 + 1e-13 * (11 - runs))
    found = between_runs(X, rounded, k, s)
    assert exact.groups >= 40 and found.groups == exact.groups and found.tau == pytest.approx(exact.tau)


def test_a_drift_per_run_is_measured_to_its_order_on_every_seed():
    """Each run offset by one drift of 150 N/m over all its lines (a structure that settled between runs): twelve
    runs realise only twelve offsets, whose groups of four give about nine independent values, so the estimate
    is good to its order, not to a percent. On ten seeds it rules every time and lies within a factor 2 of the
    offsets' standard deviation as drawn."""
    ratios = []
    for seed in range(10, 20):
        X, w, k, s, drawn = _campaign(np.geomspace(1.0, 1.2**11, 12), 5e-4, 150.0, seed=seed)
        found = between_runs(X, w, k, s)
        assert found.rules
        ratios.append(found.tau / np.std(drawn, ddof=1))
    assert 0.5 < min(ratios) and max(ratios) < 2.0, ratios


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_runs_that_repeat_within_their_noise_leave_the_line_noise_ruling(seed):
    """No drift: the curved kbar seen by twelve dense runs is cancelled to within the line noise by the
    combination, the sign test does not fire and the standard deviations are left as they are."""
    X, w, k, s, _ = _campaign(np.geomspace(1.0, 1.2**11, 12), 1e-3, 0.0, seed=seed)
    found = between_runs(X, w, k, s)
    assert not found.rules and found.groups >= 40
    assert found.combined(s) is not None and np.array_equal(found.combined(s), s)
    assert found.to_json()["ruled_by"] == "line_noise"


def test_coulomb_friction_steepest_law_stays_below_the_noise():
    """Coulomb friction's Im kbar ~ 1/X is the steepest a law of the library has: over a factor of SPAN its cubic
    term is below a line noise of 0.1 % of kbar, so dense runs without drift do not rule."""
    rng = np.random.default_rng(7)
    w = np.linspace(100.0, 120.0, 41)
    X, W, K, S = [], [], [], []
    for level in np.geomspace(1.0, 8.0, 16):
        x = 1e-4 * level * (1.0 + 0.1 * np.sin(w))
        k = 1j * 4 * 0.1 / (np.pi * x)
        std = 1e-3 * np.abs(k)
        K.append(k + std * (rng.standard_normal(w.size) + 1j * rng.standard_normal(w.size)) / math.sqrt(2))
        X.append(x), W.append(w), S.append(std)
    found = between_runs(*(np.concatenate(a) for a in (X, W, K, S)))
    assert found.groups > 100 and not found.rules


def test_levels_a_factor_of_two_apart_cannot_tell_and_say_so():
    """Three runs a factor of two apart, a drift of 150 N/m between them: no four runs measure one line within a
    factor SPAN, so nothing is estimated and the text says the line noise ruled for want of overlapping runs."""
    X, w, k, s, _ = _campaign(np.array([1.0, 2.0, 4.0]), 1e-3, 150.0, seed=4)
    found = between_runs(X, w, k, s)
    assert found == BetweenRuns(0.0, found.line_noise, 0, 0, 1.0, False)
    assert "not measurable" in found.text() and f"factor {SPAN:g}" in found.text()


def test_a_jump_between_branches_does_not_move_the_estimate():
    """A few groups across a jump (one run on the other branch at a few lines) are far off; the median keeps the
    estimate of the drift."""
    X, w, k, s, _ = _campaign(np.geomspace(1.0, 1.2**11, 12), 5e-4, 150.0, seed=5)
    clean = between_runs(X, w, k, s)
    jumped = k.copy()
    jumped[41 * 6 + 18: 41 * 6 + 23] += 5000.0       # run 7, five lines on another branch
    found = between_runs(X, w, jumped, s)
    assert found.rules and found.tau == pytest.approx(clean.tau, rel=0.15)


# ----------------------------------------------------------------------------- a whole test that repeats poorly
# The Duffing oscillator of test_predict.py held at twelve displacement amplitudes 0.4-1.6 mm (a factor 1.13
# apart), its receptance written from the single-harmonic formula h = 1 / (k + 3/4 k3 a^2 - m w^2 + j c w) -- no
# simulator, no harmonic balance of the product's -- with a line noise of 0.2 % and, at every line of every run, a
# stiffness that wanders by DRIFT N/m: a rig that repeats a line ten times less well than it measures it.
DRIFT = 4.0
LEVELS = np.geomspace(0.4e-3, 1.6e-3, 12)


def _write_drifting_session(path, drift: float, seed: int) -> None:
    from app.session import RunSpec, SessionWriter

    rng = np.random.default_rng(seed)
    writer = SessionWriter(path, plan_text="", software_version="test")
    w = 2 * np.pi * FREQUENCY
    for a in LEVELS:
        wander = drift * rng.standard_normal(w.size)
        h = 1.0 / (K + wander + 0.75 * K3 * a**2 - M * w**2 + 1j * C * w)
        std = 2e-3 * np.abs(h)
        measured = h + std / math.sqrt(2) * (rng.standard_normal(h.shape) + 1j * rng.standard_normal(h.shape))
        force = a / np.abs(h)
        writer.begin_run(RunSpec(f"sine_x_{a:.3g}m_up", "stepped_sine", float(np.median(force)), "up", "x", ["x"],
                                 256.0, ["force", "acc:x"], ["N", "m/s^2"],
                                 extras={"frf_std/x": ("m/N", (), "f8"), "force_amplitude": ("N", (), "f8")},
                                 attrs={"control": "response", "control_dof": "x",
                                        "control_quantity": "displacement", "control_target": float(a),
                                        "control_units": "m"}))
        for k, f in enumerate(FREQUENCY):
            writer.append_line(f, {"x": measured[k]}, {"frf_std/x": std[k], "force_amplitude": force[k]})
        writer.end_run("complete")
    writer.close()


def _workbench(path, yardsticks=None, levels=None):
    import tomllib

    from analysis.loop.workbench import Workbench
    from analysis.mechanics.model import load_model
    from app.analyze import read_measurements

    measurements = read_measurements(path)
    if levels is not None:
        measurements = measurements.at_levels({c.key() for c in levels})
    wb = Workbench(load_model(tomllib.loads(model_text('"cubic"'))), measurements, yardsticks=yardsticks)
    wb.prepare()
    return wb


@pytest.fixture(scope="module")
def drifting(tmp_path_factory):
    path = tmp_path_factory.mktemp("drift") / "duffing.h5"
    _write_drifting_session(path, DRIFT, seed=3)
    return path


@pytest.mark.slow
def test_a_test_that_repeats_poorly_is_judged_by_its_scatter_and_its_intervals_cover(drifting):
    """The workbench measures the wandering stiffness from the runs (within 25 % of DRIFT), judges the cubic by it,
    and the fit keeps its lines (no more than a tenth left out) with an interval that covers k3. The same samples
    judged by their line noise alone leave most lines out, and the interval misses."""
    from analysis.fitting.fit import fit_laws
    from analysis.mechanics.elements import LawTerm
    from analysis.laws import get_law

    wb = _workbench(drifting)
    report = wb.reports["spring"]
    assert report.yardstick.rules and report.yardstick.tau == pytest.approx(DRIFT, rel=0.25)
    # the session's stiffness wanders, its damping does not: the scatter lies in Re kbar, and its parts say so
    tau_re, tau_im = report.yardstick.tau_parts
    assert tau_re == pytest.approx(DRIFT, rel=0.25) and tau_im < 0.25 * DRIFT
    assert report.yardstick.to_json()["between_runs_std_parts"] == [tau_re, tau_im]
    fit = report.fit.terms[0]
    assert report.fit.outlier_share <= 0.10
    assert abs(fit.params["k3"] - K3) < 3 * fit.stderr["k3"], (fit.params["k3"], fit.stderr["k3"])
    s = report.samples
    line_noise = np.sqrt(np.maximum(s.kbar_std**2 - report.yardstick.tau**2, 0.0))
    alone = fit_laws([LawTerm(get_law("cubic"), {})], s.X, s.w, s.kbar, line_noise, exclude_outliers=True)
    covered = abs(alone.terms[0].params["k3"] - K3) < 3 * alone.terms[0].stderr["k3"]
    assert alone.outlier_share > 0.10 or not covered


@pytest.mark.slow
def test_runs_that_repeat_leave_the_line_noise_ruling_and_a_refit_on_part_inherits_the_whole_tests(drifting,
                                                                                                     tmp_path):
    """Without the wandering the line noise rules. A workbench on half of the levels -- a refit of the held-out
    checks -- judges its samples by the whole test's yardstick, not by what six runs can tell."""
    steady = tmp_path / "steady.h5"
    _write_drifting_session(steady, 0.0, seed=3)
    assert not _workbench(steady).reports["spring"].yardstick.rules
    whole = _workbench(drifting)
    half = whole.measurements.level_controls()[::2]
    part = _workbench(drifting, whole.yardsticks(), half)
    assert part.reports["spring"].yardstick is whole.reports["spring"].yardstick
    assert not _workbench(drifting, None, half).reports["spring"].yardstick.rules    # 6 runs: too few groups


@pytest.mark.slow
def test_the_frf_error_a_right_model_shows_against_runs_that_repeat_poorly_is_the_floor_reported(drifting, tmp_path):
    """The cubic at its fitted k3 is the joint's law; against the drifting runs its FRF error is what the wandering
    stiffness and the line noise alone give. The floor the workbench reports is that error, and its two parts are
    what the session was written with: the line noise 0.2 %, and the wander carried to the FRFs by the formula,
    dh = -h^2 dk, computed here from the receptance written, not by the product."""
    wb = _workbench(drifting)
    floor, error = wb.error_floor, wb.compare().error
    assert floor.ruled_by == ("spring",)
    assert floor.line_noise == pytest.approx(2e-3, rel=0.05)
    w = 2 * np.pi * FREQUENCY
    h = np.concatenate([1.0 / (K + 0.75 * K3 * a**2 - M * w**2 + 1j * C * w) for a in LEVELS])
    written = DRIFT * math.sqrt(np.sum(np.abs(h) ** 4) / np.sum(np.abs(h) ** 2))
    assert floor.between_runs == pytest.approx(written, rel=0.3)       # tau is itself estimated within 25 %
    assert error == pytest.approx(floor.total, rel=0.3)
    assert "the model is within what the test repeats" in floor.text(error)
    # runs that repeat: no scatter between runs is carried, and the floor is the line noise
    steady = tmp_path / "steady.h5"
    _write_drifting_session(steady, 0.0, seed=3)
    calm = _workbench(steady)
    assert calm.error_floor.ruled_by == () and calm.error_floor.between_runs == 0.0
    assert calm.error_floor.total == pytest.approx(2e-3, rel=0.05)
    # the harmonics resolve a tenth of what the test allows, never coarser where it repeats well
    assert wb.harmonics.truncation == pytest.approx(max(HARMONIC_TRUNCATION, 0.1 * floor.total))
    assert calm.harmonics.truncation == HARMONIC_TRUNCATION < wb.harmonics.truncation


def test_the_floor_is_the_spread_a_scatter_of_kbar_gives_the_frfs_by_monte_carlo():
    """One grounded element at the driven DOF, kbar scattered from run to run by a complex Gaussian of variance
    tau^2: the FRF error of the exact receptance h / (1 + dk h) against h, averaged over draws, is the floor, to
    first order in tau |h| (here at most 0.05)."""
    from analysis.identification.between_runs import RunSensitivity, frf_error_floor

    rng = np.random.default_rng(11)
    w = np.linspace(20.0, 40.0, 60)
    h = 1.0 / (900.0 - w**2 + 1j * 0.6 * w)                 # the structure with its element, m/N
    tau = 0.05 / np.max(np.abs(h))
    yardstick = BetweenRuns(tau, tau / 30, 40, 40, 1e-12, True)
    floor = frf_error_floor([RunSensitivity(h[:, None], None, (-h**2)[:, None, None])], [yardstick], ["e"])
    dk = tau / math.sqrt(2) * (rng.standard_normal((20000, w.size)) + 1j * rng.standard_normal((20000, w.size)))
    drawn = math.sqrt(np.mean(np.sum(np.abs(h / (1 + dk * h) - h) ** 2, axis=1)) / np.sum(np.abs(h) ** 2))
    assert floor.between_runs == pytest.approx(drawn, rel=0.02)
    assert math.isnan(floor.line_noise) and floor.total == floor.between_runs and floor.ruled_by == ("e",)
    # a yardstick that does not rule carries nothing
    quiet = BetweenRuns(tau, tau / 30, 40, 3, 0.9, False)
    std = 1e-3 * np.abs(h)[:, None]
    unruled = frf_error_floor([RunSensitivity(h[:, None], std, (-h**2)[:, None, None])], [quiet], ["e"])
    assert unruled.between_runs == 0.0 and unruled.ruled_by == ()
    assert unruled.total == pytest.approx(1e-3, rel=1e-12)          # the FRFs' noise alone
    # and with no noise measured either, there is no floor to state
    assert frf_error_floor([RunSensitivity(h[:, None], None, (-h**2)[:, None, None])], [quiet], ["e"]) is None
    # nor with FRFs measured without noise and no scatter: a floor of zero states nothing (and divides nothing)
    exact = RunSensitivity(h[:, None], np.zeros((len(h), 1)), (-h**2)[:, None, None])
    assert frf_error_floor([exact], [quiet], ["e"]) is None
