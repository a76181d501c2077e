"""The jump-robust error on a rig whose measured sweep jumps a line early: a 2-DOF rig with a hardening cubic at
x1 and dry friction at x2, three levels swept up, analysed from a model with the cubic only. Also the wording
of error ratios."""
import tomllib

import numpy as np
import pytest

from analysis import load_elements, load_structure
from analysis.comparison import gain_phrase
from analysis.harmonic_balance import continue_response
from analysis.model import load_model
from analysis.workbench import Workbench
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
    return wb, before, wb.compare()


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
    wb, before, after = analysed
    assert wb.model.element("b").laws[0].values["fs"] == pytest.approx(0.1, rel=0.01)
    # the measurement at 3 N left the resonant branch one line before the prediction does
    run = next(r for r in wb.measurements.sine if r.force == 3.0)
    (jump,) = after.jumps
    assert jump.run == run.name and jump.lines_early == 1
    assert jump.measured_between == pytest.approx((6.2, 6.28))
    assert jump.predicted_between == pytest.approx((6.28, 6.36))
    assert jump.fold_hz == pytest.approx(true_upper_fold(), rel=2e-3)
    assert after.other_branch_hz(wb.measurements.sine) == {run.name: [pytest.approx(6.28)]}
    # against the swept prediction alone that one line carries most of the error; against the nearer stable
    # branch the right law cuts the error by well over 5 x
    assert before.error / after.error > 10, (before.error, after.error)
    assert swept_only_error(wb, before) / swept_only_error(wb, after) < 5
    assert swept_only_error(wb, after) > 3 * after.error


def test_the_jump_is_reported_in_the_text_and_the_json(analysed):
    wb, _, after = analysed
    text = report_text(wb, [])
    assert "jumps (predicted fold against measured):" in text
    assert "measured between 6.2 and 6.28 Hz (1 line early)" in text
    assert "measured on the other branch" in text
    out = wb.to_json()
    (jump,) = out["jumps"]
    assert jump["fold_hz"] == pytest.approx(after.jumps[0].fold_hz)
    assert jump["measured_between_hz"] == pytest.approx([6.2, 6.28]) and jump["lines_early"] == 1
    assert list(out["other_branch_hz"].values()) == [[pytest.approx(6.28)]]


def test_gain_phrases():
    assert gain_phrase(3.2) == "x3.20 better"
    assert gain_phrase(1 / 1.25) == "x1.25 worse"


def test_the_model_tab_shows_the_jump_and_marks_the_line(qtbot, analysed):
    from app.gui.main_window import MainWindow
    from app.gui.results import analysis_view
    wb, _, _ = analysed
    window = MainWindow("test")
    qtbot.addWidget(window)
    window.model._update(analysis_view(wb, []))
    assert "measured between 6.2 and 6.28 Hz (1 line early)" in window.model.jump_label.text()
    crosses = [c for c in window.model.residual.listDataItems() if c.opts.get("symbol") == "x"]
    assert len(crosses) == 1 and crosses[0].getData()[0] == pytest.approx([6.28])
