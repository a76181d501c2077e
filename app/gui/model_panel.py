"""Model tab: the model -- opened, made from the rig, or a modal reference fitted to the session's lowest level as
``contactid reference`` fits it --, its laws per element with fitted values and uncertainties, measured against
predicted FRFs per level, the residual map, the ranked missing-effect candidates with their explanations and an
Add button each, an Auto button that follows that advice by itself, the elements no law of the library explains
with an Add button for their non-parametric part (docs/nonparametric.md), the error history (the error falling as
effects are added) and undo."""
from __future__ import annotations

import html

import numpy as np
import pyqtgraph as pg
from PySide6.QtCore import Qt
from PySide6.QtGui import QColor, QTextCursor
from PySide6.QtWidgets import (QAbstractItemView, QFileDialog, QFrame, QGroupBox, QHBoxLayout, QHeaderView, QLabel,
                               QPushButton, QSplitter, QTableWidget, QTableWidgetItem, QTextBrowser,
                               QTreeWidget, QTreeWidgetItem, QVBoxLayout, QWidget)

from analysis.prediction.comparison import gain_phrase
from analysis.mechanics.nonparametric import NAME as NONPARAMETRIC
from app.predict import KIND_WORDS

from app.kbar_view import legend_column

from .lab import Lab, save_text
from .plots import LevelPalette, configure_plot, finite_log, sensor_symbol
from .results import AnalysisView, PredictionView

CANDIDATE_COLUMNS = ("Element", "Law", "Error after (1 harmonic)", "Gain", "Significant", "")
AUTO_LINES_SHOWN = 6        # the automatic loop's lines scroll in a box this many lines high
WARNING = "color:#d62728; font-weight:bold"


def _laws_words(elements) -> str:
    """Each element's laws in one line: ``left: cubic + coulomb; right: no laws``."""
    return "; ".join(f"{name}: {' + '.join(laws) or 'no laws'}" for name, laws in elements)


class AutoLines(QTextBrowser):
    """The automatic loop's lines in a box of fixed height that scrolls to the newest: growing with them, the box
    would push Auto and Stop from under the pointer while the loop runs. ``setText`` / ``text`` as a QLabel's (rich
    text; ``text`` gives back what was set)."""

    def __init__(self, parent: QWidget | None = None):
        super().__init__(parent)
        self._text = ""
        self.setFrameShape(QFrame.Shape.NoFrame)
        self.setFixedHeight(AUTO_LINES_SHOWN * self.fontMetrics().lineSpacing() + 8)
        self.viewport().setAutoFillBackground(False)     # the panel's background, as the label it replaces

    def setText(self, text: str) -> None:  # noqa: N802 (the QLabel API)
        self._text = text
        self.setHtml(text)
        self.moveCursor(QTextCursor.MoveOperation.End)      # the newest line in view, once laid out

    def text(self) -> str:
        return self._text


class ModelPanel(QWidget):
    """The Model tab (module docstring)."""

    def __init__(self, lab: Lab, palette: LevelPalette, parent: QWidget | None = None):
        super().__init__(parent)
        self.lab = lab
        self.palette = palette
        self.view: AnalysisView | None = None
        layout = QVBoxLayout(self)

        bar = QHBoxLayout()
        self.model_label = QLabel("no model")
        self.model_label.setWordWrap(True)
        self.model_label.setTextInteractionFlags(Qt.TextInteractionFlag.TextSelectableByMouse)
        bar.addWidget(QLabel("<b>Model</b>"))
        bar.addStretch(1)
        self.open_button = QPushButton("Open model…")
        self.open_button.clicked.connect(self.open_model_dialog)
        self.starter_button = QPushButton("Starter model from rig")
        self.starter_button.setToolTip("The rig's structure with an unknown element (no laws) at each joint")
        self.starter_button.clicked.connect(lambda: self.lab.act(self.lab.use_starter_model))
        self.reference_button = QPushButton("Reference from session")
        self.reference_button.setToolTip("For a session without a random run: a modal structure fitted to its lowest "
                                         "level, as contactid reference fits it (its fit, its FRF error, a NONLINEAR "
                                         "warning when the next level moves), then the model on it with an element "
                                         "without laws at the drive point")
        self.reference_button.clicked.connect(lambda: self.lab.act(self.lab.make_reference))
        self.save_button = QPushButton("Save fitted model…")
        self.save_button.clicked.connect(self._save_model)
        self.analyze_button = QPushButton("Analyze")
        self.analyze_button.setStyleSheet("font-weight:bold")
        self.analyze_button.setToolTip("Identify, fit the laws, predict every run, rank the missing effects")
        self.analyze_button.clicked.connect(lambda: self.lab.act(self.lab.analyze))
        self.predict_button = QPushButton("Predict")
        self.predict_button.setToolTip("Predict the open session with the model as it is, nothing refitted: each "
                                       "level's error, the levels a fitted model did not see marked held out "
                                       "(as contactid predict)")
        self.predict_button.clicked.connect(lambda: self.lab.act(self.lab.predict))
        self.undo_button = QPushButton("Undo")
        self.undo_button.setToolTip("Take back the last added law")
        self.undo_button.clicked.connect(lambda: self.lab.act(self.lab.undo))
        for b in (self.open_button, self.starter_button, self.reference_button, self.save_button,
                  self.analyze_button, self.predict_button, self.undo_button):
            bar.addWidget(b)
        layout.addLayout(bar)
        # under the buttons, the window's width: where the model came from, its laws, its reference's warning
        layout.addWidget(self.model_label)
        self.error_label = QLabel("FRF error: — (press Analyze)")
        self.error_label.setStyleSheet("font-size:14pt; font-weight:bold")
        self.busy_label = QLabel("")
        # the error per level wraps under the headline: with a dozen levels one line would set the window's width
        self.level_errors = QLabel("")
        self.level_errors.setWordWrap(True)
        row = QHBoxLayout()
        row.addWidget(self.error_label, 1)
        row.addWidget(self.busy_label)
        layout.addLayout(row)
        layout.addWidget(self.level_errors)
        self.jump_label = QLabel("")
        self.jump_label.setToolTip("Where the predicted response is multivalued, each measured line is compared with "
                                   "the nearer stable branch (docs/workbench.md §3); ✕ marks lines measured on "
                                   "another branch than the swept prediction")
        self.jump_label.setWordWrap(True)
        layout.addWidget(self.jump_label)

        splitter = QSplitter(Qt.Orientation.Horizontal)
        layout.addWidget(splitter, 1)
        left = QWidget()
        column = QVBoxLayout(left)
        column.setContentsMargins(0, 0, 0, 0)
        laws_box = QGroupBox("Laws per element (fitted value ± standard error)")
        self.laws = QTreeWidget()
        self.laws.setHeaderHidden(True)
        QVBoxLayout(laws_box).addWidget(self.laws)
        column.addWidget(laws_box, 2)
        cand_box = QGroupBox("Missing effects, best first (error after adding each one)")
        cand_layout = QVBoxLayout(cand_box)
        self.candidates = QTableWidget(0, len(CANDIDATE_COLUMNS))
        self.candidates.setHorizontalHeaderLabels(CANDIDATE_COLUMNS)
        self.candidates.verticalHeader().setVisible(False)
        self.candidates.setSelectionBehavior(QAbstractItemView.SelectionBehavior.SelectRows)
        self.candidates.setEditTriggers(QAbstractItemView.EditTrigger.NoEditTriggers)
        self.candidates.horizontalHeader().setSectionResizeMode(QHeaderView.ResizeMode.ResizeToContents)
        self.candidates.horizontalHeader().setStretchLastSection(True)
        self.candidates.itemSelectionChanged.connect(self._show_explanation)
        self.unexplained = QWidget()            # one line and one Add button per unexplained element
        self.unexplained.setLayout(QVBoxLayout())
        self.unexplained.layout().setContentsMargins(0, 0, 0, 0)
        cand_layout.addWidget(self.unexplained)
        cand_layout.addWidget(self.candidates, 2)
        auto_row = QHBoxLayout()
        self.auto_button = QPushButton("Auto")
        self.auto_button.setToolTip("Follow the advice by itself: linear corrections, then add the top significant "
                                    "candidate, refit and rank again until nothing significant is left "
                                    "(as contactid analyze --auto)")
        self.auto_button.clicked.connect(self._start_auto)
        self.stop_button = QPushButton("Stop")
        self.stop_button.setToolTip("End the automatic loop before its next step (the steps taken stay)")
        self.stop_button.clicked.connect(self._stop_auto)
        self.stop_button.setEnabled(False)
        self.lab.autoProgress.connect(self._auto_line)
        self._auto_lines: list[str] = []
        self._auto_running = False
        self._stopping = False
        self.auto_label = AutoLines()
        buttons = QVBoxLayout()
        buttons.addWidget(self.auto_button)
        buttons.addWidget(self.stop_button)
        buttons.addStretch(1)
        auto_row.addLayout(buttons)
        auto_row.addWidget(self.auto_label, 1)
        cand_layout.addLayout(auto_row)
        self.explanation = QTextBrowser()
        self.explanation.setPlaceholderText("Select a candidate to read why it is proposed")
        cand_layout.addWidget(self.explanation, 1)
        column.addWidget(cand_box, 3)
        splitter.addWidget(left)

        self.graphics = pg.GraphicsLayoutWidget()
        self.frf = configure_plot(self.graphics.addPlot(0, 0, colspan=2),
                                  "Receptance |H|: measured (markers) and predicted (lines) per level",
                                  "frequency", "Hz", "|H|", "m/N", log_y=True)
        self.legend: pg.LegendItem | None = None
        self.residual = configure_plot(self.graphics.addPlot(1, 0), "Residual map: relative error per line",
                                       "frequency", "Hz", "|H pred − H meas| / |H meas|", None, log_y=True)
        self.history = configure_plot(self.graphics.addPlot(1, 1), "Error history", "step", None,
                                      "FRF error", None, log_y=True)
        self.graphics.ci.layout.setRowStretchFactor(0, 3)
        self.graphics.ci.layout.setRowStretchFactor(1, 2)
        splitter.addWidget(self.graphics)
        splitter.setSizes([520, 900])

        lab.analysisUpdated.connect(self._update)
        lab.predictionUpdated.connect(self._show_prediction)
        lab.analysisBusy.connect(self._show_busy)
        lab.modelChanged.connect(self._model_changed)
        # another session: the analysis of the one before goes (the lab dropped it), the model stays
        lab.sessionChanged.connect(self._model_changed)
        lab.instrumentsChanged.connect(self._update_enabled)
        self._model_changed()

    def plots(self) -> dict[str, pg.PlotItem]:
        return {"frf_measured_predicted": self.frf, "residual_map": self.residual, "error_history": self.history}

    # ------------------------------------------------------------------ actions
    def open_model_dialog(self) -> None:
        path, _ = QFileDialog.getOpenFileName(self, "Model file", "", "Model files (*.toml)")
        if path:
            self.lab.act(self.lab.load_model_file, path)

    def _save_model(self) -> None:
        if self.view is None:
            return
        path, _ = QFileDialog.getSaveFileName(self, "Save fitted model", "fitted-model.toml", "Model files (*.toml)")
        if path:            # the dialog asked before replacing a file
            self.lab.act(save_text, path, self.view.model_toml)

    def add_candidate(self, row: int) -> None:
        """The Add button of candidate ``row``: add its law to its element, refit, rank again."""
        c = self.view.candidates[row]
        self.lab.act(self.lab.add_law, c.element, c.law)

    # ------------------------------------------------------------------ the automatic loop
    def _start_auto(self) -> None:
        self._auto_lines = []
        self._stopping = False
        self._auto_running = self.lab.act(self.lab.auto)
        if self._auto_running:
            self.auto_label.setText("<b>Automatic loop</b> (running: each step appears as it is taken)")
        self._update_enabled()

    def _stop_auto(self) -> None:
        """Stop pressed: said at once, as the loop ends only before its next step (a discovery or a fit under way
        runs to its end first)."""
        self.lab.stop_auto()
        self._stopping = True
        self._show_auto_lines()
        self._update_enabled()

    def _auto_line(self, line: str) -> None:
        """A step of the running loop, shown as it is taken."""
        self._auto_lines.append(line)
        self._show_auto_lines()

    def _show_auto_lines(self) -> None:
        state = ("stopping: it ends before its next step; the steps taken stay" if self._stopping else "running")
        self.auto_label.setText("<br>".join([f"<b>Automatic loop</b> ({state})",
                                             *self._auto_lines]))

    # ------------------------------------------------------------------ views
    def _model_changed(self) -> None:
        """Another model or session: nothing of an analysis or prediction before stays, the model as loaded."""
        self._clear_results()
        self.error_label.setText("FRF error: — (press Analyze)")
        self._show_model()
        self._update_enabled()

    def _clear_results(self) -> None:
        self.view = None
        self.error_label.setText("")
        self.level_errors.setText("")
        self.jump_label.setText("")
        self.auto_label.setText("")
        self._auto_lines = []
        self.laws.clear()
        self.candidates.setRowCount(0)
        self._clear_unexplained()
        self.explanation.clear()
        for plot in self.plots().values():
            plot.clear()
        self._set_legend([])

    def _show_model(self) -> None:
        """The model as loaded: its name, each element's laws, and the reference it was made from."""
        self._show_label()
        reference = self._add_reference_item()
        if reference is not None:
            reference.setExpanded(True)
        if self.lab.model is not None:
            for el in self.lab.model.elements:
                where = el.dofs[0] if el.grounded else f"{el.dofs[0]}-{el.dofs[1]}"
                parts = [t.law.name for t in el.laws] + ([NONPARAMETRIC] if el.nonparametric is not None else [])
                laws = " + ".join(parts) or "no laws (identify kbar only)"
                QTreeWidgetItem(self.laws, [f"{el.name} ({where}): {laws}"])

    def _show_label(self) -> None:
        """Where the model came from, and the laws it holds now: the model as loaded, or as the analysis on this
        tab fitted it (words from before a fit never stand beside fitted laws)."""
        model = self.lab.model
        if model is None:
            self.model_label.setText("no model: open one, make a starter model from the rig, or a reference from "
                                     "the session")
            return
        if self.view is not None:
            laws = _laws_words((el.name, [law.law for law in el.laws] + ([NONPARAMETRIC] if el.nonparametric else []))
                               for el in self.view.elements)
            held = f"as fitted here: {laws}"
        else:
            laws = _laws_words((el.name, [t.law.name for t in el.laws] +
                                ([NONPARAMETRIC] if el.nonparametric is not None else [])) for el in model.elements)
            held = f"as loaded: {laws}" if model.elements else "no elements"
        text = f"{html.escape(self.lab.model_label)} — {html.escape(held)}"
        reference = self.lab.reference
        if reference is not None:
            fit = reference.fit
            modes = ", ".join(f"{f:.5g} Hz, damping {z:.3g}" for f, z in zip(fit.frequency, fit.damping))
            text += (f"<br>reference: {modes}; FRF error {reference.frf_error:.3g} on its level "
                     f"(tree below: the whole fit)")
            if reference.nonlinear:
                text += (f"<br><span style='{WARNING}'>NONLINEAR already between the two lowest levels "
                         f"({html.escape(reference.next_run)}): the reference may hold part of the joint's effect "
                         "at this level</span>")
        self.model_label.setText(text)

    def _add_reference_item(self) -> QTreeWidgetItem | None:
        """The reference the model was made from, as ``contactid reference`` prints it, atop the laws."""
        reference = self.lab.reference
        if reference is None:
            return None
        top = QTreeWidgetItem(self.laws, [f"structure: modal reference from run {reference.run}"])
        for line in reference.text().splitlines()[1:]:
            item = QTreeWidgetItem(top, [line.strip()])
            item.setToolTip(0, line.strip())
            if "NONLINEAR" in line:
                item.setForeground(0, QColor("#d62728"))
        return top

    def _update(self, view: AnalysisView) -> None:
        # analysis results arrive a few times a minute at most: drawn at once, not paced by the frame clock
        self.view = view
        self._draw()

    def _show_busy(self, busy: bool) -> None:
        self.busy_label.setText("working …" if busy else "")
        if not busy:
            self._auto_running = self._stopping = False
        self._update_enabled()

    def _update_enabled(self) -> None:
        busy = self.lab.analysis_tasks.busy
        have_view = self.view is not None
        self.analyze_button.setEnabled(not busy and self.lab.model is not None)
        self.predict_button.setEnabled(not busy and self.lab.model is not None and self.lab.session_path is not None
                                       and not self.lab.campaign_running)
        self.auto_button.setEnabled(not busy and have_view)
        self.stop_button.setEnabled(busy and self._auto_running and not self._stopping)
        self.undo_button.setEnabled(not busy and have_view and self.view.can_undo)
        self.save_button.setEnabled(have_view)
        self.starter_button.setEnabled(self.lab.rig is not None)
        self.reference_button.setEnabled(not busy and self.lab.session_path is not None
                                         and not self.lab.campaign_running)
        for row in range(self.candidates.rowCount()):
            button = self.candidates.cellWidget(row, len(CANDIDATE_COLUMNS) - 1)
            if button is not None:
                button.setEnabled(not busy)
        for button in self.unexplained.findChildren(QPushButton):
            button.setEnabled(not busy)

    def _show_prediction(self, view: PredictionView) -> None:
        """A prediction with nothing refitted: the pooled error of each kind of level above, the table in the
        explanation box, the FRFs and residuals drawn with each run's kind in the legend."""
        kinds = "; ".join(f"{KIND_WORDS[kind]} levels {error:.3g}" for kind, error in view.prediction.errors.items())
        # the model predicted is the model as loaded: an analysis shown before (its fitted laws, candidates,
        # history) is not what these numbers are of
        self._clear_results()
        self._show_model()
        self.error_label.setText(f"Prediction, nothing refitted: {kinds}")
        self.explanation.setHtml(f"<pre>{html.escape(view.text)}</pre>")
        self._draw_frf(view)
        self._update_enabled()

    def _show_explanation(self) -> None:
        rows = {i.row() for i in self.candidates.selectedIndexes()}
        if self.view is None or not rows:
            return
        c = self.view.candidates[min(rows)]
        self.explanation.setPlainText(f"{c.element}:{c.law} — single-harmonic error {c.error:.4g} ({gain_phrase(c.gain).replace('x', '×', 1)}, "
                                      f"{'significant' if c.significant else 'not significant'})\n\n{c.explanation}")

    def _draw(self) -> None:
        view = self.view
        if view is None:
            return
        levels = sorted(view.error_by_level, key=lambda e: e.control.order())
        by_level = ", ".join(f"{e.label()}: {e.error:.3g}" for e in levels)
        single = "" if view.single_harmonic_error == view.error else \
            f"; single-harmonic {view.single_harmonic_error:.4g}, as the candidates' errors"
        self.error_label.setText(f"FRF error {view.error:.4g}")
        self._show_label()
        self.level_errors.setText(f"by level: {by_level}{single}")
        self.jump_label.setText("<br>".join(["<b>Jumps</b> (predicted fold against measured):", *view.jumps])
                                if view.jumps else "")
        self.auto_label.setText("<br>".join(["<b>Automatic loop</b>", *view.auto]) if view.auto else "")
        self._draw_laws(view)
        self._draw_unexplained(view)
        self._draw_candidates(view)
        self._draw_frf(view)
        self._draw_history(view)
        self._update_enabled()

    def _draw_laws(self, view: AnalysisView) -> None:
        self.laws.clear()
        reference = self._add_reference_item()
        for el in view.elements:
            top = QTreeWidgetItem(self.laws, [f"{el.name} ({el.where}): {el.verdict}"])
            if not el.laws:
                QTreeWidgetItem(top, ["no laws yet (kbar identified only)"])
            for law in el.laws:
                item = QTreeWidgetItem(top, [law.law])
                for p in law.params:
                    QTreeWidgetItem(item, [p.text()])
            if el.nonparametric:
                QTreeWidgetItem(top, [el.nonparametric])
        self.laws.expandAll()
        if reference is not None:        # its summary and warning stand above; the laws want the tree's room
            reference.setExpanded(False)

    def _clear_unexplained(self) -> None:
        layout = self.unexplained.layout()
        while layout.count():
            row = layout.takeAt(0).widget()
            row.setParent(None)                 # gone from the panel now, deleted when Qt is done with it
            row.deleteLater()

    def _draw_unexplained(self, view: AnalysisView) -> None:
        """Each element the laws leave unexplained: the finding, what a non-parametric part gives, its Add."""
        self._clear_unexplained()
        for u in view.unexplained:
            row = QWidget()
            line = QHBoxLayout(row)
            line.setContentsMargins(0, 0, 0, 0)
            label = QLabel(f"<b>Not explained by the library:</b> {u.element}, kbar {u.noise_ratio:.0f}× the noise "
                           f"off its laws. A non-parametric part gives error {u.error:.3g} (now "
                           f"{u.error_before:.3g}): a better law could gain up to ×{u.gain:.3g}")
            label.setWordWrap(True)
            label.setToolTip(u.finding)
            line.addWidget(label, 1)
            button = QPushButton("Add non-parametric")
            button.setToolTip(f"Add a non-parametric part to {u.element} (kbar smoothed from its samples), refit "
                              f"and rank again\n\n{u.finding}")
            button.clicked.connect(lambda _=False, e=u.element: self.lab.act(self.lab.add_law, e, NONPARAMETRIC))
            line.addWidget(button)
            self.unexplained.layout().addWidget(row)

    def _draw_candidates(self, view: AnalysisView) -> None:
        table = self.candidates
        table.setRowCount(len(view.candidates))
        for row, c in enumerate(view.candidates):
            cells = (c.element, c.law, f"{c.error:.4g}", gain_phrase(c.gain).replace("x", "×", 1), "yes" if c.significant else "no")
            for col, text in enumerate(cells):
                item = QTableWidgetItem(text)
                item.setToolTip(c.explanation)
                table.setItem(row, col, item)
            button = QPushButton("Add")
            button.setToolTip(f"Add {c.law} to {c.element}, refit and rank again")
            button.clicked.connect(lambda _=False, r=row: self.add_candidate(r))
            table.setCellWidget(row, len(CANDIDATE_COLUMNS) - 1, button)
        if view.candidates:
            table.selectRow(0)
            self._show_explanation()          # row 0 may have been selected already: no selection signal
        elif not view.ranked:
            self.explanation.setPlainText("Not ranked: the automatic loop was stopped before it ranked the missing "
                                          "effects. Auto goes on from the model as it is; Undo takes back its last "
                                          "step and ranks again.")
        else:
            self.explanation.setPlainText("No candidate: every law of the library was tried" +
                                          ("; an element with a non-parametric part gets none (it explains that "
                                           "element's kbar)." if any(el.nonparametric for el in view.elements)
                                           else "."))

    def _draw_frf(self, view: AnalysisView | PredictionView) -> None:
        """Measured and predicted FRFs and the residual map, runs in level order (:meth:`Control.order`, up
        before down); the legend beside the plots names each run by how its level was held, and each sensor by
        its marker."""
        for plot in (self.frf, self.residual):
            plot.clear()
        self.palette.include(r.control for r in view.runs)
        runs = sorted(view.runs, key=lambda r: (r.control.order(), r.direction != "up", r.name))
        entries, sensors = [], {}
        for run in runs:
            color = self.palette.color(run.control)
            order = np.argsort(run.frequency_hz)
            f = run.frequency_hz[order]
            predicted = view.predicted[run.name][order]
            for p, dof in enumerate(run.sensor_dofs):
                sensors.setdefault(dof, sensor_symbol(p))
                self.frf.plot(f, finite_log(np.abs(run.receptance[order, p])), pen=None, symbol=sensor_symbol(p),
                              symbolSize=5, symbolBrush=pg.mkBrush(color), symbolPen=None)
                self.frf.plot(f, finite_log(np.abs(predicted[:, p])), pen=pg.mkPen(color, width=1.5))
            self.residual.plot(f, finite_log(view.residual_map[run.name][order]), pen=pg.mkPen(color, width=1),
                               symbol="o", symbolSize=4, symbolBrush=pg.mkBrush(color), symbolPen=None)
            self._draw_other_branch(view, run, order, color)
            entries.append(({"pen": pg.mkPen(color, width=2)},
                            f"{run.control.label()} {run.direction} · {', '.join(run.sensor_dofs)}"
                            + (f" ({view.tags[run.name]})" if run.name in view.tags else "")))
        entries += [({"pen": None, "symbol": symbol, "symbolSize": 7, "symbolBrush": pg.mkBrush("#555"),
                      "symbolPen": None}, f"measured at {dof}") for dof, symbol in sensors.items()]
        self._set_legend(entries)

    def _set_legend(self, entries) -> None:
        """The legend in its own column right of the plots (never over the data)."""
        if self.legend is not None:
            self.graphics.removeItem(self.legend)
            self.legend = None
        if entries:
            self.legend = legend_column(self.graphics.ci, entries, row=0, col=2, rowspan=2)
        self.frf.legend = self.legend          # it is the FRF plot's legend, only placed beside the plots

    def legend_names(self) -> list[str]:
        return [] if self.legend is None else [label.text for _, label in self.legend.items]

    def _draw_other_branch(self, view: AnalysisView, run, order, color) -> None:
        """Lines measured on another branch than the swept prediction: a cross on the residual map and the
        branch they were compared with on the FRF plot."""
        other = view.other_branch.get(run.name)
        if other is None or not other.any():
            return
        lines = order[other[order]]
        f = run.frequency_hz[lines]
        self.residual.plot(f, finite_log(view.residual_map[run.name][lines]), pen=None, symbol="x", symbolSize=14,
                           symbolBrush=pg.mkBrush(color), symbolPen=pg.mkPen(color, width=2))
        for p in range(len(run.sensor_dofs)):
            self.frf.plot(f, finite_log(np.abs(view.compared[run.name][lines, p])), pen=None, symbol="x",
                          symbolSize=12, symbolPen=pg.mkPen(color, width=2), symbolBrush=None)

    def _draw_history(self, view: AnalysisView) -> None:
        self.history.clear()
        steps = np.array([h.step for h in view.history], float)
        errors = np.array([h.error for h in view.history], float)
        self.history.plot(steps, finite_log(errors), pen=pg.mkPen("#1f77b4", width=2), symbol="o", symbolSize=8,
                          symbolBrush=pg.mkBrush("#1f77b4"))
        last = len(view.history) - 1
        for h in view.history:
            action = h.action.replace("add ", "+ ", 1)
            # labels alternate above and below the line so neighbours with close errors do not overlap; the last
            # one ends at its point, the first starts there, so neither leaves the plot
            x_anchor = 1.0 if h.step == last and last > 0 else 0.0 if h.step == 0 else 0.5
            label = pg.TextItem(f"{action}\n{h.error:.3g}", color="#333",
                                anchor=(x_anchor, 1.15) if h.step % 2 == 0 else (x_anchor, -0.15))
            self.history.addItem(label)
            label.setPos(h.step, np.log10(h.error) if h.error > 0 else 0.0)
        self.history.setXRange(-0.5, max(len(view.history) - 0.5, 1.5), padding=0.05)
        logs = np.log10(errors[errors > 0]) if (errors > 0).any() else np.zeros(1)
        span = logs.max() - logs.min()
        # room above and below the points for their labels (view coordinates are decades on a log axis)
        self.history.setYRange(logs.min() - 0.3 * span - 0.3, logs.max() + 0.3 * span + 0.3, padding=0)
        ticks = [(h.step, str(h.step)) for h in view.history]
        self.history.getAxis("bottom").setTicks([ticks])
