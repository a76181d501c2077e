"""Backbone tab: natural frequency and damping ratio against response amplitude for every session that measures
them, imported or measured here -- a single-mode fit per response-controlled level, the locked points of each
phase-resonance run -- and, once the model is analysed or predicts, the model's prediction of each curve with the
table ``contactid analyze`` prints (analysis/prediction/backbone.py). Drawn by the rules of backbone.png
(app/report.py): a colour per curve, dots measured, a line predicted, the legend beside the plots."""
from __future__ import annotations

import numpy as np
import pyqtgraph as pg
from PySide6.QtCore import Qt
from PySide6.QtGui import QFontDatabase
from PySide6.QtWidgets import QLabel, QPlainTextEdit, QSplitter, QVBoxLayout, QWidget

from analysis.prediction.backbone import POWER, Backbone
from app.kbar_view import legend_column, level_colours

from .lab import Lab
from .plots import configure_plot
from .results import BackboneView

NO_SESSION = "No session open: natural frequency and damping against amplitude are measured on a session's " \
             "response-controlled levels and phase-resonance runs."
NOT_YET = "No natural frequency and damping read from this session yet."
NONE_MEASURED = ("This session holds no response-controlled level and no phase-resonance run: natural frequency and "
                 "damping against amplitude are measured on those (a force-controlled level's amplitude changes "
                 "along its sweep, so it has no one amplitude).")


def _as_displacement(curve: Backbone) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A curve's (amplitude, frequency, damping) with the amplitude as the displacement it is at each point's
    frequency (as the Acquire tab's live plots show it)."""
    a, f, z = curve.arrays()
    return a / (2 * np.pi * f) ** POWER[curve.quantity], f, z


def _counted(curve: Backbone) -> str:
    what = "response level(s)" if curve.method.startswith("single-mode") else f"point(s) of {curve.runs[0]}"
    return f"{len(curve.points)} {what}, {curve.quantity} at {curve.dof}"


class BackbonePanel(QWidget):
    """The Backbone tab (module docstring)."""

    def __init__(self, lab: Lab, parent: QWidget | None = None):
        super().__init__(parent)
        self.lab = lab
        self.view: BackboneView | None = None
        layout = QVBoxLayout(self)
        self.status = QLabel(NO_SESSION)
        self.status.setWordWrap(True)
        layout.addWidget(self.status)
        # the plots side by side over the table: the table's columns want the window's width, not its height
        splitter = QSplitter(Qt.Orientation.Vertical)
        layout.addWidget(splitter, 1)
        self.graphics = pg.GraphicsLayoutWidget()
        self.frequency = configure_plot(self.graphics.addPlot(0, 0), "Natural frequency", "response amplitude", None,
                                        "natural frequency", "Hz", log_x=True)
        self.damping = configure_plot(self.graphics.addPlot(0, 1), "Damping ratio", "response amplitude", None,
                                      "damping ratio", None, log_x=True)
        self.damping.setXLink(self.frequency)
        self.legend: pg.LegendItem | None = None
        splitter.addWidget(self.graphics)
        self.table = QPlainTextEdit()
        self.table.setReadOnly(True)
        self.table.setLineWrapMode(QPlainTextEdit.LineWrapMode.NoWrap)     # columns: scroll, never fold
        self.table.setFont(QFontDatabase.systemFont(QFontDatabase.SystemFont.FixedFont))
        self.table.setPlaceholderText("The measured points, and the model's beside them once analysed")
        splitter.addWidget(self.table)
        splitter.setStretchFactor(0, 3)
        splitter.setStretchFactor(1, 2)
        lab.backboneUpdated.connect(self.show_view)
        # another session or model: the tab shows what the lab holds now (nothing of the one before)
        lab.sessionChanged.connect(lambda: self.show_view(lab.backbone))
        lab.modelChanged.connect(lambda: self.show_view(lab.backbone))
        self.show_view(None)

    def plots(self) -> dict[str, pg.PlotItem]:
        return {"natural_frequency": self.frequency, "damping": self.damping}

    def legend_names(self) -> list[str]:
        return [] if self.legend is None else [label.text for _, label in self.legend.items]

    def show_view(self, view: BackboneView | None) -> None:
        self.view = view
        for plot in (self.frequency, self.damping):
            plot.clear()
        if self.legend is not None:
            self.graphics.removeItem(self.legend)
            self.legend = None
        self.table.setPlainText("" if view is None else view.text())
        if view is None:
            self.status.setText(NO_SESSION if self.lab.session_path is None else NOT_YET)
            return
        if not view.measured:
            self.status.setText(NONE_MEASURED)
            return
        self._draw(view)
        count = ", ".join(_counted(c) for c in view.measured)
        if view.predicted:
            self.status.setText(f"Measured (dots: {count}) and predicted by the model (lines: {view.model}); RMS "
                                f"relative error of the model: {view.error_words()}.")
        else:
            self.status.setText(f"Measured (dots): {count}. The model's prediction is drawn once the model is "
                                f"analysed or predicts (Model tab).")

    def _draw(self, view: BackboneView) -> None:
        """One colour per measured curve (as backbone.png); its model's curve as a line in the same colour. One
        amplitude axis: in the curves' own units where they share them, else every curve as a displacement."""
        curves = view.comparisons or view.measured
        measured = [c.measured for c in view.comparisons] or view.measured
        units = {c.units for c in measured}
        same = len(units) == 1
        unit = units.pop() if same else "m"
        for plot in (self.frequency, self.damping):
            plot.setLabel("bottom", "response amplitude" if same else "displacement amplitude", units=unit)
        entries = []
        for curve, colour in zip(curves, level_colours(len(curves))):
            m = curve.measured if view.comparisons else curve
            name = f"{m.quantity} at {m.dof}" + (f" ({m.method})" if m.method.startswith("phase") else "")
            a, f, z = m.arrays() if same else _as_displacement(m)
            dots = {"pen": None, "symbol": "o", "symbolSize": 9, "symbolBrush": pg.mkBrush(colour), "symbolPen": None}
            line = {"pen": pg.mkPen(colour, width=2)}
            if view.comparisons:
                ca, cf, cz = curve.curve.arrays() if same else _as_displacement(curve.curve)
                self.frequency.plot(ca, cf, **line)
                self.damping.plot(ca, cz, **line)
                entries.append((line, f"{name}: model"))
            self.frequency.plot(a, f, **dots)
            known = np.isfinite(z)                # a lock without a low-level FRF to scale its power balance
            if known.any():
                self.damping.plot(a[known], z[known], **dots)
            entries.append((dots, f"{name}: measured"))
        self.legend = legend_column(self.graphics.ci, entries, row=0, col=2)
