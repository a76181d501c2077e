"""Report plots (PNG) of a workbench: FRFs measured against predicted, kbar against amplitude, the residual
per line, and the error history. Drawn with pyqtgraph off screen, so they work on a machine without a display.

Log axes are labelled at the decades only, in engineering notation with the unit on every label (docs/workbench.md):
pyqtgraph's own log axis labels every minor tick and prefixes the unit once for the whole axis, which crowds the
labels into each other and reads badly.
"""
from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from analysis.workbench import Workbench

LEVEL_COLOURS = [(31, 119, 180), (255, 127, 14), (44, 160, 44), (214, 39, 40), (148, 103, 189),
                 (140, 86, 75), (227, 119, 194), (127, 127, 127)]


def qt_application():
    """The QApplication, created off screen when there is no display."""
    if not os.environ.get("DISPLAY") and not os.environ.get("WAYLAND_DISPLAY"):
        os.environ.setdefault("QT_QPA_PLATFORM", "offscreen")
    from PySide6.QtWidgets import QApplication

    return QApplication.instance() or QApplication([])


def _colour(levels: list[float], force: float):
    return LEVEL_COLOURS[levels.index(round(force, 12)) % len(LEVEL_COLOURS)]


def _symbols(colour, size: int) -> dict:
    """Plot style of measured points: filled circles of ``size`` px, no line."""
    return {"pen": None, "symbol": "o", "symbolSize": size, "symbolBrush": colour, "symbolPen": None}


def _export(layout, path: Path, width: int = 1400, height: int = 900) -> Path:
    """The layout as a PNG at ``path``, replaced all at once (:func:`write_report` checks for old files)."""
    import pyqtgraph.exporters

    from .outputs import atomic_output

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


_PREFIXES = {-15: "f", -12: "p", -9: "n", -6: "µ", -3: "m", 0: "", 3: "k", 6: "M", 9: "G", 12: "T"}
_SUPERSCRIPT = str.maketrans("-0123456789", "⁻⁰¹²³⁴⁵⁶⁷⁸⁹")


def engineering(value: float, unit: str = "") -> str:
    """``value`` in engineering notation: a mantissa in [1, 1000) and an SI prefix on ``unit`` ("20 µm",
    "1.5 kN/m"). Without a unit, plain numbers from 0.001 to 1000 and powers of ten beyond ("10⁻⁶")."""
    if value == 0 or not np.isfinite(value):
        return f"{value:g} {unit}".strip()
    exponent = int(np.floor(np.log10(abs(value)) + 1e-9))
    if not unit:
        if -3 <= exponent < 4:
            return f"{value:.4g}"
        mantissa = value / 10.0**exponent
        head = "" if np.isclose(mantissa, 1.0) else f"{mantissa:.3g}·"
        return f"{head}10{str(exponent).translate(_SUPERSCRIPT)}"
    third = min(max(3 * (exponent // 3), min(_PREFIXES)), max(_PREFIXES))
    return f"{value / 10.0**third:.3g} {_PREFIXES[third]}{unit}"


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


def plot_frfs(wb: Workbench, path: Path, sensor: str | None = None) -> Path:
    """|h| and phase of one sensor per force level: measured (symbols) and predicted (lines)."""
    comp = wb.compare()
    levels = wb.measurements.levels
    runs = wb.measurements.sine
    sensor = sensor or runs[0].sensor_dofs[0]
    lay = _layout()
    mag = _log_plot(lay, 0, 0, title=f"Receptance {sensor} / {runs[0].excitation_dof} at each force level: "
                                     f"measured (dots) and model prediction (lines); FRF error {comp.error:.3g}",
                    y_unit="m/N")
    mag.setLabel("left", "|h|")
    mag.addLegend(offset=(-10, 10))
    ph = lay.addPlot(row=1, col=0)
    ph.setLabel("left", "phase", units="deg")
    ph.setLabel("bottom", "frequency", units="Hz")
    ph.setXLink(mag)
    for run in runs:
        p = run.sensor_dofs.index(sensor)
        order = np.argsort(run.frequency_hz)
        f = run.frequency_hz[order]
        meas = run.receptance[order, p]
        pred = comp.predicted[run.name][order, p]
        c = _colour(levels, run.force)
        measured, model = _symbols(c, 5), {"pen": {"color": c, "width": 2}}
        mag.plot(f, np.abs(meas), name=f"{run.force:g} N {run.direction}", **measured)
        mag.plot(f, np.abs(pred), **model)
        ph.plot(f, np.degrees(np.angle(meas)), **measured)
        ph.plot(f, np.degrees(np.angle(pred)), **model)
    return _export(lay, path)


def plot_kbar(wb: Workbench, path: Path) -> Path:
    """Re and Im of every element's kbar against its amplitude, coloured by force level; the fitted laws as
    crosses at the same samples."""
    levels = wb.measurements.levels
    lay = _layout()
    lay.addLabel("Equivalent complex stiffness kbar of each element against its amplitude X: identified "
                 "(dots, one colour per force level) and fitted laws (crosses)", row=0, col=0,
                 colspan=max(len(wb.model.elements), 1), size="11pt")
    for col, el in enumerate(wb.model.elements):
        rep = wb.reports.get(el.name)
        s = rep.samples if rep else None
        k_u, x_u = s.units if s is not None else ("N/m", "m")
        verdict = "" if rep is None or rep.verdict is None else (": linear" if rep.verdict.linear else
                                                                 ": nonlinear")
        re = _log_plot(lay, 1, col, title=f"element {el.name} at {' - '.join(el.dofs)}{verdict}", x_unit=x_u)
        im = _log_plot(lay, 2, col, x_unit=x_u)
        re.setLabel("left", "Re kbar", units=k_u)
        im.setLabel("left", "Im kbar", units=k_u)
        im.setLabel("bottom", "amplitude X")
        im.setXLink(re)
        if col == 0:
            re.addLegend(offset=(-10, 10))
        if s is None:
            continue
        for force in levels:
            sel = np.isclose(s.level, force)
            if not sel.any():
                continue
            measured = _symbols(_colour(levels, force), 4)
            re.plot(s.X[sel], s.kbar[sel].real, name=f"{force:g} N", **measured)
            im.plot(s.X[sel], s.kbar[sel].imag, **measured)
        if (el.laws or el.nonparametric is not None) and all(t.complete for t in el.laws):
            # the model at each sample's (X, w): markers, since kbar may depend on w as well as X
            model = el.describing_function(s.X, s.w)
            style = {"pen": None, "symbol": "x", "symbolSize": 5, "symbolPen": {"color": "k", "width": 1}}
            re.plot(s.X, model.real, **style)
            im.plot(s.X, model.imag, **style)
    return _export(lay, path)


def plot_residuals(wb: Workbench, path: Path) -> Path:
    """Relative FRF error per line and run: where the model fails."""
    comp = wb.compare()
    levels = wb.measurements.levels
    lay = _layout()
    p = _log_plot(lay, 0, 0, title="Where the model fails: relative FRF error of the prediction at each "
                                   "frequency line and force level", y_unit="")
    p.setLabel("left", "relative FRF error")
    p.setLabel("bottom", "frequency", units="Hz")
    p.addLegend(offset=(-10, 10))
    for run in wb.measurements.sine:
        order = np.argsort(run.frequency_hz)
        p.plot(run.frequency_hz[order], np.maximum(comp.residual_map[run.name][order], 1e-6),
               pen={"color": _colour(levels, run.force), "width": 2}, name=f"{run.force:g} N {run.direction}")
        other = comp.other_branch.get(run.name, np.zeros(len(order), bool))
        if other.any():                    # measured on another branch than the swept prediction (a jump)
            p.plot(run.frequency_hz[other], np.maximum(comp.residual_map[run.name][other], 1e-6), pen=None,
                   symbol="x", symbolSize=14, symbolPen={"color": _colour(levels, run.force), "width": 2})
    return _export(lay, path, height=600)


def plot_history(wb: Workbench, path: Path) -> Path:
    """The error after each step of the model history."""
    import pyqtgraph as pg

    lay = _layout()
    p = _log_plot(lay, 0, 0, title="FRF error of the model after each step: the start, linear corrections "
                                   "and each effect added", y_unit="")
    x = np.arange(len(wb.history))
    errors = np.array([max(h.error, 1e-9) for h in wb.history])
    p.plot(x, errors, pen={"color": (31, 119, 180), "width": 2}, symbol="o", symbolSize=9,
           symbolBrush=(31, 119, 180))
    p.getAxis("bottom").setTicks([[(i, h.action.replace("add ", "+")) for i, h in enumerate(wb.history)]])
    p.setXRange(-0.5, len(wb.history) - 0.5, padding=0)   # room for the first and last step's names
    p.setLabel("left", "relative FRF error")
    for i, e in enumerate(errors):
        label = pg.TextItem(f"{e:.3g}", color="k", anchor=(0.5, 1.3))
        label.setPos(i, np.log10(e))
        p.addItem(label)
    return _export(lay, path, height=600)


REPORT_FILES = ("frf.png", "kbar.png", "residuals.png", "error_history.png")


def write_report(wb: Workbench, folder: Path, overwrite: bool = False) -> list[Path]:
    """All report plots into ``folder`` (REPORT_FILES); returns their paths. Existing plots are refused
    (InputError) unless ``overwrite``, before any is drawn."""
    from .outputs import check_output

    folder.mkdir(parents=True, exist_ok=True)
    for name in REPORT_FILES:
        check_output(folder / name, overwrite=overwrite, field=None, overwrite_flag="--overwrite")
    sensor = wb.measurements.sine[0].excitation_dof
    if sensor not in wb.measurements.sine[0].sensor_dofs:
        sensor = wb.measurements.sine[0].sensor_dofs[0]
    frf, kbar, residuals, history = (folder / name for name in REPORT_FILES)
    return [plot_frfs(wb, frf, sensor), plot_kbar(wb, kbar), plot_residuals(wb, residuals),
            plot_history(wb, history)]
