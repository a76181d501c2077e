"""The jump-robust error on a rig whose measured sweep jumps a line early: a 2-DOF rig with a hardening cubic at
x1 and dry friction at x2, three levels swept up, analysed from a model with the cubic only. Also the wording
of error ratios."""
import tomllib
from dataclasses import replace

import numpy as np
import pytest

from analysis import load_elements, load_structure
from analysis.prediction.comparison import gain_phrase
from analysis.prediction.harmonic_balance import continue_response
from analysis.mechanics.model import load_model
from analysis.loop.workbench import Workbench
from app.analyze import report_text
from app.campaign.instruments import emulated_instruments
from app.campaign.measure import run_plan
from app.campaign.plan import parse_plan
from app.session.writer import open_session
from app.session.data import measurements_from_session
from drivers.simulation.rig import parse_rig
from test_hidden_effects import LUMPED, LUMPED_IO, element

RIG_ELEMENTS = element("a", "x1", '{ law = "cubic", k3 = 3.0e5 }') + element("b", "x2", '{ law = "coulomb", fs = 0.1 }')
# lines every 0.08 Hz from 5 Hz: at 3 N the line 6.28 Hz lies 6.5 mHz below the upper fold (6.2865 Hz), where
# the resonant branch's basin is so small that the step onto that line throws the structure off it
PLAN = "".join(f'[[stepped_sine]]\nforce = {f}\nstart = 5.0\nstop = 7.4\nstep = 0.08\ndirection = "up"\n'
               f'refine = false\n' for f in (0.5, 1.0, 3.0)) + "[limits]\nmax_force = 20.0\nmax_acceleration = 1500.0\n"


@pytest.fixture(scope="module")
def analysed(tmp_path_factory):
    rig = parse_rig('name = "jump"\n' + LUMPED + RIG_ELEMENTS + LUMPED_IO, "jump.toml")
    path = tmp_path_factory.mktemp("jump") / "s.h5"
    with emulated_instruments(rig) as inst:
        assert not run_plan(parse_plan(tomllib.loads(PLAN), PLAN), inst, path).aborted
    with open_session(path) as s:
        measurements = measurements_from_session(s)
    wb = Workbench(load_model(tomllib.loads(LUMPED + element("a", "x1", '"cubic"') + element("b", "x2", ""))),
                   measurements)
    wb.start()
    before = wb.compare()
    wb.add("b", "coulomb")
    after = wb.compare()
    # what the loop's comparison holds before any report asks for a fold (a report locates it in place)
    unlocated = [(j.located, j.fold_hz) for j in after.jumps]
    return wb, before, after, unlocated


def swept_only_error(wb, comp):
    """The error against the swept prediction alone (what the jump-robust error replaces)."""
    num = sum(np.sum(np.abs(comp.predicted[r.name] - r.receptance) ** 2) for r in wb.measurements.sine)
    return np.sqrt(num / sum(np.sum(np.abs(r.receptance) ** 2) for r in wb.measurements.sine))


def true_upper_fold():
    s = load_structure(tomllib.loads(LUMPED)["structure"])
    els = load_elements(tomllib.loads(RIG_ELEMENTS), s, None, True)
    curve = continue_response(s, els, "x2", 3.0, 2 * np.pi * 6.0, 2 * np.pi * 6.4)
    return curve.fold_frequencies[0] / (2 * np.pi)


@pytest.mark.slow
def test_an_early_jump_does_not_dominate_the_error_of_the_right_model(analysed):
    wb, before, after, unlocated = analysed
    assert wb.model.element("b").laws[0].values["fs"] == pytest.approx(0.1, rel=0.01)
    # the measurement at 3 N left the resonant branch one line before the prediction does
    run = next(r for r in wb.measurements.sine if r.force == 3.0)
    (jump,) = after.jumps
    assert jump.run == run.name and jump.lines_early == 1
    assert jump.measured_between == pytest.approx((6.2, 6.28))
    assert jump.predicted_between == pytest.approx((6.28, 6.36))
    # the loop's comparisons go without the fold, which only a report reads; asked for, it is located in place
    assert unlocated == [(False, None)]
    assert wb.compare(folds=True) is after
    assert jump.located and jump.fold_hz == pytest.approx(true_upper_fold(), rel=2e-3)
    assert after.other_branch_hz(wb.measurements.sine) == {run.name: [pytest.approx(6.28)]}
    # against the swept prediction alone that one line carries most of the error; against the nearer stable
    # branch the right law cuts the error by well over 5 x
    assert before.error / after.error > 10, (before.error, after.error)
    assert swept_only_error(wb, before) / swept_only_error(wb, after) < 5
    assert swept_only_error(wb, after) > 3 * after.error


@pytest.mark.slow
def test_the_jump_is_reported_in_the_text_and_the_json(analysed):
    wb, _, after, _ = analysed
    text = report_text(wb, [])
    assert "jumps (predicted fold against measured):" in text
    assert "measured between 6.2 and 6.28 Hz (1 line early)" in text
    assert "measured on the other branch" in text
    assert "predicted jump at 6.29 Hz" in text
    out = wb.to_json()
    (jump,) = out["jumps"]
    assert jump["fold_hz"] == pytest.approx(true_upper_fold(), rel=2e-3)
    assert jump["measured_between_hz"] == pytest.approx([6.2, 6.28]) and jump["lines_early"] == 1
    assert list(out["other_branch_hz"].values()) == [[pytest.approx(6.28)]]


def test_gain_phrases():
    assert gain_phrase(3.2) == "x3.20 better"
    assert gain_phrase(1 / 1.25) == "x1.25 worse"


@pytest.mark.slow
def test_the_model_tab_shows_the_jump_and_marks_the_line(qtbot, analysed):
    from app.gui.main_window import MainWindow
    from app.gui.results import analysis_view
    wb, _, _, _ = analysed
    window = MainWindow("test")
    qtbot.addWidget(window)
    window.model._update(analysis_view(wb, []))
    assert "measured between 6.2 and 6.28 Hz (1 line early)" in window.model.jump_label.text()
    assert "predicted jump at 6.29 Hz" in window.model.jump_label.text()
    crosses = [c for c in window.model.residual.listDataItems() if c.opts.get("symbol") == "x"]
    assert len(crosses) == 1 and crosses[0].getData()[0] == pytest.approx([6.28])


@pytest.mark.slow
def test_without_harmonics_the_fit_keeps_its_own_comparison_with_its_jump(analysed):
    # the bias correction's comparison with harmonics is kept for compare, jumps and all: the model's own
    measurements = analysed[0].measurements
    blind = replace(measurements, sine=[replace(r, distortion=None) for r in measurements.sine])
    wb = Workbench(load_model(tomllib.loads(LUMPED + element("a", "x1", '"cubic"') + element("b", "x2", ""))), blind)
    wb.start()
    wb.add("b", "coulomb")
    assert wb.harmonics_blind and wb.harmonics is not None
    kept = wb.compare()
    again = wb.predictor.compare(harmonics=wb.harmonics)
    assert len(kept.jumps) == 1 and kept.error == pytest.approx(again.error, rel=1e-12)
    for run, compared in kept.compared.items():
        np.testing.assert_allclose(compared, again.compared[run], rtol=1e-12, atol=0)
    assert wb.compare(folds=True).jumps[0].fold_hz == pytest.approx(true_upper_fold(), rel=2e-3)


def _run_and_prediction(L: int, missed: list[int], far: float, harmonics_measured: bool, seed: int = 7):
    """A run of ``L`` lines with unit noise, and a prediction right except at the lines ``missed``, off there by
    100 sigma, and off everywhere by ``far`` times the receptance."""
    from analysis.prediction.comparison import RunPrediction
    from analysis.common.measurements import SineRun

    rng = np.random.default_rng(seed)
    truth = (1e-4 / (1 + 1j * np.linspace(-2, 2, L)))[:, None]
    std = np.full((L, 1), 1e-7)
    measured = truth + std / np.sqrt(2) * (rng.standard_normal((L, 1)) + 1j * rng.standard_normal((L, 1)))
    predicted = truth * (1 + far)
    predicted[missed] += 100 * std[missed]
    run = SineRun("up", 1.0, "up", "x1", ["x1"], np.linspace(5, 7, L), measured, std,
                  distortion=np.zeros(L) if harmonics_measured else None)
    ok = np.ones(L, bool)
    return run, RunPrediction(predicted, predicted, ok, ok, np.zeros((L, 1), complex), np.zeros((L, 1), complex))


@pytest.mark.parametrize("harmonics_measured", [False, True])
def test_without_harmonics_the_chi_square_is_also_given_capped_at_the_outlier_limit(harmonics_measured):
    """On imported FRFs (no harmonics) two lines missed by 100 sigma (where friction sticks) cost the capped
    chi-square the outlier limit each, as a kbar sample's share is capped; the plain one counts them whole, and
    where the harmonics were measured only the plain one is given."""
    from analysis.prediction.comparison import compare_predictions
    from analysis.common.statistics import outlier_limit

    run, pred = _run_and_prediction(40, [5, 20], 0.0, harmonics_measured)
    comp = compare_predictions([run], {"up": pred})
    z = np.abs(pred.swept - run.receptance) ** 2 / run.receptance_std ** 2
    assert comp.chi_square == pytest.approx(float(z.sum()), rel=1e-12)
    if harmonics_measured:
        assert comp.capped_chi_square is None
    else:
        clean = float(np.delete(z, [5, 20]).sum())
        assert comp.capped_chi_square == pytest.approx(clean + 2 * outlier_limit(40), rel=1e-12)


def test_a_fall_of_the_plain_or_the_capped_chi_square_is_a_fall_above_the_noise():
    """A model right on most lines but 100 sigma off at three where friction sticks, after one a few sigma off
    everywhere: the plain chi-square rises, the capped one falls (seed 786947 random 48); where the harmonics were
    measured the plain one alone judges. Two models far from every line: the capped one cannot fall (every share
    at the cap), the plain one does (seed 172963 random 17)."""
    from analysis.prediction.comparison import chi_square_falls, compare_predictions

    def comparison(missed, far, harmonics=False):
        run, pred = _run_and_prediction(40, missed, far, harmonics)
        return compare_predictions([run], {"up": pred})

    for harmonics in (False, True):
        before, after = comparison([], 0.004, harmonics), comparison([5, 20, 30], 0.0, harmonics)
        assert after.chi_square > before.chi_square
        assert chi_square_falls(before, after, 1, 1e-3) is not harmonics
    far, farther = comparison([], 0.5), comparison([], 1.0)
    assert far.capped_chi_square == pytest.approx(farther.capped_chi_square)
    assert chi_square_falls(farther, far, 1, 1e-3)
    assert not chi_square_falls(far, farther, 1, 1e-3)
