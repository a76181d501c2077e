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


def window_on(qtbot, session, model) -> MainWindow:
    """The lab window with ``model`` loaded and ``session`` open."""
    window = MainWindow("test")
    qtbot.addWidget(window)
    window.lab.load_model_file(str(model))
    window.lab.open_session(str(session))
    return window


def shown_error(window) -> float:
    return float(re.match(r"FRF error (\S+)", window.model.error_label.text()).group(1))


@pytest.mark.slow
def test_add_on_the_top_candidate_lowers_the_displayed_error_and_undo_restores_it(qtbot, hidden_effect_session):
    session, model = hidden_effect_session
    window = window_on(qtbot, session, model)
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
    assert err.startswith(f"contactid: error: {model}: --add left:cubicc: unknown law 'cubicc'") and "\n" not in err
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


def _twelve_level_view():
    """An analysis of the Brake-Reuss beam's kind of session: four force levels and eight response levels held at
    x1, the runs named (and so listed by the session) in text order."""
    import numpy as np

    from analysis.common.measurements import Control, SineRun
    from analysis.prediction.comparison import LevelError
    from app.gui.results import AnalysisView, HistoryView

    f = np.linspace(79.0, 81.2, 12)
    h = (1e-4 / (1 + 1j * (f - 80.3))).reshape(-1, 1)
    levels = [Control("force", "x1", "force", v) for v in (0.2, 0.5, 1.0, 1.5)] + \
        [Control("response", "x1", "acceleration", v) for v in (5, 20, 30, 40, 50, 60, 70, 80)]
    runs = sorted([SineRun(f"sine_{c.label().replace(' ', '')}_up", 0.12 + 0.03 * c.target, "up", "x1", ["x1"], f,
                           h * (1 + 0.01 * i), control=c) for i, c in enumerate(levels)], key=lambda r: r.name)
    return levels, AnalysisView(
        elements=[], error=0.98, error_by_level=[LevelError(r.force, 0.5, r.control) for r in runs], runs=runs,
        predicted={r.name: h for r in runs}, residual_map={r.name: np.full(len(f), 0.1) for r in runs},
        candidates=[], history=[HistoryView(0, "start", 0.98)], model_toml="")


def test_twelve_levels_fit_a_small_screen_in_level_order_in_colours_apart(qtbot):
    from app.kbar_view import level_colours

    levels, view = _twelve_level_view()
    window = MainWindow("test")
    qtbot.addWidget(window)
    window.model._update(view)
    # the legend beside the plots lists the runs as the reports do: force levels by force, then response levels
    assert window.model.legend_names() == [f"{c.label()} up · x1" for c in levels] + ["measured at x1"]
    assert window.model.frf.legend is window.model.legend
    # twelve colours, the report's, none shared
    colours = [window.palette.color(c) for c in levels]
    assert colours == ["#%02x%02x%02x" % c for c in level_colours(12)] and len(set(colours)) == 12
    assert "by level: 0.2 N: 0.5, 0.5 N: 0.5, 1 N: 0.5, 1.5 N: 0.5, 5 m/s^2 at x1: 0.5" in \
        window.model.level_errors.text()
    # no label sets the width and no tab the height past a 1366 x 768 screen (title bar and taskbar aside)
    hint = window.minimumSizeHint()
    assert hint.width() <= 1366 and hint.height() <= 740, hint


@pytest.mark.slow
def test_stop_during_discovery_keeps_the_steps_taken_and_says_what_was_not_tried(qtbot, hidden_effect_session):
    session, model = hidden_effect_session
    window = window_on(qtbot, session, model)
    panel = window.model
    with qtbot.waitSignal(window.lab.analysisUpdated, timeout=120000):
        panel.analyze_button.click()
    reported = []

    def on_line(line: str) -> None:                 # Stop as the first law discovery chose is added
        if line.startswith("discover ") and not reported:
            panel.stop_button.click()
            assert "stopping" in panel.auto_label.text() and not panel.stop_button.isEnabled()
        if not line.startswith("discovery:"):
            reported.append(line)
    window.lab.autoProgress.connect(on_line)
    with qtbot.waitSignal(window.lab.analysisUpdated, timeout=300000):
        panel.auto_button.click()
    view = window.lab.analysis
    # every step shown while the loop ran is in the model the tab shows; after Stop nothing more was added
    assert reported and len(view.history) == len(reported) + 1
    kept = {el.name: [law.law for law in el.laws] for el in view.elements}
    for line in reported:
        action, what = line.split(": error")[0].split(" ", 1)
        element, laws = what.split(":")
        assert action == "discover" and kept[element] == laws.split("+")
    assert view.auto[-1].startswith(f"stopped by the user: the model on this tab keeps the {len(reported)} step(s)")
    assert "not tried:" in view.auto[-1]
    # a law set discovery found is called discovered only where the model holds it
    assert all(kept[line.split(":")[0][len("discovered "):]] for line in view.auto if line.startswith("discovered "))
    # no ranking after Stop, and the empty table does not claim every law was tried
    assert not view.ranked and panel.candidates.rowCount() == 0
    assert panel.explanation.toPlainText().startswith("Not ranked: the automatic loop was stopped")
    assert shown_error(window) == pytest.approx(view.history[-1].error, rel=1e-3)
