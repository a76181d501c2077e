"""Nothing from before: after another session (opened or imported), another model or another step, every view
shows the state now -- no analysis of the session before, no old error in the status bar, no "no laws" beside
fitted laws, no sample that moved without a word -- and what the operator entered or aims at stays where it was
(a refused import's dialog, the Auto and Stop buttons while the loop reports)."""
from dataclasses import replace
from types import SimpleNamespace

import numpy as np
import pytest
from PySide6.QtCore import QPoint

from analysis.common.errors import InputError
from app.gui.main_window import MainWindow
from analysis.prediction.backbone import Backbone, ModalPoint
from app.gui.results import BackboneView, ElementView, LawView, PredictionView, kbar_basis
from drivers.simulation.rig import load_rig
from test_gui_identify import _view as identification
from test_gui_import import controller_file
from test_gui_model import _twelve_level_view


@pytest.fixture
def window(qtbot):
    w = MainWindow("test")
    qtbot.addWidget(w)
    return w


def finished_session(path):
    """A closed session with one complete stepped-sine run."""
    from app.session.writer import RunSpec, SessionWriter
    w = SessionWriter(path, software_version="test")
    w.begin_run(RunSpec("sine_0.8N_up", "stepped_sine", 0.8, "up", "x2", ["x1", "x2"], 100.0,
                        ["force", "acc:x1", "acc:x2"], ["N", "m/s^2", "m/s^2"], {"force_amplitude": ("N", (), "f8")}))
    for i, fi in enumerate(np.linspace(1.0, 2.0, 11)):
        w.append_line(fi, {"x1": 1e-3 / (1 + 1j * i), "x2": 2e-3 / (1 - 1j * i)}, {"force_amplitude": 0.8})
    w.end_run("complete")
    w.close()
    return str(path)


def analysed(window):
    """The window as after an Analyze: an analysis on the Model tab, its identification on the Identify tab."""
    _, view = _twelve_level_view()
    window.lab._analysis_done(view, window.lab._generation)
    window.lab._show_identification(identification(fitted=True))
    window.identify.redraw.now()
    return view


def drawn(plot) -> int:
    xs = [c.getOriginalDataset()[0] for c in plot.listDataItems()]
    return sum(0 if x is None else len(x) for x in xs)


@pytest.mark.slow
def test_an_import_drops_the_results_of_the_session_before(window, qtbot, tmp_path):
    window.lab.open_session(finished_session(tmp_path / "before.h5"))
    analysed(window)
    assert drawn(window.model.frf) > 0
    assert window.identify.plots() and window.model.error_label.text().startswith("FRF error 0.98")
    window.lab._show_backbone(BackboneView([Backbone("x1", "acceleration", [ModalPoint(5.0, 80.3, 0.0015)],
                                                     "measured", "single-mode fit per response level", ("r",))]))
    assert drawn(window.backbone.frequency) == 1

    dialog = window.import_dialog()
    dialog.add_files([controller_file(tmp_path / "low.uff")])
    dialog.files.item(0, 1).setText("0.2")
    dialog.dof_map.setPlainText("1+Z=x1\n2+Z=x2")
    with qtbot.waitSignal(window.lab.sessionChanged, timeout=30000):
        dialog._accept()
    assert window.lab.session_path == str(tmp_path / "low.h5")
    assert window.lab.analysis is None and window.model.view is None
    assert window.model.error_label.text() == "FRF error: — (press Analyze)"
    assert window.model.level_errors.text() == "" and window.model.legend_names() == []
    assert all(drawn(plot) == 0 for plot in window.model.plots().values())
    assert not window.model.auto_button.isEnabled() and not window.model.save_button.isEnabled()
    # the Identify tab waits for the new session's identification, the old dots gone
    assert window.identify.view is None and window.identify.plots() == {}
    assert "0.4 N" not in window.identify.status.text()
    # the Backbone tab too: the new session's curves (it holds no response level), none of the old one's
    qtbot.waitUntil(lambda: window.lab.backbone is not None, timeout=30000)
    assert drawn(window.backbone.frequency) == 0 and window.backbone.status.text().startswith(
        "This session holds no response-controlled level")


@pytest.mark.slow
def test_an_old_error_leaves_the_status_bar_when_an_analysis_goes_through(window):
    window.show_error("open a session first")
    assert window.statusBar().currentMessage() == "open a session first"
    view = analysed(window)
    assert window.statusBar().currentMessage() == f"analysed: FRF error {view.error:.4g}"


@pytest.mark.slow
def test_a_refused_import_reopens_as_the_operator_left_it(window, qtbot, tmp_path):
    files = [controller_file(tmp_path / "low.uff"), controller_file(tmp_path / "high.uff")]
    dialog = window.import_dialog()
    dialog.add_files(files)
    dialog.dof_map.setPlainText("1+Z=x1\n2+Z=x2")
    dialog.excitation.setText("x2")
    with qtbot.waitSignal(window.lab.error, timeout=30000) as refused:      # no force level: refused
        dialog._accept()
    again = window.import_dialog()
    assert again.isVisible()
    assert [again.files.item(r, 0).text() for r in range(again.files.rowCount())] == files
    assert again.dof_map.toPlainText() == "1+Z=x1\n2+Z=x2" and again.excitation.text() == "x2"
    assert again.message.text() == refused.args[0]            # and why it was refused, beside what to correct
    again.files.item(0, 1).setText("0.2")
    again.files.item(1, 1).setText("0.8")
    with qtbot.waitSignal(window.lab.sessionChanged, timeout=30000):
        again._accept()
    assert window.import_dialog().files.rowCount() == 0       # an import that went through: the next starts empty


@pytest.mark.slow
def test_auto_and_stop_stay_where_they_are_while_the_loop_reports(window, qtbot):
    window.resize(1366, 768)
    window.show()
    qtbot.waitExposed(window)
    analysed(window)
    window.tabs.setCurrentWidget(window.model)
    panel = window.model
    panel._auto_running = True
    qtbot.wait(50)
    where = [b.mapTo(window, QPoint(0, 0)) for b in (panel.auto_button, panel.stop_button)]
    for i in range(20):
        window.lab.autoProgress.emit(f"add right:cubic+coulomb: error 0.{i:03d} -> 0.{i:03d} (x1.26 better, "
                                     "required x1.3; the backbone and the damping both call for it)")
    qtbot.wait(50)
    assert [b.mapTo(window, QPoint(0, 0)) for b in (panel.auto_button, panel.stop_button)] == where
    assert "error 0.019" in panel.auto_label.text()           # the newest line is there, scrolled into view
    bar = panel.auto_label.verticalScrollBar()
    assert bar.maximum() > 0 and bar.maximum() - bar.value() < panel.auto_label.fontMetrics().lineSpacing()


@pytest.mark.slow
def test_the_model_line_names_the_laws_the_tab_shows(window):
    window.lab.rig = load_rig("paper-2dof")
    window.lab.use_starter_model()
    assert "left: no laws; right: no laws" in window.model.model_label.text()
    _, view = _twelve_level_view()
    elements = [ElementView("left", "x1", None, False, "", 10, 0, (LawView("cubic", ()),)),
                ElementView("right", "x2", None, False, "", 10, 0, (LawView("cubic", ()), LawView("coulomb", ())))]
    window.lab._analysis_done(replace(view, elements=elements), window.lab._generation)
    text = window.model.model_label.text()
    assert "no laws" not in text and "as fitted here: left: cubic; right: cubic + coulomb" in text
    assert text.startswith("starter model for paper-2dof")


@pytest.mark.slow
def test_a_prediction_replaces_the_analysis_shown_before(window):
    analysed(window)
    assert window.model.history.listDataItems()
    levels, analysis = _twelve_level_view()
    runs = analysis.runs
    comparison = SimpleNamespace(predicted=analysis.predicted, residual_map=analysis.residual_map, other_branch={},
                                 compared={})
    prediction = SimpleNamespace(errors={"fitted": 0.5}, comparison=comparison,
                                 levels=[SimpleNamespace(control=c, kind="fitted") for c in levels])
    window.lab.predictionUpdated.emit(PredictionView("prediction table", prediction, runs))
    panel = window.model
    assert panel.error_label.text().startswith("Prediction, nothing refitted")
    assert panel.view is None and panel.candidates.rowCount() == 0 and not panel.history.listDataItems()
    assert not panel.undo_button.isEnabled() and not panel.auto_button.isEnabled()
    assert "prediction table" in panel.explanation.toPlainText()


def test_samples_that_moved_with_a_fit_say_so_and_why(window):
    before = identification(fitted=True)
    window.lab._show_identification(before)
    window.identify.redraw.now()
    assert "moved" not in window.identify.status.text()
    el = before.elements[1]
    moved = replace(el, samples=replace(el.samples, kbar=el.samples.kbar * 1.5))
    basis = "on data without harmonics, less the fitted laws' own fundamental bias"
    window.lab._show_identification(replace(before, elements=[before.elements[0], moved], basis=basis))
    window.identify.redraw.now()
    status = window.identify.status.text()
    assert f"kbar {basis}" in status
    i = int(np.argmax(np.abs(el.samples.kbar)))          # kbar x 1.5 moves most where |kbar| is largest
    k = el.samples.kbar[i]
    assert (f"the samples moved with this analysis (its fit, not the data): {el.name} by up to 50.0% of its "
            f"largest |kbar|, most at X = {el.samples.X[i]:.3g} m: Re kbar {k.real:.4g} -> {1.5 * k.real:.4g}, "
            f"Im kbar {k.imag:.4g} -> {1.5 * k.imag:.4g} N/m") in status


def test_the_basis_of_the_samples_is_said_where_an_analysis_moves_them():
    law = SimpleNamespace(complete=True)
    fitted = SimpleNamespace(laws=[law])

    def wb(blind, elements, update=None):
        return SimpleNamespace(reference=SimpleNamespace(update=update), harmonics_blind=blind,
                               model=SimpleNamespace(elements=elements))
    assert kbar_basis(wb(False, [fitted])) == ""                                   # the plain closed form
    assert kbar_basis(wb(True, [fitted, SimpleNamespace(laws=[])])) == ""          # not every element fitted
    assert "fundamental bias" in kbar_basis(wb(True, [fitted]))
    assert kbar_basis(wb(False, [fitted], update=object())) == \
        "relative to the structure updated from the random run"


def test_a_reference_needs_a_finished_session(window):
    with pytest.raises(InputError, match="open a session first"):
        window.lab.make_reference()
    assert not window.model.reference_button.isEnabled()
