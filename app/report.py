"""Report plots (PNG) of a workbench: FRFs measured against predicted, kbar against amplitude, the residual
per line, and the error history. Drawn with pyqtgraph off screen, so they work on a machine without a display.

Log axes are labelled at the decades only, in engineering notation with the unit on every label (docs/workbench.md):
pyqtgraph's own log axis labels every minor tick and prefixes the unit once for the whole axis, which crowds the
labels into each other and reads badly.
"""
from __future__ import annotations

import os
from pathlib import Path
from typing import Sequence

import numpy as np

from analysis.common.held_signals import signals_held
from analysis.common.measurements import SineRun
from analysis.prediction.backbone import BackboneComparison
from analysis.prediction.comparison import Comparison
from analysis.common.wording import engineering
from analysis.loop.workbench import Workbench

from app.analyze import backbones, comparisons_error, element_misfits
from app.kbar_view import (level_colours, level_masks, level_panels, level_style, legend_column, linear_axis,
                           model_paths, ordered_levels, panel_title)


def qt_application():
    """The QApplication, created off screen when there is no display."""
    if not os.environ.get("DISPLAY") and not os.environ.get("WAYLAND_DISPLAY"):
        os.environ.setdefault("QT_QPA_PLATFORM", "offscreen")
    from PySide6.QtWidgets import QApplication

    return QApplication.instance() or QApplication([])


class _Levels:
    """The levels of some runs in :meth:`Control.order`, each with its colour (app/kbar_view.py: the GUI's too)."""

    def __init__(self, runs: Sequence[SineRun]):
        self.controls = ordered_levels(r.control for r in runs)
        self._colours = {c.key(): colour for c, colour in zip(self.controls, level_colours(len(self.controls)))}

    def colour(self, run_or_control):
        control = getattr(run_or_control, "control", run_or_control)
        return self._colours[control.key()]


def _in_level_order(runs: Sequence[SineRun]) -> list[SineRun]:
    """Runs as legends list them: by level (:meth:`Control.order`), up before down."""
    return sorted(runs, key=lambda r: (r.control.order(), r.direction != "up", r.name))


def _symbols(colour, size: int) -> dict:
    """Plot style of measured points: filled circles of ``size`` px, no line."""
    return {"pen": None, "symbol": "o", "symbolSize": size, "symbolBrush": colour, "symbolPen": None}


def _line(colour, width: float = 2) -> dict:
    return {"pen": {"color": colour, "width": width}}


def _export(layout, path: Path, width: int = 1400, height: int = 900) -> Path:
    """The layout as a PNG at ``path``, replaced all at once (:func:`write_report` checks for old files)."""
    import pyqtgraph.exporters

    from app.session.outputs import atomic_output

    layout.resize(width, height)
    layout.show()                       # off screen: lays the plots out at the export size
    qt_application().processEvents()
    layout.grab()                       # a first paint sizes the axes to their tick labels ...
    qt_application().processEvents()    # ... and the layout follows before the picture is taken
    exporter = pyqtgraph.exporters.ImageExporter(layout.scene())
    exporter.parameters()["width"] = width
    with atomic_output(path, overwrite=True, field=None, keep_suffix=True) as temp:
        exporter.export(str(temp))
    layout.close()
    return path


def _labelled_log_ticks(low: float, high: float) -> list[float]:
    """log10 of the labelled ticks between ``low`` and ``high`` (log10 values): the decades; when the view holds
    fewer than two, 1-2-5 times the decades; when it holds fewer than two of those either (a range within a
    factor of about 2), evenly spaced round values -- a log axis must never carry fewer than two numbers."""
    decades = np.arange(np.ceil(low - 1e-9), np.floor(high + 1e-9) + 1)
    if len(decades) >= 2:
        return decades.tolist()
    steps = np.log10([1.0, 2.0, 5.0])
    one_two_five = (np.arange(np.floor(low), np.ceil(high) + 1)[:, None] + steps).ravel()
    one_two_five = one_two_five[(one_two_five >= low - 1e-9) & (one_two_five <= high + 1e-9)]
    if len(one_two_five) >= 2:
        return one_two_five.tolist()
    lo, hi = 10.0**low, 10.0**high
    step = _round_step((hi - lo) / 4)
    values = np.arange(np.ceil(lo / step) * step, hi + 1e-9 * step, step)
    return np.log10(values[values > 0]).tolist()


def _round_step(span: float) -> float:
    """The 1-2-5 multiple of a power of ten nearest above ``span``."""
    decade = 10.0 ** np.floor(np.log10(span))
    return next(m * decade for m in (1.0, 2.0, 5.0, 10.0) if m * decade >= span * (1 - 1e-9))


def _log_axis(orientation: str, unit: str):
    """A log-scale axis labelled at the decades only, each label in engineering notation with its unit; the
    other integers times a decade get unlabelled minor ticks."""
    import pyqtgraph as pg

    class LogAxis(pg.AxisItem):
        def tickValues(self, minVal, maxVal, size):
            low, high = sorted((minVal, maxVal))
            labelled = _labelled_log_ticks(low, high)
            minor = [v for d in range(int(np.floor(low)), int(np.ceil(high)) + 1)
                     for v in d + np.log10(np.arange(2, 10))
                     if low <= v <= high and not np.isclose(labelled, v).any()]
            return [(1.0, labelled), (None, minor)]

        def tickStrings(self, values, scale, spacing):
            if spacing is None:
                return ["" for _ in values]
            return [engineering(10.0**v, unit) for v in values]

    axis = LogAxis(orientation)
    axis.enableAutoSIPrefix(False)
    return axis


def _log_plot(lay, row: int, col: int, title: str | None = None, x_unit: str | None = None,
              y_unit: str | None = None):
    """A plot whose x (when ``x_unit`` is given) and y (when ``y_unit`` is given) axes are logarithmic with
    readable decade labels; "" is a dimensionless axis."""
    axes = {}
    if x_unit is not None:
        axes["bottom"] = _log_axis("bottom", x_unit)
    if y_unit is not None:
        axes["left"] = _log_axis("left", y_unit)
    plot = lay.addPlot(row=row, col=col, title=title, axisItems=axes)
    plot.setLogMode(x=x_unit is not None, y=y_unit is not None)
    return plot


def _layout():
    import pyqtgraph as pg

    qt_application()
    pg.setConfigOptions(antialias=True, background="w", foreground="k")
    return pg.GraphicsLayoutWidget()


PANEL_COLUMNS = 4      # small multiples side by side in a report PNG before they take another row


def plot_frfs(comp: Comparison, runs: Sequence[SineRun], path: Path, sensor: str | None = None,
              tags: dict[str, str] | None = None) -> Path:
    """|h| and phase of one sensor per level: measured (markers: circles where the force was held, squares where
    a response was) and predicted (lines), the legend beside the plots in level order; ``tags`` (run name ->
    words) are added to a run's legend entry (a prediction marks its held-out levels so). More levels than one
    plot holds are drawn as small multiples (app/kbar_view.py, :func:`level_panels`): a column of |h| over phase
    per panel, PANEL_COLUMNS to a row, frequency axes linked, each titled by the levels it holds."""
    lay = frf_layout(comp, runs, sensor, tags)
    rows = 2 * (-(-len(level_panels(r.control for r in runs)) // PANEL_COLUMNS))
    return _export(lay, path, height=900 if rows <= 2 else 450 * rows + 50)


def frf_layout(comp: Comparison, runs: Sequence[SineRun], sensor: str | None = None,
               tags: dict[str, str] | None = None):
    """The plots of :func:`plot_frfs`, laid out."""
    levels = _Levels(runs)
    sensor = sensor or runs[0].sensor_dofs[0]
    panels = level_panels(r.control for r in runs)
    lay = _layout()
    heading = (f"Receptance {sensor} / {runs[0].excitation_dof} at each level: measured (markers) and model "
               f"prediction (lines); FRF error {comp.error:.3g}")
    columns = min(len(panels), PANEL_COLUMNS)
    top = 0
    if len(panels) > 1:
        lay.addLabel(heading, row=0, col=0, colspan=columns, size="11pt")
        top = 1
    entries, first = [], None
    for k, panel in enumerate(panels):
        row, col = top + 2 * (k // PANEL_COLUMNS), k % PANEL_COLUMNS
        keys = {c.key() for c in panel}
        mag = _log_plot(lay, row, col, title=heading if len(panels) == 1 else panel_title(panel), y_unit="m/N")
        ph = lay.addPlot(row=row + 1, col=col)
        if col == 0:
            mag.setLabel("left", "|h|")
            ph.setLabel("left", "phase", units="deg")
        ph.setLabel("bottom", "frequency", units="Hz")
        ph.setXLink(mag)
        # the frequency axes linked; each panel's |h| and phase fitted to its own levels (a linked range follows
        # the first panel's data alone and would cut the others')
        if first is None:
            first = mag
        else:
            mag.setXLink(first)
        for run in _in_level_order([r for r in runs if r.control.key() in keys]):
            p = run.sensor_dofs.index(sensor)
            order = np.argsort(run.frequency_hz)
            f = run.frequency_hz[order]
            meas = run.receptance[order, p]
            pred = comp.predicted[run.name][order, p]
            c = levels.colour(run)
            measured, model = level_style(run.control, c, 5), _line(c)
            mag.plot(f, np.abs(meas), **measured)
            mag.plot(f, np.abs(pred), **model)
            ph.plot(f, np.degrees(np.angle(meas)), **measured)
            ph.plot(f, np.degrees(np.angle(pred)), **model)
            entries.append(({**measured, **model}, _run_name(run, tags)))
    legend_column(lay.ci, entries, row=top, col=columns, rowspan=2 * (-(-len(panels) // PANEL_COLUMNS)))
    return lay


def _run_name(run: SineRun, tags: dict[str, str] | None) -> str:
    tag = (tags or {}).get(run.name)
    return f"{run.control.label()} {run.direction}" + (f" ({tag})" if tag else "")


def plot_kbar(wb: Workbench, path: Path) -> Path:
    """Re and Im of every element's kbar against its amplitude (:func:`kbar_layout`) as a PNG."""
    return _export(kbar_layout(wb), path)


def kbar_layout(wb: Workbench):
    """Re and Im of every element's kbar against its amplitude: the identified samples as markers coloured by
    level, drawn above the fitted laws, which are a black line per level through the same lines in frequency
    order (app/kbar_view.py); one legend beside the plots, in level order. An element judged linear is drawn on
    an axis that shows how flat it is."""
    runs = wb.measurements.sine
    levels = _Levels(runs)
    lay = _layout()
    lay.addLabel("Equivalent complex stiffness kbar of each element against its amplitude X: identified (markers, "
                 "one colour per level: circles force held, squares response held)<br>and the fitted laws (black "
                 "line per level, in frequency order)", row=0, col=0, colspan=max(len(wb.model.elements), 1) + 1,
                 size="11pt")
    any_fitted = False
    for col, el in enumerate(wb.model.elements):
        rep = wb.reports.get(el.name)
        s = rep.samples if rep else None
        k_u, x_u = s.units if s is not None else ("N/m", "m")
        linear = rep is not None and rep.verdict is not None and rep.verdict.linear
        verdict = "" if rep is None or rep.verdict is None else (": linear" if linear else ": nonlinear")
        misfits = {m.part: m for m in element_misfits(wb, el)}
        panels = {}
        for row, part, take in ((1, "Re", np.real), (2, "Im", np.imag)):
            plot = _log_plot(lay, row, col, x_unit=x_u)
            plot.setLabel("left", f"{part} kbar", units=k_u)
            panels[part] = (plot, take)
        panels["Im"][0].setLabel("bottom", "amplitude X")
        panels["Im"][0].setXLink(panels["Re"][0])
        if s is None:
            panels["Re"][0].setTitle(f"kbar of {el.name} at {' - '.join(el.dofs)}{verdict}: no samples")
            continue
        fitted = (el.laws or el.nonparametric is not None) and all(t.complete for t in el.laws)
        paths = model_paths(s.X, s.w, s.level, el.describing_function(s.X, s.w)) if fitted else []
        any_fitted = any_fitted or bool(paths)
        masks = level_masks(s.level, runs)
        for part, (plot, take) in panels.items():
            title = f"{part} kbar of {el.name} at {' - '.join(el.dofs)}{verdict}"
            for p in paths:      # under the dots: the measured points stay visible
                line = plot.plot(p.X, take(p.kbar), pen={"color": "k", "width": 1.5}, connect="finite")
                line.setZValue(0)
            for control, sel in masks:
                if sel.any():
                    dots = plot.plot(s.X[sel], take(s.kbar[sel]), **level_style(control, levels.colour(control), 5))
                    dots.setZValue(10)
            axis = linear_axis(take(s.kbar)) if linear else None
            if axis is not None:
                plot.setYRange(axis.low, axis.high, padding=0)
                title += f" ({axis.words()})"
            if part in misfits:
                m = misfits[part]
                title += (f"<br>systematic misfit: law {'above' if m.misfit < 0 else 'below'} the data at "
                          f"{engineering(m.X_range[0], x_u)}..{engineering(m.X_range[1], x_u)}")
            plot.setTitle(title, size="10pt")
    entries = [(level_style(c, levels.colour(c), 6), f"{c.label()} identified") for c in levels.controls]
    entries += [({"pen": {"color": "k", "width": 1.5}}, "fitted laws")] if any_fitted else []
    legend_column(lay.ci, entries, row=1, col=max(len(wb.model.elements), 1), rowspan=2)
    return lay


def plot_residuals(comp: Comparison, runs: Sequence[SineRun], path: Path,
                   tags: dict[str, str] | None = None) -> Path:
    """Relative FRF error per line and run, over every response the runs measured: where the model fails
    (``tags`` as in :func:`plot_frfs`; the legend beside the plot, in level order)."""
    levels = _Levels(runs)
    responses = ", ".join(dict.fromkeys(d for run in runs for d in run.sensor_dofs))
    lay = _layout()
    p = _log_plot(lay, 0, 0, title=f"Where the model fails: relative FRF error of the prediction at each frequency "
                                   f"line and level, over the responses {responses} "
                                   f"(force at {runs[0].excitation_dof})", y_unit="")
    p.setLabel("left", "relative FRF error")
    p.setLabel("bottom", "frequency", units="Hz")
    shown, entries = [], []
    for run in _in_level_order(runs):
        order = np.argsort(run.frequency_hz)
        residual = np.maximum(comp.residual_map[run.name][order], 1e-6)
        shown.append(residual)
        style = {**_line(levels.colour(run)), **level_style(run.control, levels.colour(run), 4)}
        p.plot(run.frequency_hz[order], residual, **style)
        entries.append((style, _run_name(run, tags)))
        other = comp.other_branch.get(run.name, np.zeros(len(order), bool))
        if other.any():                    # measured on another branch than the swept prediction (a jump)
            p.plot(run.frequency_hz[other], np.maximum(comp.residual_map[run.name][other], 1e-6), pen=None,
                   symbol="x", symbolSize=14, symbolPen={"color": levels.colour(run), "width": 2})
    p.setYRange(*_log_range_with_ticks(np.concatenate(shown)), padding=0)
    legend_column(lay.ci, entries, row=0, col=1)
    return _export(lay, path, height=600)


def _log_range_with_ticks(values, headroom: float = 0.05, footroom: float = 0.0) -> tuple[float, float]:
    """The view (log10 low, log10 high) of a log axis showing ``values``: it reaches down to the nearest value
    that the axis labels (:func:`_labelled_log_ticks`: a reader reads the lowest point against a number under it)
    at least ``footroom`` of the span below the lowest point (room for a label under it), and ``headroom`` of the
    span above the highest."""
    lo, hi = float(np.log10(np.min(values))), float(np.log10(np.max(values)))
    span = max(hi - lo, 0.3)
    high = hi + headroom * span
    below = lo - footroom * span
    decade = np.floor(below)
    # the 1-2-5 values below the lowest point, nearest first
    for low in decade + np.log10([5.0, 2.0, 1.0, 0.5, 0.2, 0.1]):
        if low <= below and min(_labelled_log_ticks(low, high)) <= low + 1e-9:
            return float(low), float(high)
    return float(decade - 1), float(high)


def _label_anchor(values: np.ndarray, i: int) -> tuple[float, float]:
    """Where a point's value label goes so that the line does not run through it: above a point no neighbour
    rises above, below one no neighbour falls under, else on the right beside a point the line passes through
    (above right where it falls, below right where it rises)."""
    neighbours = [values[j] for j in (i - 1, i + 1) if 0 <= j < len(values)]
    if all(n <= values[i] for n in neighbours):
        return 0.5, 1.4
    if all(n >= values[i] for n in neighbours):
        return 0.5, -0.4
    return (-0.15, 1.2) if values[i - 1] > values[i + 1] else (-0.15, -0.2)


def plot_history(wb: Workbench, path: Path) -> Path:
    """The error after each step of the model history."""
    import pyqtgraph as pg

    lay = _layout()
    p = _log_plot(lay, 0, 0, title="FRF error of the model after each step (all responses, all force levels): the "
                                   "start, linear corrections and each effect added", y_unit="")
    x = np.arange(len(wb.history))
    errors = np.array([max(h.error, 1e-9) for h in wb.history])
    p.plot(x, errors, pen={"color": (31, 119, 180), "width": 2}, symbol="o", symbolSize=9,
           symbolBrush=(31, 119, 180))
    p.getAxis("bottom").setTicks([[(i, h.action.replace("add ", "+")) for i, h in enumerate(wb.history)]])
    p.setXRange(-0.5, len(wb.history) - 0.5, padding=0)   # room for the first and last step's names
    # room above for a label over the highest point, below for one under the lowest
    low, high = _log_range_with_ticks(errors, headroom=0.12, footroom=0.12)
    p.setYRange(low, high, padding=0)
    p.setLabel("left", "relative FRF error")
    for i, e in enumerate(errors):
        label = pg.TextItem(f"{e:.3g}", color="k", anchor=_label_anchor(errors, i))
        label.setPos(i, np.log10(e))
        p.addItem(label)
    return _export(lay, path, height=600)


REPORT_FILES = ("frf.png", "kbar.png", "residuals.png", "error_history.png")
BACKBONE_FILE = "backbone.png"     # with the report files where the session has response-controlled levels


def plot_backbones(comparisons: list[BackboneComparison], path: Path) -> Path:
    """Natural frequency and damping ratio against response amplitude: measured (a single-mode fit per response
    level, dots) and predicted from the model (line), one colour per held DOF and quantity."""
    return _export(backbone_layout(comparisons), path, height=700)


def backbone_layout(comparisons: list[BackboneComparison]):
    """The two panels of :func:`plot_backbones` (frequency above, damping below, amplitude axes linked)."""
    lay = _layout()
    error = comparisons_error(comparisons)
    lay.addLabel("Natural frequency and damping ratio against response amplitude: measured (dots, a modal fit per "
                 "response-controlled level<br>or a phase-resonance point) and predicted by the model (line); "
                 f"RMS relative error: frequency {error.frequency:.3g}, damping {error.damping:.3g}",
                 row=0, col=0, colspan=2, size="11pt")
    units = comparisons[0].measured.units if comparisons else ""
    freq = _log_plot(lay, 1, 0, x_unit=units)
    damp = _log_plot(lay, 2, 0, x_unit=units)
    damp.setXLink(freq)
    freq.setLabel("left", "natural frequency", units="Hz")
    damp.setLabel("left", "damping ratio")
    damp.setLabel("bottom", "response amplitude")
    entries = []
    for c, colour in zip(comparisons, level_colours(len(comparisons))):
        name = f"{c.measured.quantity} at {c.measured.dof}" + \
            (f" ({c.measured.method})" if c.measured.method.startswith("phase") else "")
        a, f, z = c.measured.arrays()
        ca, cf, cz = c.curve.arrays()
        for plot, measured, predicted in ((freq, f, cf), (damp, z, cz)):
            plot.plot(ca, predicted, **_line(colour))
            known = np.isfinite(measured)              # no damping where the model has no mode shape there
            if known.any():
                plot.plot(a[known], measured[known], **_symbols(colour, 9))
        entries += [(_line(colour), f"{name}: model"), (_symbols(colour, 9), f"{name}: measured")]
    legend_column(lay.ci, entries, row=1, col=1, rowspan=2)
    return lay


def write_report(wb: Workbench, folder: Path, overwrite: bool = False,
                 comparisons: list[BackboneComparison] | None = None) -> list[Path]:
    """All report plots into ``folder`` (REPORT_FILES, and BACKBONE_FILE where the session has response levels:
    ``comparisons``, computed here if not given); returns their paths. Existing plots are refused (InputError)
    unless ``overwrite``, before any is drawn."""
    from app.session.outputs import check_output

    comparisons = backbones(wb) if comparisons is None else comparisons
    names = REPORT_FILES + ((BACKBONE_FILE,) if comparisons else ())
    folder.mkdir(parents=True, exist_ok=True)
    for name in names:
        check_output(folder / name, overwrite=overwrite, field=None, overwrite_flag="--overwrite")
    runs = wb.measurements.sine
    comp = wb.compare()
    frf, kbar, residuals, history = (folder / name for name in REPORT_FILES)
    plots = [_drawn(plot_frfs, comp, runs, frf, _drive_point(runs)), _drawn(plot_kbar, wb, kbar),
             _drawn(plot_residuals, comp, runs, residuals), _drawn(plot_history, wb, history)]
    if comparisons:
        plots.append(_drawn(plot_backbones, comparisons, folder / BACKBONE_FILE))
    return plots


def _drawn(plot, *args) -> Path:
    """``plot(*args)``, drawn whole. Qt calls the plot items' Python overrides (a resize, a paint) from its own C++
    frames, and a KeyboardInterrupt raised in one leaves the scene half updated: the process crashed (SIGSEGV)
    where it should have said it was interrupted. A signal acts once the PNG is written
    (:func:`analysis.common.held_signals.signals_held`); a plot takes a fraction of a second."""
    with signals_held():
        return plot(*args)


PREDICTION_FILES = ("frf.png", "residuals.png")


def write_prediction_report(comp: Comparison, runs: Sequence[SineRun], comparisons: list[BackboneComparison],
                            folder: Path, overwrite: bool = False,
                            tags: dict[str, str] | None = None) -> list[Path]:
    """The plots of a prediction with nothing refitted (``contactid predict``): PREDICTION_FILES, and
    BACKBONE_FILE where the session has response levels; refused as :func:`write_report` refuses."""
    from app.session.outputs import check_output

    names = PREDICTION_FILES + ((BACKBONE_FILE,) if comparisons else ())
    folder.mkdir(parents=True, exist_ok=True)
    for name in names:
        check_output(folder / name, overwrite=overwrite, field=None, overwrite_flag="--overwrite")
    frf, residuals = (folder / name for name in PREDICTION_FILES)
    plots = [_drawn(plot_frfs, comp, runs, frf, _drive_point(runs), tags),
             _drawn(plot_residuals, comp, runs, residuals, tags)]
    if comparisons:
        plots.append(_drawn(plot_backbones, comparisons, folder / BACKBONE_FILE))
    return plots


def _drive_point(runs: Sequence[SineRun]) -> str:
    """The sensor the FRF plot shows: the drive point where it is measured, else the first sensor."""
    first = runs[0]
    return first.excitation_dof if first.excitation_dof in first.sensor_dofs else first.sensor_dofs[0]
