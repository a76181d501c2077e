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


@pytest.mark.slow
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


@pytest.mark.slow
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
    from analysis.common.measurements import Control

    return _level_view([Control("force", "x1", "force", v) for v in (0.2, 0.5, 1.0, 1.5)] +
                       [Control("response", "x1", "acceleration", v) for v in (5, 20, 30, 40, 50, 60, 70, 80)])


def _level_view(levels):
    """An analysis of one up-sweep at each of ``levels``, held at x1."""
    import numpy as np

    from analysis.common.measurements import SineRun
    from analysis.prediction.comparison import LevelError
    from app.gui.results import AnalysisView, HistoryView

    f = np.linspace(79.0, 81.2, 12)
    h = (1e-4 / (1 + 1j * (f - 80.3))).reshape(-1, 1)
    runs = sorted([SineRun(f"sine_{c.label().replace(' ', '')}_up", 0.12 + 0.03 * c.target, "up", "x1", ["x1"], f,
                           h * (1 + 0.01 * i), control=c) for i, c in enumerate(levels)], key=lambda r: r.name)
    return levels, AnalysisView(
        elements=[], error=0.98, error_by_level=[LevelError(r.force, 0.5, r.control) for r in runs], runs=runs,
        predicted={r.name: h for r in runs}, residual_map={r.name: np.full(len(f), 0.1) for r in runs},
        candidates=[], history=[HistoryView(0, "start", 0.98)], model_toml="")


@pytest.mark.slow
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


def _on_a_small_screen(qtbot, view) -> MainWindow:
    """The window as a 1366 x 768 screen shows it, on the Model tab, with ``view`` drawn."""
    window = MainWindow("test")
    qtbot.addWidget(window)
    window.resize(1366, 768)
    window.show()
    window.tabs.setCurrentWidget(window.model)
    window.model._update(view)
    qtbot.wait(100)
    return window


@pytest.mark.slow
def test_thirty_levels_are_small_multiples_of_neighbours_and_their_legend_stays_on_a_small_screen(qtbot):
    from analysis.common.measurements import Control
    from app.kbar_view import level_panels, panel_title

    levels = [Control("force", "x1", "force", round(0.1 * 1.15**i, 4)) for i in range(20)] + \
        [Control("response", "x1", "acceleration", 5.0 * (i + 1)) for i in range(10)]
    levels, view = _level_view(levels)
    window = _on_a_small_screen(qtbot, view)
    panel = window.model
    panels = level_panels(levels)
    # force levels in two panels of ten neighbours, the response levels in a third, each titled by its range
    assert [len(p) for p in panels] == [10, 10, 10] and len(panel.frf_panels) == 3
    assert set(panel.plots()) >= {"frf_measured_predicted", "frf_measured_predicted_2", "frf_measured_predicted_3"}
    for plot, held in zip(panel.frf_panels, panels):
        assert panel_title(held) in plot.titleLabel.text
        colours = {item.opts["symbolBrush"].color().name() for item in plot.listDataItems() if item.opts["symbol"]}
        assert len(colours) == len(held)                # a colour of its own to each level of the panel
    # the legend lists all thirty by how they were held, in columns, inside the plots' area on the screen
    assert panel.legend_names()[:1] == ["0.1 N up · x1"] and len(panel.legend_names()) == 31
    shown = panel.graphics.mapFromScene(panel.legend.sceneBoundingRect()).boundingRect()
    assert panel.graphics.viewport().rect().contains(shown), shown
    hint = window.minimumSizeHint()
    assert hint.width() <= 1366 and hint.height() <= 740, hint
    # back to a few levels: one plot again
    _, few = _level_view(levels[:4])
    panel._update(few)
    assert len(panel.frf_panels) == 1 and panel.frf.titleLabel.text.startswith("Receptance")


@pytest.mark.slow
def test_the_model_line_shows_an_apostrophe_as_itself(qtbot):
    """The model's origin ("the rig's structure") was escaped for an HTML attribute: the label read "rig&#x27;s"."""
    from PySide6.QtGui import QTextDocument

    _, view = _twelve_level_view()
    window = _on_a_small_screen(qtbot, view)
    window.lab.model = load_model(tomllib.loads(LINEAR_MODEL))
    window.lab.model_label = "starter model for paper-2dof (the rig's structure, an element at each joint) <x>"
    window.model._show_label()
    text = window.model.model_label.text()
    assert "&#x27;" not in text and "&#39;" not in text
    document = QTextDocument()
    document.setHtml(text)
    assert "(the rig's structure, an element at each joint) <x>" in document.toPlainText()


def _tick_labels(plot):
    """The frequency labels a plot draws now: (left, right, text) in px along its axis."""
    from PySide6.QtGui import QImage, QPainter

    image = QImage(8, 8, QImage.Format.Format_ARGB32)
    painter = QPainter(image)
    try:
        texts = plot.getAxis("bottom").generateDrawSpecs(painter)[2]
    finally:
        painter.end()
    return sorted((rect.left(), rect.right(), text) for rect, _, text in texts)


@pytest.mark.slow
def test_the_narrow_frf_panels_of_thirty_levels_keep_their_frequency_labels_apart(qtbot):
    from analysis.common.measurements import Control

    levels = [Control("force", "x1", "force", round(0.1 * 1.15**i, 4)) for i in range(20)] + \
        [Control("response", "x1", "acceleration", 5.0 * (i + 1)) for i in range(10)]
    _, view = _level_view(levels)
    window = _on_a_small_screen(qtbot, view)
    panels = window.model.frf_panels
    assert len(panels) == 3
    # the plots' side as narrow as longer legend names and a wider candidate table leave it: panels of ~50 px
    splitter = window.model.graphics.parentWidget()
    splitter.setSizes([sum(splitter.sizes()) - 690, 690])
    qtbot.wait(50)
    # the session's span, and a wider one (the beam's 77 ... 83 Hz, or a sweep of 20 Hz) on the same narrow panels
    for span in (None, (77.0, 83.0), (70.0, 90.0)):
        if span is not None:
            panels[0].setXRange(*span, padding=0)               # linked: every panel shows it
            qtbot.wait(50)
        for plot in panels:
            labels = _tick_labels(plot)
            assert labels, (span, plot.titleLabel.text)
            for (_, right, text), (left, _, following) in zip(labels, labels[1:]):
                assert left - right >= 6, (span, plot.titleLabel.text, text, following, plot.vb.width())


@pytest.mark.slow
def test_every_candidate_column_and_add_button_is_in_view_on_a_1366_px_screen(qtbot):
    from app.gui.results import CandidateView

    _, view = _twelve_level_view()
    view.candidates = [CandidateView("joint", law, 0.47, 2.1, significant, "why")
                       for law, significant in (("quadratic_damping", True), ("velocity_stiffness", False),
                                                ("anderson_ferri", False))]
    window = _on_a_small_screen(qtbot, view)
    table = window.model.candidates
    header, width = table.horizontalHeader(), table.viewport().width()
    assert sum(table.columnWidth(c) for c in range(table.columnCount())) <= width
    for col in range(table.columnCount()):
        assert 0 <= header.sectionViewportPosition(col) and \
            header.sectionViewportPosition(col) + header.sectionSize(col) <= width, table.horizontalHeaderItem(col)
    assert table.horizontalScrollBar().maximum() == 0
    # each Add button whole inside the table's view, the law's whole name in its cell's tooltip
    for row in range(table.rowCount()):
        button = table.cellWidget(row, table.columnCount() - 1)
        assert button.geometry().right() < width and button.width() >= button.fontMetrics().horizontalAdvance("Add")
    assert table.item(1, 1).toolTip().startswith("joint:velocity_stiffness")
    assert table.horizontalHeaderItem(4).text() == "Significant" and table.horizontalHeaderItem(4).toolTip()


@pytest.mark.slow
def test_the_laws_tree_keeps_ten_rows_after_auto_on_a_small_screen_and_its_share_can_be_moved(qtbot):
    from app.gui.results import CandidateView, ElementView, LawView, ParamView, UnexplainedView

    _, view = _twelve_level_view()
    # after Auto on the beam: two joints of three laws each, candidates, the loop's lines, an unexplained element
    laws = (LawView("cubic", (ParamView("k3", 1e9, 1e7, "N/m^3"),)),
            LawView("coulomb", (ParamView("Fs", 0.3, 0.01, "N"), ParamView("kt", 2e4, 1e3, "N/m"))),
            LawView("quadratic_damping", (ParamView("c2", 4.0, 0.2, "N s^2/m^2"),)))
    view.elements = [ElementView(name, dof, None, False, "", 100, 0, laws) for name, dof in (("left", "x1"),
                                                                                        ("right", "x2"))]
    view.candidates = [CandidateView("left", law, 0.47, 1.1, False, "why") for law in
                       ("quintic", "velocity_stiffness", "anderson_ferri", "iwan", "unilateral", "cubic_damping")]
    view.unexplained = [UnexplainedView("right", "kbar departs from its laws", 12.0, 0.002, 0.0027, 1.24)]
    view.auto = [f"step {i}: add left:law_{i} (x1.3 better, x1.3 required)" for i in range(8)]
    window = _on_a_small_screen(qtbot, view)
    tree = window.model.laws
    rows = tree.visualItemRect(tree.topLevelItem(0)).height()
    assert rows > 0 and tree.viewport().height() >= 10 * rows, (tree.viewport().height(), rows)
    hint = window.minimumSizeHint()
    assert hint.width() <= 1366 and hint.height() <= 740, hint
    # the user gives the candidates more room: the tree keeps a few rows, never collapses
    splitter = window.model.left_splitter
    total = sum(splitter.sizes())
    splitter.moveSplitter(0, 1)
    qtbot.wait(50)
    assert splitter.sizes()[0] < total // 3 and tree.viewport().height() >= 4 * rows


@pytest.mark.slow
def test_error_history_labels_sit_at_their_points_inside_the_plot_and_apart(qtbot):
    import numpy as np
    import pyqtgraph as pg
    from PySide6.QtCore import QPointF

    from app.gui.results import HistoryView

    _, view = _twelve_level_view()
    steps = [("start", 4.61), ("discover left:cubic+quadratic_damping", 0.31),
             ("discover right:cubic+coulomb+velocity_stiffness", 0.0031), ("linear correction x1", 0.0029),
             ("add right:velocity_stiffness", 0.0028), ("add left:quintic", 0.0027)]
    view.history = [HistoryView(i, action, error) for i, (action, error) in enumerate(steps)]
    window = _on_a_small_screen(qtbot, view)
    plot = window.model.history
    for size in ((1366, 768), (1600, 1000)):
        window.resize(*size)
        qtbot.wait(100)
        box = plot.getViewBox()
        frame = box.sceneBoundingRect()
        labels = [item for item in plot.items if isinstance(item, pg.TextItem) and item.isVisible()]
        assert len(labels) >= 4, size                   # most errors shown, not all dropped for want of room
        rects = [label.sceneBoundingRect() for label in labels]
        for i, rect in enumerate(rects):
            assert frame.contains(rect), (size, labels[i].toPlainText())
            assert not any(rect.intersects(other) for other in rects[i + 1:]), (size, labels[i].toPlainText())
            # at its own point: over it or under it by a few pixels, the point within its width
            value = labels[i].toPlainText().splitlines()[-1]
            (step,) = [s for s, (_, error) in enumerate(steps) if f"{error:.3g}" == value]
            point = box.mapViewToScene(QPointF(step, np.log10(steps[step][1])))
            assert rect.left() <= point.x() <= rect.right()
            assert min(abs(rect.bottom() - point.y()), abs(rect.top() - point.y())) <= 8
            assert labels[i].toolTip().startswith(f"step {step}: {steps[step][0]}")


def analysed_window(qtbot, session, model) -> MainWindow:
    """The window on ``session`` with ``model`` loaded and Analyze pressed and done."""
    window = window_on(qtbot, session, model)
    with qtbot.waitSignal(window.lab.analysisUpdated, timeout=120000):
        window.model.analyze_button.click()
    return window


@pytest.mark.slow
def test_stop_during_discovery_keeps_the_steps_taken_and_says_what_was_not_tried(qtbot, hidden_effect_session):
    window = analysed_window(qtbot, *hidden_effect_session)
    panel = window.model
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


@pytest.mark.slow
def test_stop_inside_discovery_ends_it_there_and_the_model_stays_as_it_was(qtbot, hidden_effect_session):
    window = analysed_window(qtbot, *hidden_effect_session)
    panel = window.model
    before = window.lab.analysis.history
    lines = []

    def on_line(line: str) -> None:                 # Stop as discovery reports its first element's sets
        if line.startswith("discovery:") and not lines:
            panel.stop_button.click()
        lines.append(line)
    window.lab.autoProgress.connect(on_line)
    with qtbot.waitSignal(window.lab.analysisUpdated, timeout=300000):
        panel.auto_button.click()
    view = window.lab.analysis
    # heard inside discovery: nothing more was reported, no step taken, the model as analysed
    assert len(lines) == 1 and [h.error for h in view.history] == [h.error for h in before]
    assert all(not el.laws for el in view.elements if el.name in {"left", "right"})
    assert view.auto[-1] == ("stopped by the user: no step was taken: the model is as it was; discovery, under way, "
                             "was undone; not tried: the laws discovery would have found, the linear corrections "
                             "and the ranking of the missing effects")
