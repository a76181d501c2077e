"""Report plots (PNG) of a workbench: FRFs measured against predicted, kbar against amplitude, the residual
per line, and the error history. Drawn with pyqtgraph off screen, so they work on a machine without a display.
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
    import pyqtgraph.exporters

    layout.resize(width, height)
    layout.show()                       # off screen: lays the plots out at the export size
    qt_application().processEvents()
    exporter = pyqtgraph.exporters.ImageExporter(layout.scene())
    exporter.parameters()["width"] = width
    exporter.export(str(path))
    layout.close()
    return path


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
    mag = lay.addPlot(row=0, col=0, title=f"receptance {sensor} / {runs[0].excitation_dof}: measured (o) "
                                          f"and model (line), error {comp.error:.3g}")
    mag.setLogMode(y=True)
    mag.setLabel("left", "|h|", units="m/N")
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
    for col, el in enumerate(wb.model.elements):
        rep = wb.reports.get(el.name)
        s = rep.samples if rep else None
        re = lay.addPlot(row=0, col=col, title=f"{el.name} ({el.dofs[0]}): "
                         + ("" if rep is None or rep.verdict is None else
                            ("linear" if rep.verdict.linear else "nonlinear")))
        im = lay.addPlot(row=1, col=col)
        k_u, x_u = s.units if s is not None else ("N/m", "m")
        re.setLabel("left", "Re kbar", units=k_u)
        im.setLabel("left", "Im kbar", units=k_u)
        im.setLabel("bottom", "amplitude X", units=x_u)
        for plot in (re, im):
            plot.setLogMode(x=True)
            plot.getAxis("bottom").setStyle(maxTextLevel=0)     # decade labels only: no crowded minor labels
        if s is None:
            continue
        for force in levels:
            sel = np.isclose(s.level, force)
            if not sel.any():
                continue
            measured = _symbols(_colour(levels, force), 4)
            re.plot(s.X[sel], s.kbar[sel].real, **measured)
            im.plot(s.X[sel], s.kbar[sel].imag, **measured)
        if el.laws and all(t.complete for t in el.laws):
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
    p = lay.addPlot(title="where the model fails: relative FRF error per line")
    p.setLogMode(y=True)
    p.setLabel("left", "relative error")
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
    p = lay.addPlot(title="FRF error as effects are added")
    p.setLogMode(y=True)
    x = np.arange(len(wb.history))
    errors = np.array([max(h.error, 1e-9) for h in wb.history])
    p.plot(x, errors, pen={"color": (31, 119, 180), "width": 2}, symbol="o", symbolSize=9,
           symbolBrush=(31, 119, 180))
    p.getAxis("bottom").setTicks([[(i, h.action.replace("add ", "+")) for i, h in enumerate(wb.history)]])
    p.setLabel("left", "FRF error")
    for i, e in enumerate(errors):
        label = pg.TextItem(f"{e:.3g}", color="k", anchor=(0.5, 1.3))
        label.setPos(i, np.log10(e))
        p.addItem(label)
    return _export(lay, path, height=600)


def write_report(wb: Workbench, folder: Path) -> list[Path]:
    """All report plots into ``folder``; returns their paths."""
    folder.mkdir(parents=True, exist_ok=True)
    sensor = wb.measurements.sine[0].excitation_dof
    if sensor not in wb.measurements.sine[0].sensor_dofs:
        sensor = wb.measurements.sine[0].sensor_dofs[0]
    return [plot_frfs(wb, folder / "frf.png", sensor), plot_kbar(wb, folder / "kbar.png"),
            plot_residuals(wb, folder / "residuals.png"), plot_history(wb, folder / "error_history.png")]
