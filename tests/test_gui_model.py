"""The missing-effect loop driven through the Model tab on a session whose rig hides nonlinear laws the model
does not have: Analyze, Add on the top candidate (the displayed error falls, to the value the command-line
analysis finds for the same addition), Undo (back to where it was)."""
import re
import tomllib
from types import SimpleNamespace

import pytest

from analysis.mechanics.model import load_model
from analysis.common.tables import load_toml
from app.analyze import run_workbench
from app.gui.main_window import MainWindow
from app.campaign.instruments import emulated_instruments
from app.campaign.measure import run_plan
from app.campaign.plan import parse_plan
from drivers.simulation.rig import load_rig
from paper_structure import PAPER_STRUCTURE

LINEAR_MODEL = PAPER_STRUCTURE + """
[[element]]
name = "left"
dof = "x1"
laws = []

[[element]]
name = "right"
dof = "x2"
laws = []
"""
PLAN = {"random": {"force_rms": 0.05, "band": [0.5, 5.0], "duration": 16.0},
        "stepped_sine": [{"force": 0.8, "start": 0.9, "stop": 2.9, "step": 0.125, "direction": "up",
                          "refine": False}],
        "limits": {"max_force": 5.0, "max_acceleration": 50.0}}


@pytest.fixture(scope="module")
def hidden_effect_session(tmp_path_factory):
    """paper-2dof (cubic + quadratic damping at x1, cubic + Coulomb at x2) measured through the drivers, and
    the model that knows none of it."""
    folder = tmp_path_factory.mktemp("hidden")
    session, model = folder / "paper.h5", folder / "linear.toml"
    model.write_text(LINEAR_MODEL, encoding="utf-8")
    with emulated_instruments(load_rig("paper-2dof")) as instruments:
        summary = run_plan(parse_plan(PLAN), instruments, session)
    assert not summary.aborted, summary.aborted
    return session, model


def shown_error(window) -> float:
    return float(re.match(r"FRF error (\S+)", window.model.error_label.text()).group(1))


@pytest.mark.slow
def test_add_on_the_top_candidate_lowers_the_displayed_error_and_undo_restores_it(qtbot, hidden_effect_session):
    session, model = hidden_effect_session
    window = MainWindow("test")
    qtbot.addWidget(window)
    window.lab.load_model_file(str(model))
    window.lab.open_session(str(session))
    panel = window.model
    assert not panel.undo_button.isEnabled()

    with qtbot.waitSignal(window.lab.analysisUpdated, timeout=120000):
        panel.analyze_button.click()
    qtbot.waitUntil(lambda: panel.candidates.rowCount() > 0)
    before = shown_error(window)
    top = window.lab.analysis.candidates[0]
    assert (panel.candidates.item(0, 0).text(), panel.candidates.item(0, 1).text()) == (top.element, top.law)
    assert top.explanation in panel.explanation.toPlainText()       # the top one is selected and explained
    assert not panel.undo_button.isEnabled()

    with qtbot.waitSignal(window.lab.analysisUpdated, timeout=120000):
        panel.candidates.cellWidget(0, 5).click()                     # its Add button
    qtbot.waitUntil(lambda: len(window.lab.analysis.history) == 2)
    after = shown_error(window)
    assert after < before
    assert after == pytest.approx(top.error, rel=1e-3)                # the ranking predicted it
    # the same addition through the command-line path (a fresh workbench) gives the same error
    wb, _ = run_workbench(session, model, [f"{top.element}:{top.law}"], rank=False)
    assert after == pytest.approx(wb.history[-1].error, rel=1e-3)
    laws = {el.name: [law.law for law in el.laws] for el in window.lab.analysis.elements}
    assert laws[top.element] == [top.law]
    assert panel.history.listDataItems()[0].getOriginalDataset()[1] == pytest.approx([before, after], rel=1e-3)

    assert panel.undo_button.isEnabled()
    with qtbot.waitSignal(window.lab.analysisUpdated, timeout=120000):
        panel.undo_button.click()
    qtbot.waitUntil(lambda: len(window.lab.analysis.history) == 1)
    assert shown_error(window) == pytest.approx(before, rel=1e-6)
    assert all(not el.laws for el in window.lab.analysis.elements)


def test_a_model_that_does_not_fit_the_session_is_a_message(qtbot, hidden_effect_session, tmp_path):
    session, _ = hidden_effect_session
    wrong = tmp_path / "wrong.toml"
    wrong.write_text(LINEAR_MODEL.replace('"x1", "x2"]\nmass', '"a", "b"]\nmass').replace('dof = "x1"', 'dof = "a"')
                     .replace('dof = "x2"', 'dof = "b"'), encoding="utf-8")
    load_model(load_toml(wrong))                                        # a valid model, of another structure
    window = MainWindow("test")
    qtbot.addWidget(window)
    window.lab.load_model_file(str(wrong))
    window.lab.open_session(str(session))
    with qtbot.waitSignal(window.lab.error, timeout=60000) as failed:
        window.model.analyze_button.click()
    assert "not in the model's structure" in failed.args[0]
    assert window.error_bar.isVisibleTo(window) and failed.args[0] in window.error_bar.label.text()
    assert window.lab.analysis is None and window.model.error_label.text().startswith("FRF error: —")


def test_analyze_names_a_bad_add_by_the_option_that_gave_it(hidden_effect_session, capsys):
    from app.cli import main

    session, model = hidden_effect_session
    assert main(["analyze", str(session), str(model), "--add", "left:cubicc", "--no-history"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("contactid: error: --add left:cubicc: unknown law 'cubicc'") and "\n" not in err
    assert main(["analyze", str(session), str(model), "--add", "middle:cubic", "--no-history"]) == 2
    assert f"{model}: --add middle:cubic: no element named 'middle'" in capsys.readouterr().err


def test_a_model_without_joints_is_no_identification_error(qtbot):
    """A linear rig (a structure and no elements) gives FRFs and nothing to identify: no error banner."""
    window = MainWindow("test")
    qtbot.addWidget(window)
    errors = []
    window.lab.error.connect(errors.append)
    structure = tomllib.loads(LINEAR_MODEL.split("[[element]]")[0])["structure"]
    window.lab.set_model(load_model({"structure": structure, "element": []}, "linear rig"), "linear rig")
    assert window.identify.status.text().startswith("The model has no elements: nothing to identify")
    window.lab._measurement_reader = lambda: (lambda: SimpleNamespace(sine=["a stepped-sine run"], random=None))
    window.lab._identify_now()
    qtbot.waitUntil(lambda: not window.lab.analysis_tasks.busy)
    qtbot.wait(50)
    assert errors == [] and window.lab.identification is None
