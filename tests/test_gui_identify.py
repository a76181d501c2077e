"""The Identify tab draws kbar by the plot rules of kbar.png: the identified dots above the fitted laws' line per
level, one legend beside the plots in level order, an element judged linear on an axis that shows it flat."""
from PySide6.QtCore import QObject, Signal

from app.gui.identify_panel import IdentifyPanel
from app.gui.plots import FrameClock, LevelPalette
from app.gui.results import ElementView, IdentificationView
from app.kbar_view import FLAT_VIEW
from test_report import _kbar_workbench


class _Lab(QObject):
    identificationUpdated = Signal(object)
    modelChanged = Signal()
    sessionChanged = Signal()
    model = None


def _view(fitted: bool) -> IdentificationView:
    wb = _kbar_workbench()
    elements = []
    for el in wb.model.elements:
        r = wb.reports[el.name]
        s = r.samples
        elements.append(ElementView(el.name, el.dofs[0], s, r.verdict.linear, "", len(s.X), 0,
                                    model=el.describing_function(s.X, s.w) if fitted else None))
    return IdentificationView(elements, 80, False, wb.measurements.sine)


def _panel(qtbot, view):
    panel = IdentifyPanel(_Lab(), FrameClock(), LevelPalette())
    qtbot.addWidget(panel)
    panel._update(view)
    panel.redraw.now()
    return panel


def test_identify_tab_draws_dots_above_the_fitted_laws_with_one_legend_beside_the_plots(qtbot):
    panel = _panel(qtbot, _view(fitted=True))
    plots = panel.plots()
    assert len(plots) == 4
    for name, plot in plots.items():
        items = plot.listDataItems()
        dots = [c for c in items if c.opts["symbol"] is not None and len(c.xData)]
        lines = [c for c in items if c.opts["symbol"] is None and len(c.xData)]
        assert len(dots) == 2 and len(lines) == 2, name
        assert min(d.zValue() for d in dots) > max(line.zValue() for line in lines), name
        assert plot.legend is None, name                          # nothing over the data
        assert sorted(d.opts["symbol"] for d in dots) == ["o", "s"], name   # force held, response held
    # level order, each named by how it was held: the response level is not "0.1 N" (its median force)
    assert panel.legend_names() == ["0.4 N identified", "20 m/s^2 at x1 identified", "fitted laws"]
    assert panel.graphics.ci.layout.itemAt(0, 2) is panel.legend
    assert panel.status.text().endswith("levels 0.4 N, 20 m/s^2 at x1")


def test_identify_tab_colours_the_levels_as_the_report_does(qtbot):
    from app.kbar_view import level_colours

    panel = _panel(qtbot, _view(fitted=False))
    dots = {d.opts["symbol"]: d.opts["symbolBrush"].color().name() for d in panel.plots()["kbar_re_soft"]
            .listDataItems() if len(d.xData)}
    assert [dots["o"], dots["s"]] == ["#%02x%02x%02x" % c for c in level_colours(2)]


def test_identify_tab_before_fitting_names_no_fitted_laws(qtbot):
    panel = _panel(qtbot, _view(fitted=False))
    assert "fitted laws" not in panel.legend_names() and len(panel.legend_names()) == 2


def test_identify_tab_shows_a_linear_element_flat(qtbot):
    panel = _panel(qtbot, _view(fitted=True))
    flat = panel.plots()["kbar_re_flat"]
    low, high = flat.viewRange()[1]
    assert high - low >= 2 * FLAT_VIEW * 9.6e6 * 0.999 and "linear: samples within" in flat.titleLabel.text
    assert panel.plots()["kbar_re_soft"].vb.autoRangeEnabled()[1]


def test_identify_legend_stands_beside_the_kbar_plots_with_each_marker_level_with_its_words(qtbot):
    """The kbar legend sat over the data, its markers half a row below their labels: now in a column of its own
    right of the plots (over none of them), each marker at the height of its words."""
    panel = _panel(qtbot, _view(fitted=True))
    panel.resize(1100, 700)
    panel.show()
    qtbot.wait(100)
    legend = panel.legend
    area = legend.sceneBoundingRect()
    for name, plot in panel.plots().items():
        assert not area.intersects(plot.vb.sceneBoundingRect()), name
        assert area.left() >= plot.vb.sceneBoundingRect().right(), name
    assert len(legend.items) == 3
    for sample, label in legend.items:
        marker = sample.sceneBoundingRect().center().y()
        words = label.item.sceneBoundingRect().center().y()
        assert abs(marker - words) <= 2, (label.text, marker, words)


def test_identify_tab_says_which_yardstick_judged_each_element(qtbot):
    """Under each element's evidence, the yardstick its verdict, outliers and intervals were judged by, in the
    words of the text report (docs/fitting.md, "The yardstick")."""
    from dataclasses import replace

    from analysis.identification.between_runs import BetweenRuns

    view = _view(fitted=False)
    judged = [BetweenRuns(0.0, 2.0, 0, 0, 1.0, False), BetweenRuns(430.0, 13.0, 64, 64, 5e-20, True, 0.16)]
    view = IdentificationView([replace(e, yardstick=j.text()) for e, j in zip(view.elements, judged)], 80, False,
                              view.runs)
    shown = _panel(qtbot, view).verdicts.toPlainText()
    assert "Yardstick: the line noise (2 N/m); the scatter between runs is not measurable" in shown
    assert "Yardstick: the scatter between runs, 430 N/m (Re 394.1, Im 172; 33x the line noise of 13 N/m" in shown
