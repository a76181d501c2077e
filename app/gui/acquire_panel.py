"""Acquire tab: the plan editor (force or response levels, span, step, direction; optional random run) validated
as it is edited, Start / Pause / Abort, and the live view of the campaign: time signals, FRF magnitude and phase
growing line by line per level, achieved against target force, distortion, steady-state waiting, natural frequency
and damping against amplitude (a point per locked phase-resonance level as it locks, a point per response level
as it ends), progress and ETA, and the event log."""
from __future__ import annotations

import datetime as _dt
from pathlib import Path

import numpy as np
import pyqtgraph as pg
from PySide6.QtCore import QRectF, Qt
from PySide6.QtGui import QColor
from PySide6.QtWidgets import (QAbstractItemView, QComboBox, QDoubleSpinBox, QFileDialog, QFormLayout, QFrame,
                               QGroupBox, QHBoxLayout, QHeaderView, QLabel, QLineEdit, QListWidget, QProgressBar,
                               QPushButton, QScrollArea, QSplitter, QTableWidget, QVBoxLayout, QWidget)

from analysis.prediction.backbone import POWER, measured_backbone, measured_power_balance
from analysis.common.errors import InputError
from app.models import builtin_plan_path
from app.session import measurements_from_session
from drivers.simulation.rig import builtin_rigs

from app.campaign import load_plan
from .lab import Lab, save_text
from .live import ALARM_COLOR, CampaignFeed, is_alarm
from .plan_doc import plan_document, plan_toml
from .plots import (CHANNEL_COLORS, FrameClock, LevelPalette, Redraw, configure_plot, finite_log, random_pen,
                    run_control, sensor_symbol, shrinkable_title, side_legend)

COLUMNS = ("Level", "Start", "Stop", "Step", "Dir", "Refine", "Holds", "DOF")
COLUMN_TIPS = ("N for a force level; m/s², m/s or m for a response level (SI units)", "Hz", "Hz", "Hz",
               "sweep direction", "adaptive refinement near resonance", "what the level holds",
               "the sensor DOF whose response amplitude is held")
HOLDS = ("force", "acceleration", "velocity", "displacement")    # what a level holds (docs/campaigns.md)
DEFAULT_LEVEL = {"force": 0.8, "start": 0.8, "stop": 3.2, "step": 0.025, "direction": "up", "refine": True}
TIME_PERIODS = 5            # periods of the current line shown in the time plots
TIME_WINDOW_DEFAULT = 1.0   # s shown before the first line (and during the random run)
EVENTS_KEPT = 500


def default_session_name() -> str:
    return f"session-{_dt.datetime.now():%Y%m%d-%H%M%S}.h5"


def _line_path(m) -> str:
    """How the last line was measured: from its transient (with the fit's 3 std), after waiting, or at the
    settling limit."""
    head = f"last line {m.frequency:.4g} Hz: "
    if m.transient:
        return head + f"from its transient after {m.settle_periods:.0f} periods (3 std {3 * m.transient_std:.1e})"
    if m.steady:
        return head + f"steady after {m.settle_periods:.0f} periods"
    return head + f"measured at the settling limit ({m.settle_periods:.0f} periods)"


def _level(run) -> str:
    """A live run's level for a legend: its force, or the response amplitude it holds and where."""
    return run_control(run).label()


def _spin(value: float, decimals: int = 4, minimum: float = 0.0, maximum: float = 1e5) -> QDoubleSpinBox:
    spin = QDoubleSpinBox(decimals=decimals, minimum=minimum, maximum=maximum)
    spin.setValue(value)
    spin.setButtonSymbols(QDoubleSpinBox.ButtonSymbols.NoButtons)
    return spin


class _CellSpin(QDoubleSpinBox):
    """A number of the plan table: written without trailing zeros ("0.8", "0.025"), and as wide as what it shows,
    so the table's columns, sized to their contents, show every digit (a spin box asks room for its maximum)."""

    def textFromValue(self, value: float) -> str:  # noqa: N802 (Qt API)
        text = self.locale().toString(float(value), "f", self.decimals())
        point = self.locale().decimalPoint()
        return text.rstrip("0").rstrip(point) if point in text else text

    def sizeHint(self):  # noqa: N802 (Qt API)
        hint = super().sizeHint()
        hint.setWidth(self.fontMetrics().horizontalAdvance(max(self.text(), "0.0", key=len)) + 12)
        return hint

    def minimumSizeHint(self):  # noqa: N802 (Qt API)
        return self.sizeHint()


class _CellCombo(QComboBox):
    """A choice of the plan table, as wide as the choice it shows (a combo box asks room for its longest item)."""

    def sizeHint(self):  # noqa: N802 (Qt API)
        hint = super().sizeHint()
        longest = self.fontMetrics().horizontalAdvance(max((self.itemText(i) for i in range(self.count())),
                                                           key=len, default=""))
        hint.setWidth(hint.width() - longest + self.fontMetrics().horizontalAdvance(self.currentText()))
        return hint

    def minimumSizeHint(self):  # noqa: N802 (Qt API)
        return self.sizeHint()


class _CellLine(QLineEdit):
    """The DOF of a plan row: as wide as its text or its placeholder, not a line edit's default width."""

    def sizeHint(self):  # noqa: N802 (Qt API)
        hint = super().sizeHint()
        hint.setWidth(self.fontMetrics().horizontalAdvance(max(self.text(), self.placeholderText(), key=len)) + 12)
        return hint

    def minimumSizeHint(self):  # noqa: N802 (Qt API)
        return self.sizeHint()


def _format_eta(seconds: float | None) -> str:
    if seconds is None:
        return "ETA —"
    seconds = int(round(seconds))
    return f"ETA {seconds // 3600:d} h {seconds % 3600 // 60:02d} min" if seconds >= 3600 else \
        f"ETA {seconds // 60:d} min {seconds % 60:02d} s"


class PlanEditor(QGroupBox):
    """The plan as a table of force levels plus an optional random run; emits the document on every edit."""

    def __init__(self, lab: Lab, parent: QWidget | None = None):
        super().__init__("Plan", parent)
        self.lab = lab
        self.touched = False            # the operator loaded or edited a plan (do not replace it)
        self._extra: dict = {}          # [settle] / [control] of a loaded plan, kept as they were
        self._limits: dict[int, float | None] = {}     # row -> force limit of a loaded response level
        layout = QVBoxLayout(self)
        self.table = QTableWidget(0, len(COLUMNS))
        self.table.setHorizontalHeaderLabels(COLUMNS)
        for col, tip in enumerate(COLUMN_TIPS):
            self.table.horizontalHeaderItem(col).setToolTip(tip)
        # every column as wide as its cells' contents (the last one takes what is left): no digit is cut off; a
        # narrow column of the splitter scrolls the table sideways rather than truncate its cells
        self.table.horizontalHeader().setSectionResizeMode(QHeaderView.ResizeMode.ResizeToContents)
        self.table.horizontalHeader().setStretchLastSection(True)
        self.table.verticalHeader().setVisible(False)
        self.table.setSelectionBehavior(QAbstractItemView.SelectionBehavior.SelectRows)
        self.table.setMinimumHeight(110)
        layout.addWidget(self.table)
        buttons = QHBoxLayout()
        for text, slot in (("Add level", self._add_clicked), ("Remove level", self._remove_clicked),
                           ("Load plan…", self._load_clicked), ("Save plan…", self._save_clicked)):
            button = QPushButton(text)
            button.clicked.connect(slot)
            buttons.addWidget(button)
        layout.addLayout(buttons)

        self.random = QGroupBox("Random run first (reference FRFs)")
        self.random.setCheckable(True)
        self.random.setChecked(False)
        form = QFormLayout(self.random)
        self.random_rms = _spin(0.05)
        self.random_low, self.random_high = _spin(0.5), _spin(5.0)
        self.random_duration = _spin(120.0, 1)
        band = QHBoxLayout()
        band.addWidget(self.random_low)
        band.addWidget(QLabel("–"))
        band.addWidget(self.random_high)
        band.addWidget(QLabel("Hz"))
        form.addRow("Force rms [N]", self.random_rms)
        form.addRow("Band", band)
        form.addRow("Duration [s]", self.random_duration)
        layout.addWidget(self.random)
        self.random.toggled.connect(self._edited)
        for spin in (self.random_rms, self.random_low, self.random_high, self.random_duration):
            spin.valueChanged.connect(self._edited)

        self.validation = QLabel()
        self.validation.setWordWrap(True)
        layout.addWidget(self.validation)
        lab.planChecked.connect(self._show_check)
        self.set_levels([DEFAULT_LEVEL])
        self.touched = False

    # ------------------------------------------------------------------ rows
    def _add_row(self, level: dict) -> None:
        row = self.table.rowCount()
        self.table.insertRow(row)
        for col, key in enumerate(("force", "start", "stop", "step")):
            value = level["response"] if key == "force" and "response" in level else level[key]
            spin = _CellSpin(decimals=4 if key != "force" else 3, minimum=0.0, maximum=1e5)
            spin.setValue(value)
            spin.setButtonSymbols(QDoubleSpinBox.ButtonSymbols.NoButtons)
            spin.valueChanged.connect(self._edited)
            self.table.setCellWidget(row, col, spin)
        direction = _CellCombo()
        direction.addItems(["up", "down", "both"])
        direction.setCurrentText(level["direction"])
        direction.currentTextChanged.connect(self._edited)
        self.table.setCellWidget(row, 4, direction)
        refine = _CellCombo()
        refine.addItems(["yes", "no"])
        refine.setCurrentText("yes" if level.get("refine", True) else "no")
        refine.setToolTip("Adaptive refinement: extra lines where the FRF changes fast (near resonance)")
        refine.currentTextChanged.connect(self._edited)
        self.table.setCellWidget(row, 5, refine)
        holds = _CellCombo()
        holds.addItems(HOLDS)
        holds.setCurrentText(level.get("quantity", "acceleration") if "response" in level else "force")
        holds.setToolTip("What the level holds: the force, or a response amplitude at a DOF (SI units: m/s², m/s, m)")
        holds.currentTextChanged.connect(self._edited)
        self.table.setCellWidget(row, 6, holds)
        dof = _CellLine(level.get("dof", ""))
        dof.setPlaceholderText("DOF")
        dof.setToolTip("the sensor DOF whose response amplitude is held")
        dof.textChanged.connect(self._edited)
        self.table.setCellWidget(row, 7, dof)
        self._limits[row] = level.get("force_limit")     # a loaded response level's force limit, kept
    def set_levels(self, levels: list[dict]) -> None:
        self.table.setRowCount(0)
        self._limits = {}
        for level in levels:
            self._add_row(level)
        self._edited()

    def levels(self) -> list[dict]:
        out = []
        for row in range(self.table.rowCount()):
            cell = self.table.cellWidget
            level = {key: cell(row, col).value() for col, key in enumerate(("force", "start", "stop", "step"))}
            level["direction"] = cell(row, 4).currentText()
            level["refine"] = cell(row, 5).currentText() == "yes"
            out.append(self._held(row, level))
        return out

    def _held(self, row: int, level: dict) -> dict:
        """A row's level as the plan spells it: a force, or ``response`` with its quantity, DOF and force limit."""
        holds = self.table.cellWidget(row, 6).currentText()
        if holds == "force":
            return level
        held = {"response": level.pop("force"), "quantity": holds, "dof": self.table.cellWidget(row, 7).text()}
        if self._limits.get(row) is not None:
            held["force_limit"] = self._limits[row]
        return {**held, **level}

    def document(self) -> dict:
        """The plan document without limits (the Lab adds them)."""
        doc: dict = {**self._extra}
        if self.random.isChecked():
            doc["random"] = {"force_rms": self.random_rms.value(),
                             "band": [self.random_low.value(), self.random_high.value()],
                             "duration": self.random_duration.value()}
        if self.table.rowCount():
            doc["stepped_sine"] = self.levels()
        return doc

    # ------------------------------------------------------------------ actions
    def _edited(self, *_) -> None:
        self.touched = True
        self.table.resizeColumnsToContents()        # a cell's text changed its width (the header does not see it)
        self.lab.set_plan_document(self.document())

    def _add_clicked(self) -> None:
        levels = self.levels()
        last = dict(levels[-1]) if levels else dict(DEFAULT_LEVEL)
        key = "response" if "response" in last else "force"
        last[key] = round(last[key] * 2, 6)                  # the next level: twice the amplitude
        self._add_row(last)
        self._edited()

    def _remove_clicked(self) -> None:
        rows = sorted({i.row() for i in self.table.selectedIndexes()}, reverse=True) or [self.table.rowCount() - 1]
        for row in rows:
            if row >= 0:
                self.table.removeRow(row)
        self._edited()

    def _load_clicked(self) -> None:
        path, _ = QFileDialog.getOpenFileName(self, "Plan file", "", "Plan files (*.toml)")
        if path:
            self.lab.act(self.load, path)

    def load(self, path) -> None:
        """Fill the editor from a plan file (its limits go to the Rig tab)."""
        doc = plan_document(load_plan(path))
        self._extra = {k: doc[k] for k in ("settle", "control", "phase_resonance") if k in doc}
        self.random.blockSignals(True)
        self.random.setChecked("random" in doc)
        if "random" in doc:
            r = doc["random"]
            for spin, value in ((self.random_rms, r["force_rms"]), (self.random_low, r["band"][0]),
                                (self.random_high, r["band"][1]), (self.random_duration, r["duration"])):
                spin.blockSignals(True)
                spin.setValue(value)
                spin.blockSignals(False)
        self.random.blockSignals(False)
        self.lab.set_limits(doc["limits"]["max_force"], doc["limits"]["max_acceleration"])
        self.set_levels(doc["stepped_sine"])

    def load_default_for(self, rig_name: str) -> None:
        """The built-in rig's own plan, unless the operator already made one."""
        if not self.touched and rig_name in builtin_rigs():
            self.load(builtin_plan_path(rig_name))
            self.touched = False

    def _save_clicked(self) -> None:
        doc = self.lab.full_plan_document()
        path, _ = QFileDialog.getSaveFileName(self, "Save plan", "plan.toml", "Plan files (*.toml)")
        if path and doc is not None:     # the dialog asked before replacing a file
            self.lab.act(save_text, path, plan_toml(doc))

    def _show_check(self, ok: bool, message: str) -> None:
        self.validation.setText(message)
        self.validation.setStyleSheet("color:#2ca02c" if ok else "color:#d62728; font-weight:bold")


class LivePlots(pg.GraphicsLayoutWidget):
    """Time signals, FRFs, force, distortion and settling of the running campaign, redrawn by the frame clock."""

    def __init__(self, lab: Lab, clock: FrameClock, palette: LevelPalette, parent: QWidget | None = None):
        super().__init__(parent)
        self.lab = lab
        self.palette = palette
        self.feed: CampaignFeed | None = None
        self.line_frequency: float | None = None
        self.force_time = configure_plot(self.addPlot(0, 0), "Force", "time before now", "s", "force", "N",
                                         grid=False)
        self.acc_time = configure_plot(self.addPlot(0, 1), "Acceleration", "time before now", "s",
                                       "acceleration", "m/s²", grid=False)
        self.magnitude = configure_plot(self.addPlot(1, 0), "Receptance |H|", "frequency", "Hz", "|H|", "m/N",
                                        log_y=True)
        self.phase = configure_plot(self.addPlot(1, 1), "Receptance phase", "frequency", "Hz", "phase", "°")
        bottom = self.addLayout(2, 0, colspan=3)       # under the legends' column too: the titles want room
        self.force_level = configure_plot(bottom.addPlot(0, 0), "Force: achieved ●, target ┄",
                                          "frequency", "Hz", "force amplitude", "N")
        self.thd = configure_plot(bottom.addPlot(0, 1), "THD: response ●, force ┄",
                                  "frequency", "Hz", "THD", "%")
        self.settle = configure_plot(bottom.addPlot(0, 2), "Settling: waited ●, from the transient ◆, limit ×",
                                     "frequency", "Hz", "periods waited", None)
        modal = self.addLayout(3, 0, colspan=3)
        self.natural = configure_plot(modal.addPlot(0, 0),
                                      "Natural frequency against amplitude",
                                      "displacement amplitude", "m", "frequency", "Hz", log_x=True)
        self.damping = configure_plot(modal.addPlot(0, 1), "Damping ratio against amplitude",
                                      "displacement amplitude", "m", "damping ratio", None, log_x=True)
        self.damping.setXLink(self.natural)
        # the legends in a column of their own right of the plots, never over the data (docs/gui.md, "Legends"):
        # the channels beside the time plots, the runs and sensors beside the FRFs (for |H| and the phase alike),
        # the phase-resonance and response levels beside the modal plots
        self.legends = {"acceleration_time": side_legend(self.ci, self.acc_time, 0, 2),
                        "frf_magnitude": side_legend(self.ci, self.magnitude, 1, 2),
                        "natural_frequency": side_legend(modal, self.natural, 0, 2)}
        for plot in self.plots().values():      # long titles are cut short rather than push the legends away
            shrinkable_title(plot)
        self._modal_runs: tuple = ()                     # the finished response levels fitted so far
        self._locked_damping: dict[tuple, np.ndarray | None] = {}   # (run, points) -> damping by power balance
        self.phase.setXLink(self.magnitude)
        self.ci.layout.setRowStretchFactor(1, 2)
        self._time_curves: list[pg.PlotDataItem] = []
        self._run_curves: dict[tuple, pg.PlotDataItem] = {}
        self._drawn_end = -1
        self.time_redraw = Redraw(clock, self._draw_time, self, stale=self._new_samples)
        self.lines_redraw = Redraw(clock, self._draw_lines, self)

    def showEvent(self, event) -> None:  # noqa: N802 (Qt API)
        """The plots and legends fitted to the widget once shown: sized while the titles still set the minimum
        width (before :func:`shrinkable_title`), the layout kept that width and ran past the right edge."""
        super().showEvent(event)
        self.ci.setGeometry(QRectF(0, 0, self.viewport().width(), self.viewport().height()))

    def plots(self) -> dict[str, pg.PlotItem]:
        return {"force_time": self.force_time, "acceleration_time": self.acc_time, "frf_magnitude": self.magnitude,
                "frf_phase": self.phase, "force_achieved": self.force_level, "thd": self.thd,
                "settling": self.settle, "natural_frequency": self.natural, "damping": self.damping}

    def shown(self, plot: pg.PlotItem, run: str, what: str) -> tuple[np.ndarray, np.ndarray]:
        """The points a run's curve on ``plot`` shows now (``what``: a sensor DOF on the FRF plots; "achieved",
        "target", "response", "force", "steady", "transient" or "limit" on the others; "locked" for a
        phase-resonance run on the natural-frequency and damping plots, whose response levels are ``run`` "response levels",
        ``what`` e.g. "acceleration at x2"); empty before its first line."""
        curve = self._run_curves.get((id(plot), run, what))
        x, y = (None, None) if curve is None else curve.getOriginalDataset()
        return (np.empty(0), np.empty(0)) if x is None else (np.asarray(x), np.asarray(y))

    def shown_samples(self) -> int:
        """Samples per channel the time plots show now."""
        x = self._time_curves[0].getOriginalDataset()[0] if self._time_curves else None
        return 0 if x is None else len(x)

    def start(self, feed: CampaignFeed) -> None:
        """A new campaign: clear everything, one time curve per DAQ channel."""
        self.feed = feed
        self.line_frequency = None
        self._drawn_end = -1
        for plot in self.plots().values():
            plot.clear()
            if plot.legend is not None:
                plot.legend.clear()
        self._run_curves.clear()
        self._modal_runs = ()
        self._locked_damping = {}
        ring = feed.ring
        self._time_curves = []
        for i, channel in enumerate(ring.channels):
            plot = self.force_time if channel == "force" else self.acc_time
            curve = plot.plot([], [], pen=pg.mkPen(CHANNEL_COLORS[i % len(CHANNEL_COLORS)], width=1),
                              name=None if channel == "force" else channel, connect="finite")
            curve.setDownsampling(auto=True, method="peak")
            curve.setClipToView(True)
            self._time_curves.append(curve)
        feed.signals.lineMeasured.connect(self._on_line)
        feed.signals.randomMeasured.connect(lambda *_: self.lines_redraw.request())
        feed.signals.runEnded.connect(lambda *_: self.lines_redraw.now())

    def _on_line(self, run: str, index: int, m, target: float) -> None:
        self.line_frequency = m.frequency
        self.lines_redraw.request()

    def _new_samples(self) -> bool:
        return self.feed is not None and self.feed.ring.end != self._drawn_end

    # ------------------------------------------------------------------ drawing
    def time_window(self) -> float:
        """Seconds shown: a few periods of the current line, or a default before the first line."""
        ring = self.feed.ring
        if self.line_frequency is None:
            return min(TIME_WINDOW_DEFAULT, ring.capacity / ring.sample_rate)
        return float(np.clip(TIME_PERIODS / self.line_frequency, 64 / ring.sample_rate,
                             ring.capacity / ring.sample_rate))

    def _draw_time(self) -> None:
        ring = self.feed.ring
        self._drawn_end = ring.end
        window = self.time_window()
        t, data = ring.tail(int(window * ring.sample_rate))
        if not len(t):
            return
        t = t - t[-1]
        for i, curve in enumerate(self._time_curves):
            curve.setData(t, data[:, i])
        for plot in (self.force_time, self.acc_time):
            plot.setXRange(-window, 0, padding=0)

    def _curve(self, plot: pg.PlotItem, key: tuple, **style) -> pg.PlotDataItem:
        curve = self._run_curves.get((id(plot),) + key)
        if curve is None:
            curve = plot.plot([], [], **style)
            self._run_curves[(id(plot),) + key] = curve
        return curve

    def _draw_lines(self) -> None:
        live = self.lab.live
        if live is None:
            return
        for run in live.runs():
            if not len(run.frequency):
                continue
            if run.kind == "random":
                self._draw_random(run)
            else:
                self._draw_sine(run)
            if run.kind == "phase_resonance":
                self._draw_locked(run)
        self._draw_response_levels(live)

    def _draw_locked(self, run) -> None:
        """A phase-resonance run's locked points, natural frequency against displacement amplitude, one more as
        each force level locks."""
        dof = run.attrs["phase_dof"]
        w = 2 * np.pi * run.frequency
        X = np.abs(run.arrays[f"harmonics/acc:{dof}"][:, 1]) / w ** 2
        color = self.palette.color(run_control(run))
        style = {"pen": pg.mkPen(color, width=1.2), "symbol": "o", "symbolSize": 7, "symbolBrush": pg.mkBrush(color),
                 "symbolPen": None}
        self._curve(self.natural, (run.name, "locked"), name=f"phase resonance at {dof}",
                    **style).setData(X, run.frequency)
        zeta = self._power_balance(run)
        if zeta is not None:
            self._curve(self.damping, (run.name, "locked"), **style).setData(X, zeta)

    def _power_balance(self, run) -> np.ndarray | None:
        """The locked points' damping ratio by the power balance, with the modal constant from the session's own
        low-level FRF (analysis/prediction/backbone.py ``measured_power_balance``): computed once per point locked; None
        until the session holds such an FRF."""
        key = (run.name, len(run.frequency))
        if key not in self._locked_damping:
            try:
                m = measurements_from_session(self.lab.live)
            except InputError:       # lines the analysis refuses: no damping drawn, no crash
                m = None
            phase = None if m is None else next((p for p in m.phase if p.name == run.name), None)
            self._locked_damping[key] = None if phase is None else measured_power_balance(m, phase)
        return self._locked_damping[key]

    def _draw_response_levels(self, live) -> None:
        """The modal fit of every finished response-controlled level (analysis/prediction/backbone.py), one point per level:
        refitted only when another level finishes."""
        done = tuple(r.name for r in live.runs() if r.attrs.get("control") == "response" and r.status != "running")
        if done == self._modal_runs:
            return
        self._modal_runs = done
        try:
            finished = [r for r in measurements_from_session(live).sine if r.name in done]
        except InputError:           # lines the analysis refuses (a sensor that saw nothing): no points, no crash
            return
        for bb in measured_backbone(finished):
            _, f, zeta = bb.arrays()
            amplitude = bb.arrays()[0] / (2 * np.pi * f) ** POWER[bb.quantity]     # as a displacement
            style = {"pen": pg.mkPen("#444444", width=1.2), "symbol": "d", "symbolSize": 9,
                     "symbolBrush": pg.mkBrush("#444444"), "symbolPen": None}
            name = f"response levels at {bb.dof}"
            key = ("response levels", f"{bb.quantity} at {bb.dof}")
            self._curve(self.natural, key, name=name, **style).setData(amplitude, f)
            self._curve(self.damping, key, **style).setData(amplitude, zeta)

    def _draw_random(self, run) -> None:
        for p, dof in enumerate(run.sensor_dofs):
            h = run.frf[dof]
            self._curve(self.magnitude, (run.name, dof), pen=random_pen(p), name=f"random · {dof}").setData(
                run.frequency, finite_log(np.abs(h)))
            self._curve(self.phase, (run.name, dof), pen=random_pen(p)).setData(run.frequency,
                                                                                np.degrees(np.angle(h)))

    def _draw_sine(self, run) -> None:
        level = run_control(run)
        f, color = run.frequency, self.palette.color(level)
        order = np.argsort(f)
        for p, dof in enumerate(run.sensor_dofs):
            h = run.frf[dof][order]
            style = {"pen": pg.mkPen(color, width=1.2), "symbol": sensor_symbol(p), "symbolSize": 5,
                     "symbolBrush": pg.mkBrush(color), "symbolPen": None}
            self._curve(self.magnitude, (run.name, dof), name=f"{_level(run)} {run.direction} · {dof}",
                        **style).setData(f[order], finite_log(np.abs(h)))
            self._curve(self.phase, (run.name, dof), **style).setData(f[order], np.degrees(np.angle(h)))
        a = run.arrays
        self._curve(self.force_level, (run.name, "achieved"), pen=None, symbol="o", symbolSize=5,
                    symbolBrush=pg.mkBrush(color), symbolPen=None).setData(f, a["force_amplitude"])
        self._curve(self.force_level, (run.name, "target"), pen=self.palette.pen(level, dashed=True)).setData(
            f[order], a["force_target"][order])
        response = [a[k] for k in a if k.startswith("thd/acc:")]
        if response:
            self._curve(self.thd, (run.name, "response"), pen=None, symbol="o", symbolSize=5,
                        symbolBrush=pg.mkBrush(color), symbolPen=None).setData(
                f, 100 * np.max(np.stack(response), axis=0))
        if "thd/force" in a:
            self._curve(self.thd, (run.name, "force"), pen=self.palette.pen(level, dashed=True)).setData(
                f[order], 100 * a["thd/force"][order])
        steady = a["steady"].astype(bool)
        transient = a["transient"].astype(bool) if "transient" in a else np.zeros(len(f), bool)
        waited = steady & ~transient
        self._curve(self.settle, (run.name, "steady"), pen=None, symbol="o", symbolSize=5,
                    symbolBrush=pg.mkBrush(color), symbolPen=None).setData(f[waited], a["settle_periods"][waited])
        self._curve(self.settle, (run.name, "transient"), pen=None, symbol="d", symbolSize=7,
                    symbolBrush=None, symbolPen=pg.mkPen(color, width=1.2)).setData(
            f[transient], a["settle_periods"][transient])
        self._curve(self.settle, (run.name, "limit"), pen=None, symbol="x", symbolSize=9,
                    symbolBrush=pg.mkBrush("#d62728"), symbolPen=pg.mkPen("#d62728")).setData(
            f[~steady], a["settle_periods"][~steady])


class AcquirePanel(QWidget):
    """The Acquire tab (module docstring)."""

    def __init__(self, lab: Lab, clock: FrameClock, palette: LevelPalette, parent: QWidget | None = None):
        super().__init__(parent)
        self.lab = lab
        self._last_line_end = 0
        self._last_line = None                                       # the last LineMeasurement
        splitter = QSplitter(Qt.Orientation.Horizontal, self)
        outer = QHBoxLayout(self)
        outer.addWidget(splitter)

        left = QWidget()
        column = QVBoxLayout(left)
        self.editor = PlanEditor(lab)
        column.addWidget(self.editor)
        session_box = QGroupBox("Session file")
        row = QHBoxLayout(session_box)
        self.output = QLineEdit(str(Path.cwd() / default_session_name()))
        browse = QPushButton("Browse…")
        browse.clicked.connect(self._browse_output)
        row.addWidget(self.output, 1)
        row.addWidget(browse)
        column.addWidget(session_box)

        run_box = QGroupBox("Campaign")
        run_layout = QVBoxLayout(run_box)
        buttons = QHBoxLayout()
        self.start_button = QPushButton("Start")
        self.pause_button = QPushButton("Pause")
        self.abort_button = QPushButton("Abort")
        self.abort_button.setStyleSheet("font-weight:bold; color:#d62728")
        self.abort_button.setToolTip("Output off at once; the lines measured so far stay in the session")
        self.start_button.clicked.connect(lambda: self.lab.act(self.lab.start_campaign, self.output.text().strip()))
        self.pause_button.clicked.connect(self._pause_clicked)
        self.abort_button.clicked.connect(lambda: self.lab.abort("operator abort"))
        for b in (self.start_button, self.pause_button, self.abort_button):
            buttons.addWidget(b)
        run_layout.addLayout(buttons)
        self.arm_hint = QLabel()
        self.arm_hint.setWordWrap(True)
        run_layout.addWidget(self.arm_hint)
        self.progress = QProgressBar()
        self.progress.setFormat("%v / %m planned lines")
        self.progress.setValue(0)
        run_layout.addWidget(self.progress)
        self.run_label, self.eta_label, self.settle_label = QLabel("idle"), QLabel("ETA —"), QLabel("")
        for label in (self.run_label, self.eta_label, self.settle_label):
            label.setWordWrap(True)
            run_layout.addWidget(label)
        column.addWidget(run_box)

        events_box = QGroupBox("Events")
        events_layout = QVBoxLayout(events_box)
        self.events = QListWidget()
        events_layout.addWidget(self.events)
        column.addWidget(events_box, 1)
        # the plan, controls and events scroll on a short screen rather than push the window past it
        scroll = QScrollArea()
        scroll.setWidget(left)
        scroll.setWidgetResizable(True)
        scroll.setFrameShape(QFrame.Shape.NoFrame)
        scroll.setHorizontalScrollBarPolicy(Qt.ScrollBarPolicy.ScrollBarAlwaysOff)
        scroll.setMinimumWidth(left.minimumSizeHint().width() + scroll.verticalScrollBar().sizeHint().width())
        splitter.addWidget(scroll)

        self.live = LivePlots(lab, clock, palette)
        splitter.addWidget(self.live)
        splitter.setStretchFactor(0, 0)
        splitter.setStretchFactor(1, 1)
        splitter.setSizes([500, 1000])
        self.wait_redraw = Redraw(clock, self._draw_wait, self, stale=lambda: self.lab.campaign_running)

        lab.armedChanged.connect(self._show_armed)
        lab.campaignStarted.connect(self._campaign_started)
        lab.campaignFinished.connect(self._campaign_finished)
        lab.instrumentsChanged.connect(self._instruments_changed)
        self._planned = 0                  # the lines the plan of the progress bar plans
        lab.planChecked.connect(self._show_planned)
        self._show_armed(False, "not armed")
        self._show_planned()
        self._update_enabled()

    def plots(self) -> dict[str, pg.PlotItem]:
        return self.live.plots()

    # ------------------------------------------------------------------ actions
    def _browse_output(self) -> None:
        path, _ = QFileDialog.getSaveFileName(self, "Session file", self.output.text(), "Sessions (*.h5)")
        if path:
            self.output.setText(path)

    def _pause_clicked(self) -> None:
        if self.pause_button.text() == "Pause":
            self.lab.pause()
            self.pause_button.setText("Resume")
            self.run_label.setText("paused: output off, the current line is measured again on resume")
        else:
            self.lab.resume()
            self.pause_button.setText("Pause")

    def _instruments_changed(self) -> None:
        if self.lab.rig is not None:
            self.editor.load_default_for(self.lab.rig.name)
        self._update_enabled()

    # ------------------------------------------------------------------ campaign views
    def _show_planned(self, *_) -> None:
        """Before a campaign: 0 of the lines the checked plan plans, counted as its check counts them
        (:meth:`Plan.planned_lines`, the campaign's own count)."""
        if self.lab.campaign_running:
            return
        self._planned = self.lab.plan.planned_lines() if self.lab.plan is not None else 0
        self.progress.setRange(0, max(self._planned, 1))
        self.progress.setValue(0)
        self.progress.setFormat("%v / %m planned lines" if self._planned else "no plan")

    def _campaign_started(self, feed: CampaignFeed) -> None:
        self.events.clear()
        self._planned = self.lab.plan.planned_lines() if self.lab.plan is not None else 0
        self.progress.setRange(0, max(self._planned, 1))
        self.progress.setValue(0)
        self._last_line_end, self._last_line = 0, None
        self.pause_button.setText("Pause")
        self.live.start(feed)
        s = feed.signals
        s.runStarted.connect(lambda name, spec: self.run_label.setText(f"run {name}: {spec.kind}, {spec.force:g} N"))
        s.lineMeasured.connect(self._on_line)
        s.eventLogged.connect(self._add_event)
        s.progressed.connect(self._on_progress)
        self._update_enabled()

    def _on_line(self, run: str, index: int, m, target: float) -> None:
        self._last_line_end = self.lab.feed.ring.end
        self._last_line = m

    def _on_progress(self, done: int, total: int, eta, run: str) -> None:
        """Lines done against lines planned; refinement near resonance may add lines beyond the plan."""
        self.progress.setRange(0, max(total, 1))
        self.progress.setValue(min(done, total))
        added = total - self._planned if self._planned else 0      # lines refinement added to the plan so far
        if done > total:
            self.progress.setFormat(f"{done} lines ({total} planned; refinement added {done - total})")
            self.eta_label.setText("ETA — (more lines than planned: refining near a resonance)")
        else:
            self.progress.setFormat(f"%v / %m lines ({self._planned} planned + {added} added by refinement)"
                                    if added > 0 else "%v / %m planned lines")
            self.eta_label.setText(_format_eta(eta))

    def _draw_wait(self) -> None:
        """How long the line being measured has waited for steady state (stream time since the last line)."""
        feed = self.lab.feed
        if feed is None or not self.lab.campaign_running:
            return
        ring = feed.ring
        if ring.end < self._last_line_end:          # a new stream began (next run)
            self._last_line_end = 0
        waiting = (ring.end - self._last_line_end) / ring.sample_rate
        text = f"waiting for steady state: {waiting:.1f} s of signal at this line"
        if self._last_line is not None:
            text += "\n" + _line_path(self._last_line)
        self.settle_label.setText(text)

    def _add_event(self, kind: str, message: str) -> None:
        self.events.addItem(f"{kind}: {message}")
        if is_alarm(kind, message):
            self.events.item(self.events.count() - 1).setForeground(QColor(ALARM_COLOR))
        while self.events.count() > EVENTS_KEPT:
            self.events.takeItem(0)
        self.events.scrollToBottom()

    def _campaign_finished(self, text: str, aborted: bool) -> None:
        self.run_label.setText(("ABORTED — " if aborted else "finished — ") + text)
        self.settle_label.setText("")
        self.eta_label.setText("ETA —")
        self.live.lines_redraw.now()
        self.output.setText(str(Path(self.output.text()).with_name(default_session_name())))
        self._update_enabled()

    def _show_armed(self, armed: bool, message: str) -> None:
        self.arm_hint.setText(message if armed else "Not armed: connect and Arm on the Rig tab to enable Start.")
        self.arm_hint.setStyleSheet("color:#d62728; font-weight:bold" if armed else "color:#555")
        self._update_enabled()

    def _update_enabled(self) -> None:
        running = self.lab.campaign_running
        self.start_button.setEnabled(self.lab.armed_plan is not None and not running)
        self.pause_button.setEnabled(running)
        self.abort_button.setEnabled(running)
        self.editor.setEnabled(not running)
