"""Report plots: log axes labelled at the decades only, in engineering notation, and every plot written."""
import numpy as np
import pytest

from analysis.mechanics.model import load_model
from analysis.loop.workbench import Workbench
from types import SimpleNamespace

from analysis.common.measurements import Control
from analysis.missing.diagnosis import ElementSamples
from analysis.common.wording import engineering
from app.kbar_view import FLAT_VIEW, level_colours, model_paths
from app.report import (_label_anchor, _labelled_log_ticks, _log_axis, _log_range_with_ticks, kbar_layout,
                        qt_application, write_report)
from test_workbench import PAPER_LAWS, model_doc, synthesise


@pytest.mark.parametrize("value, unit, text", [
    (2e-5, "m", "20 µm"), (1e-3, "m/N", "1 mm/N"), (1e7, "N/m", "10 MN/m"), (100e-6, "rad", "100 µrad"),
    (0.01, "", "0.01"), (1e-6, "", "10⁻⁶"), (3e5, "", "3·10⁵"), (1.0, "N", "1 N"), (-2.5e3, "N/m", "-2.5 kN/m")])
def test_engineering_notation(value, unit, text):
    assert engineering(value, unit) == text


def test_decades_only_when_the_view_holds_two_or_more():
    assert _labelled_log_ticks(-7.3, -4.6) == [-7.0, -6.0, -5.0]
    # within one decade: 1-2-5 steps; within a factor of 2: round values, never fewer than two labels
    assert np.allclose(10 ** np.array(_labelled_log_ticks(np.log10(0.15), np.log10(0.9))), [0.2, 0.5])
    close = 10 ** np.array(_labelled_log_ticks(np.log10(1.2), np.log10(1.23)))
    assert len(close) >= 2 and np.all((close >= 1.2 - 1e-12) & (close <= 1.23 + 1e-12))


def test_log_axis_labels_decades_and_leaves_minor_ticks_blank():
    qt_application()
    axis = _log_axis("bottom", "m")
    (major_spacing, major), (minor_spacing, minor) = axis.tickValues(-7.3, -4.6, 600)  # 50 nm .. 25 µm
    assert axis.tickStrings(major, 1.0, major_spacing) == ["100 nm", "1 µm", "10 µm"]
    assert len(minor) == 4 + 8 + 8 + 1 and set(axis.tickStrings(minor, 1.0, minor_spacing)) == {""}


@pytest.mark.slow
def test_write_report_draws_every_plot(tmp_path):
    wb = Workbench(load_model(model_doc({"left": PAPER_LAWS["left"], "right": [{"law": "cubic"}]})),
                   synthesise(PAPER_LAWS, lines=17))
    wb.start()
    wb.add("right", "coulomb")
    paths = write_report(wb, tmp_path)
    assert [p.name for p in paths] == ["frf.png", "kbar.png", "residuals.png", "error_history.png"]
    from PySide6.QtGui import QImage
    for p in paths:
        image = QImage(str(p))
        assert image.width() == 1400 and image.height() in (600, 900)


@pytest.mark.slow
def test_ctrl_c_while_a_plot_is_drawn_acts_once_its_png_is_written(tmp_path, monkeypatch, ctrl_c):
    """Qt calls the plot items' Python overrides from its own frames: a KeyboardInterrupt raised there crashed the
    process. A signal acts once the plot in hand is written; the plots after it are not drawn."""
    import signal

    import app.report as report

    wb = Workbench(load_model(model_doc({"left": PAPER_LAWS["left"], "right": [{"law": "cubic"}]})),
                   synthesise(PAPER_LAWS, lines=17))
    wb.start()
    legend_column = report.legend_column

    def ctrl_c_in_the_legend(*args, **kwargs):
        signal.raise_signal(signal.SIGINT)
        return legend_column(*args, **kwargs)

    monkeypatch.setattr(report, "legend_column", ctrl_c_in_the_legend)
    with pytest.raises(KeyboardInterrupt):
        write_report(wb, tmp_path)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["frf.png"]


# --- the kbar plot's rules (docs/workbench.md, "kbar plots") ---------------------------------------------------
TWO_ELEMENTS = {"structure": {"type": "lumped", "dofs": ["x1", "x2"], "mass": [[1.0, 0.0], [0.0, 2.0]],
                              "stiffness": [[200.0, -100.0], [-100.0, 200.0]]},
                "element": [{"name": "flat", "dof": "x1", "laws": [{"law": "linear", "k": -9.6e6, "c": -99.0}]},
                            {"name": "soft", "dof": "x2", "laws": [{"law": "cubic", "k3": -2e5}]}]}


def _sweep(level_count=2, lines=40):
    """Samples as a sweep gives them: each level's amplitude rises to the resonance and falls after it, so one
    amplitude occurs at two frequencies (a law depending on w is not a function of X alone)."""
    w = np.tile(np.linspace(300.0, 360.0, lines), level_count)
    level = np.repeat([0.1 * 4**i for i in range(level_count)], lines)
    X = level * 1e-4 / (1 + ((w - 330.0) / 8.0) ** 2) ** 0.5
    return X, w, level


def _kbar_workbench():
    model = load_model(TWO_ELEMENTS)
    X, w, level = _sweep()
    rng = np.random.default_rng(1)
    reports = {}
    for el, linear in zip(model.elements, (True, False)):
        kbar = el.describing_function(X, w) * (1 + 2e-5 * rng.standard_normal(len(X)))
        samples = ElementSamples(el.name, X, w, kbar, None, level)
        reports[el.name] = SimpleNamespace(samples=samples, verdict=SimpleNamespace(linear=linear))
    # the 0.4 N level held the force; the other held 20 m/s^2 at x1, its median force 0.1 N
    runs = [SimpleNamespace(name="held", force=0.1, control=Control("response", "x1", "acceleration", 20.0)),
            SimpleNamespace(name="forced", force=0.4, control=Control("force", "x1", "force", 0.4))]
    return SimpleNamespace(model=model, reports=reports, measurements=SimpleNamespace(sine=runs))


def _panels(layout):
    import pyqtgraph as pg
    return [item for item in layout.ci.items if isinstance(item, pg.PlotItem)]


def _curves(plot):
    return [item for item in plot.listDataItems()]


def test_kbar_plot_draws_the_measured_points_above_the_fitted_laws_and_one_legend_beside_them():
    import pyqtgraph as pg

    qt_application()
    layout = kbar_layout(_kbar_workbench())           # kept: the plots live as long as their layout
    panels = _panels(layout)
    assert len(panels) == 4
    for plot in panels:
        dots = [c for c in _curves(plot) if c.opts["symbol"] is not None]
        lines = [c for c in _curves(plot) if c.opts["symbol"] is None]
        assert dots and lines
        assert min(d.zValue() for d in dots) > max(line.zValue() for line in lines)
        assert all(line.opts["pen"] is not None for line in lines)        # the model is a line, not crosses
        assert plot.legend is None                                        # nothing over the data
        # circles where the force was held, squares where a response was, in the level's colour
        assert {d.opts["symbol"] for d in dots} == {"o", "s"}
    (legend,) = [item for item in layout.ci.items if isinstance(item, pg.LegendItem)]
    # in level order (force levels first) and named by how each was held, not by the held level's median force
    assert [label.text for _, label in legend.items] == ["0.4 N identified", "20 m/s^2 at x1 identified",
                                                         "fitted laws"]
    assert [sample.item.opts["symbol"] for sample, _ in legend.items][:2] == ["o", "s"]
    assert layout.ci.layout.itemAt(1, 2) is legend                        # a column of its own, right of the plots


def _cie_lab(rgb):
    c = np.asarray(rgb, float) / 255
    c = np.where(c > 0.04045, ((c + 0.055) / 1.055) ** 2.4, c / 12.92)
    xyz = c @ np.array([[0.4124, 0.3576, 0.1805], [0.2126, 0.7152, 0.0722], [0.0193, 0.1192, 0.9505]]).T
    f = np.cbrt(xyz / [0.95047, 1.0, 1.08883])        # every level colour is far above the linear toe
    return np.stack([116 * f[..., 1] - 16, 500 * (f[..., 0] - f[..., 1]), 200 * (f[..., 1] - f[..., 2])], -1)


@pytest.mark.parametrize("n, apart", [(2, 50), (4, 40), (12, 15), (30, 4)])
def test_level_colours_stay_apart_for_many_levels_and_read_on_white(n, apart):
    lab = _cie_lab(level_colours(n))
    distance = np.linalg.norm(lab[:, None] - lab[None], axis=-1)
    np.fill_diagonal(distance, np.inf)
    assert distance.min() > apart                    # CIE76 dE: 2.3 is just noticeable
    assert lab[:, 0].max() < 65                      # no pale yellow or green on the white background


def test_kbar_plot_draws_a_linear_element_on_an_axis_that_shows_it_flat():
    qt_application()
    wb = _kbar_workbench()
    layout = kbar_layout(wb)
    re_flat = layout.getItem(1, 0)                      # Re kbar of the linear element
    low, high = re_flat.viewRange()[1]
    mean = -9.6e6
    assert high - low >= 2 * FLAT_VIEW * abs(mean) * 0.999 and low < mean < high
    assert "samples within" in re_flat.titleLabel.text
    # the nonlinear element keeps the axis its data span
    assert layout.getItem(1, 1).vb.autoRangeEnabled()[1] and not re_flat.vb.autoRangeEnabled()[1]


def test_model_paths_follow_each_level_in_frequency_order():
    X, w, level = _sweep()
    model = -99.0j * w                                  # a linear law's Im kbar = c w: not single-valued in X
    paths = model_paths(X, w, level, model)
    assert [p.level for p in paths] == [0.1, 0.4]
    for p in paths:
        assert np.all(np.diff(-p.kbar.imag / 99.0) > 0)   # along w, never jumping between the two sides
        assert len(p.X) == 40


def test_log_axis_reaches_a_labelled_number_below_the_lowest_point():
    for values in ([1.23, 1.24, 0.0222], [0.0013, 0.05], [0.02224], [0.5, 0.9]):
        low, high = _log_range_with_ticks(np.array(values))
        assert min(_labelled_log_ticks(low, high)) <= np.log10(min(values))
        assert high >= np.log10(max(values))
    # a history's lowest point just above a labelled number: the axis goes on below it, for the label under it
    low, high = _log_range_with_ticks(np.array([1.23, 1.2, 0.0102]), headroom=0.12, footroom=0.12)
    assert low <= np.log10(0.0102) - 0.12 * (np.log10(1.23) - np.log10(0.0102))
    assert min(_labelled_log_ticks(low, high)) <= low + 1e-9


def test_history_labels_sit_off_the_line():
    errors = np.array([1.23, 1.24, 0.0222, 0.03])
    assert _label_anchor(errors, 1)[1] > 1       # the highest: above
    assert _label_anchor(errors, 0)[1] < 0       # its neighbour is higher: below
    assert _label_anchor(errors, 2)[1] < 0       # the lowest: below
    assert _label_anchor(errors, 3)[1] > 1       # the last, above its neighbour


def test_model_paths_break_where_the_amplitude_jumps():
    # an up-sweep over a fold: the amplitude grows to 0.12 and drops to 0.04 between two neighbouring lines
    w = np.linspace(1.0, 2.0, 6)
    X = np.array([0.05, 0.08, 0.12, 0.04, 0.03, 0.02])     # steps of x1.6 on the flank are still a path
    (path,) = model_paths(X, w, np.full(6, 0.8), 1.0 + 0j * X)
    assert np.isnan(path.X[3]) and np.isnan(path.kbar[3].real)         # no segment from 0.12 to 0.04
    assert np.count_nonzero(np.isnan(path.X)) == 1 and list(path.X[:3]) == [0.05, 0.08, 0.12]
    assert list(path.X[4:]) == [0.04, 0.03, 0.02]


# --- many levels: 2, 4, 12 and 30 (docs/gui.md, "Levels") -----------------------------------------------------------
def _many_levels(count):
    """``count`` levels of paper-2dof's kind synthesised by harmonic balance: two thirds held at a force, the rest
    named as held at an acceleration of x2 (how a level was held is all the plots read of it)."""
    from dataclasses import replace

    forces = np.geomspace(0.1, 1.6, count)
    data = synthesise(PAPER_LAWS, forces=tuple(forces), lines=13)
    held = count // 3
    runs = [run if i < count - held else
            replace(run, name=f"sine_x2_{5 * (i + 1)}mps2_up",
                    control=Control("response", "x2", "acceleration", 5.0 * (i + 1)))
            for i, run in enumerate(data.sine)]
    return replace(data, sine=runs)


def _legend(layout):
    import pyqtgraph as pg
    (legend,) = [item for item in layout.ci.items if isinstance(item, pg.LegendItem)]
    return legend


@pytest.mark.slow
@pytest.mark.parametrize("count", [2, 4, 12, 30])
def test_many_levels_make_small_multiples_of_neighbours_each_told_apart_and_the_legends_fit(count):
    from app.kbar_view import LEGEND_ROWS, PANEL_LEVELS, level_panels, ordered_levels
    from app.report import frf_layout

    wb = Workbench(load_model(model_doc(PAPER_LAWS)), _many_levels(count), harmonics=None)
    wb.start()
    runs = wb.measurements.sine
    qt_application()
    layout = frf_layout(wb.compare(), runs, "x2")
    panels = level_panels(r.control for r in runs)
    # one plot while it holds them, else small multiples: force and response levels apart, neighbours together
    assert len(panels) == {2: 1, 4: 1, 12: 1, 30: 3}[count]                  # 20 force levels, 10 response
    if count > PANEL_LEVELS:
        assert all(len(p) <= PANEL_LEVELS and len({c.mode for c in p}) == 1 for p in panels)
    plots = _panels(layout)
    assert len(plots) == 2 * len(panels)
    for panel, (mag, phase) in zip(panels, zip(plots[::2], plots[1::2])):
        brushes = [c.opts["symbolBrush"] for c in _curves(mag) if c.opts["symbol"] is not None]
        assert len(brushes) == len(panel) == len(set(map(str, brushes)))        # a colour per level in its panel
        if len(panels) > 1:
            assert panel[0].label().split(" ", 1)[0] in mag.titleLabel.text
    # the legend names every level by how it was held, in order, in columns of at most LEGEND_ROWS
    legend = _legend(layout)
    names = [label.text for _, label in legend.items]
    assert names == [f"{c.label()} up" for c in ordered_levels(r.control for r in runs)]
    assert legend.layout.rowCount() <= LEGEND_ROWS
    layout.resize(1400, 900)
    layout.show()
    qt_application().processEvents()
    assert layout.sceneRect().contains(legend.sceneBoundingRect())
    layout.close()
