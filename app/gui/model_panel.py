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
from PySide6.QtCore import QPointF, QRectF, Qt
from PySide6.QtGui import QColor, QFontMetrics, QTextCursor
from PySide6.QtWidgets import (QAbstractItemView, QFileDialog, QFrame, QGroupBox, QHBoxLayout, QHeaderView, QLabel,
                               QPushButton, QSplitter, QTableWidget, QTableWidgetItem, QTextBrowser,
                               QTreeWidget, QTreeWidgetItem, QVBoxLayout, QWidget)

from analysis.prediction.comparison import gain_phrase
from analysis.mechanics.nonparametric import NAME as NONPARAMETRIC
from app.analyze import measured_from_why
from app.predict import KIND_WORDS

from app.kbar_view import legend_column, level_panels, panel_title

from .lab import Lab, save_text
from .plots import LevelPalette, SpacedAxis, configure_plot, finite_log, sensor_symbol, shrinkable_title
from .results import AnalysisView, PredictionView

CANDIDATE_COLUMNS = ("Element", "Law", "Error after\n(1 harmonic)", "Gain", "Significant", "")
CANDIDATE_HEADER_TIPS = ("The element the law would be added to",
                         ("The law of the library added (its full name in the row's tooltip where the column is "
                          "too narrow)"),
                         ("The FRF error with the law added and refitted, by the single-harmonic measure the "
                          "ranking uses"),
                         "How much the error falls against the model's single-harmonic error",
                         "Whether the fall passes the significance test (the reason in the explanation below)",
                         "Add the law to its element, refit and rank again")
LAW_COLUMN = 1              # the column that gives up width (its text elided, whole in the tooltip)
AUTO_LINES_SHOWN = 6        # the automatic loop's lines scroll in a box this many lines high
WARNING = "color:#d62728; font-weight:bold"
FRF_TITLE = "Receptance |H|: measured (markers) and predicted (lines) per level"
HISTORY_GAP = 5             # pixels between an error-history point and its label
HISTORY_LABEL_WIDTH = 150   # pixels: an error-history label's action is elided to this width ...
HISTORY_MIN_LETTERS = 14    # ... and left out where fewer of its letters would stay


def _laws_words(elements) -> str:
    """Each element's laws in one line: ``left: cubic + coulomb; right: no laws``."""
    return "; ".join(f"{name}: {' + '.join(laws) or 'no laws'}" for name, laws in elements)


LAWS_ROWS = 10
"""Rows of the laws tree shown by default, above the candidates (the user moves the splitter between them)."""
LAWS_MIN_ROWS = 5
"""Rows of the laws tree shown at least, whatever the candidates, the Auto lines and the explanation ask."""


def _indented(text: str) -> str:
    """A step and the reason under it (:meth:`analysis.loop.auto.AutoStep.text`) as the label's rich text: the
    reason on its own line, indented, where the step is shown."""
    return text.replace("\n", "<br>&nbsp;&nbsp;&nbsp;&nbsp;")


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
        # rich text always: its words are HTML-escaped, and Qt's guess would show an escaped quote as "&#x27;"
        self.model_label.setTextFormat(Qt.TextFormat.RichText)
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
        # the laws above the candidates, apart by a splitter the user can move: the candidates, the Auto lines and
        # the explanation that come with Auto take their own share, never the laws' (LAWS_ROWS rows by default)
        left = QSplitter(Qt.Orientation.Vertical)
        left.setChildrenCollapsible(False)
        self.left_splitter = left
        laws_box = QGroupBox("Laws per element (fitted value ± standard error)")
        self.laws = QTreeWidget()
        self.laws.setHeaderHidden(True)
        self.laws.setMinimumHeight(LAWS_MIN_ROWS * self._tree_row_height() + 6)
        QVBoxLayout(laws_box).addWidget(self.laws)
        left.addWidget(laws_box)
        cand_box = QGroupBox("Missing effects, best first (error after adding each one)")
        cand_layout = QVBoxLayout(cand_box)
        self.candidates = QTableWidget(0, len(CANDIDATE_COLUMNS))
        self.candidates.setHorizontalHeaderLabels(CANDIDATE_COLUMNS)
        self.candidates.verticalHeader().setVisible(False)
        self.candidates.setSelectionBehavior(QAbstractItemView.SelectionBehavior.SelectRows)
        self.candidates.setEditTriggers(QAbstractItemView.EditTrigger.NoEditTriggers)
        # every column as wide as its contents but the law's, which takes the rest and elides what does not fit:
        # all of them, the Add buttons too, stay in view at the width a 1366 px screen leaves the table
        header = self.candidates.horizontalHeader()
        header.setSectionResizeMode(QHeaderView.ResizeMode.ResizeToContents)
        header.setSectionResizeMode(LAW_COLUMN, QHeaderView.ResizeMode.Stretch)
        header.setStretchLastSection(False)
        self.candidates.setTextElideMode(Qt.TextElideMode.ElideMiddle)
        for col, tip in enumerate(CANDIDATE_HEADER_TIPS):
            self.candidates.horizontalHeaderItem(col).setToolTip(tip)
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
        self.stop_button.setToolTip("End the automatic loop now: the step under way is undone, the steps taken stay")
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
        left.addWidget(cand_box)
        left.setStretchFactor(0, 1)
        left.setStretchFactor(1, 1)
        # the default: LAWS_ROWS rows of the tree, the rest to the candidates (a 1366 x 768 screen leaves about
        # 560 px to the two); the user moves the line between them
        laws_height = LAWS_ROWS * self._tree_row_height() + 40        # and the box's title and frame
        left.setSizes([laws_height, max(560 - laws_height, 260)])
        splitter.addWidget(left)

        self.graphics = pg.GraphicsLayoutWidget()
        # the FRFs' small multiples side by side in a row of their own (one panel while one holds the levels)
        self.frf_area = self.graphics.addLayout(0, 0, colspan=2)
        self.frf = self._frf_plot(0)
        self.frf_panels = [self.frf]
        self.legend: pg.LegendItem | None = None
        self.residual = configure_plot(self.graphics.addPlot(1, 0), "Residual map: relative error per line",
                                       "frequency", "Hz", "|H pred − H meas| / |H meas|", None, log_y=True)
        self.history = configure_plot(self.graphics.addPlot(1, 1), "Error history", "step", None,
                                      "FRF error", None, log_y=True)
        self._history_labels: list[tuple] = []
        self._history_font = self.font()
        self._history_font.setPointSizeF(8)
        self.history.getViewBox().sigResized.connect(self._place_history_labels)
        # the history as wide as the residual map (not narrowed by the other's longer title): its labels want room
        for plot in (self.residual, self.history):
            plot.setPreferredWidth(300)
            shrinkable_title(plot)
        self.graphics.ci.layout.setColumnStretchFactor(0, 1)
        self.graphics.ci.layout.setColumnStretchFactor(1, 1)
        self.graphics.ci.layout.setRowStretchFactor(0, 3)
        self.graphics.ci.layout.setRowStretchFactor(1, 2)
        splitter.addWidget(self.graphics)
        # the candidates' six columns want about 520 px: the plots give that much up on a 1366 px screen
        splitter.setSizes([600, 820])

        lab.analysisUpdated.connect(self._update)
        lab.predictionUpdated.connect(self._show_prediction)
        lab.analysisBusy.connect(self._show_busy)
        lab.modelChanged.connect(self._model_changed)
        # another session: the analysis of the one before goes (the lab dropped it), the model stays
        lab.sessionChanged.connect(self._model_changed)
        lab.instrumentsChanged.connect(self._update_enabled)
        self._model_changed()

    def _tree_row_height(self) -> int:
        """The height of a row of the laws tree (its font's line and the item margins)."""
        return self.laws.fontMetrics().height() + 1

    def plots(self) -> dict[str, pg.PlotItem]:
        extra = {f"frf_measured_predicted_{k + 1}": p for k, p in enumerate(self.frf_panels[1:], 1)}
        return {"frf_measured_predicted": self.frf, **extra, "residual_map": self.residual,
                "error_history": self.history}

    def _frf_plot(self, column: int) -> pg.PlotItem:
        # the frequency labels spaced for the panel's width: small multiples are narrow (SpacedAxis)
        plot = configure_plot(self.frf_area.addPlot(0, column, axisItems={"bottom": SpacedAxis("bottom")}),
                              FRF_TITLE, "frequency", "Hz",
                              "|H|" if column == 0 else "", "m/N" if column == 0 else None, log_y=True)
        shrinkable_title(plot)      # cut where the panel is narrow, never widening the plots
        if column:
            plot.setXLink(self.frf)
        return plot

    def _frf_panels(self, panels: list) -> list[pg.PlotItem]:
        """A plot per panel of levels (:func:`level_panels`), titled by the levels it holds where there are
        several; the panels beyond those asked for go."""
        while len(self.frf_panels) > max(len(panels), 1):
            self.frf_area.removeItem(self.frf_panels.pop())
        while len(self.frf_panels) < len(panels):
            self.frf_panels.append(self._frf_plot(len(self.frf_panels)))
        for plot, panel in zip(self.frf_panels, panels):
            title = FRF_TITLE if len(panels) == 1 else panel_title(panel)
            if plot.titleLabel.text != title:
                plot.setTitle(title, size="10pt")
        return self.frf_panels

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
        """Stop pressed: said at once; the loop ends within its next fit evaluation or predicted line
        (:mod:`analysis.common.interrupt`), the step under way undone."""
        self.lab.stop_auto()
        self._stopping = True
        self._show_auto_lines()
        self._update_enabled()

    def _auto_line(self, line: str) -> None:
        """A step of the running loop, shown as it is taken."""
        self._auto_lines.append(line)
        self._show_auto_lines()

    def _show_auto_lines(self) -> None:
        state = ("stopping: the step under way is undone; the steps taken stay" if self._stopping else "running")
        self.auto_label.setText("<br>".join([f"<b>Automatic loop</b> ({state})", *map(_indented, self._auto_lines)]))

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
        self._history_labels = []
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
        text = f"{html.escape(self.lab.model_label, quote=False)} — {html.escape(held, quote=False)}"
        reference = self.lab.reference
        if reference is not None:
            fit = reference.fit
            modes = ", ".join(f"{f:.5g} Hz, damping {z:.3g}" for f, z in zip(fit.frequency, fit.damping))
            text += (f"<br>reference: {modes}; FRF error {reference.frf_error:.3g} on its level "
                     f"(tree below: the whole fit)")
            if reference.nonlinear:
                text += (f"<br><span style='{WARNING}'>NONLINEAR already between the two lowest levels "
                         f"({html.escape(reference.next_run, quote=False)}): the reference may hold part of the "
                         "joint's effect "
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
        self.explanation.setHtml(f"<pre>{html.escape(view.text, quote=False)}</pre>")
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
        floor = f"\n{view.error_floor}" if view.error_floor else ""
        self.level_errors.setText(f"by level: {by_level}{single}{floor}")
        self.jump_label.setText("<br>".join(["<b>Jumps</b> (predicted fold against measured):", *view.jumps])
                                if view.jumps else "")
        self.auto_label.setText("<br>".join(["<b>Automatic loop</b>", *map(_indented, view.auto)]) if view.auto else "")
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
            elif el.in_reference:
                note = QTreeWidgetItem(top, ["laws measured from their small-amplitude state (in the reference)"
                                             if el.origin is None else
                                             "laws measured from the joint's state at the reference's level"])
                why = measured_from_why(el.origin)
                note.setToolTip(0, why[0].upper() + why[1:] + ".")
            for law in el.laws:
                item = QTreeWidgetItem(top, [f"{law.law}, read as {law.limit}" if law.limit else law.law])
                if law.why:
                    item.setToolTip(0, law.why)
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
                item.setToolTip(f"{c.element}:{c.law}\n\n{c.explanation}")      # the law whole where elided
                table.setItem(row, col, item)
            button = QPushButton("Add")
            # as narrow as its word: a style's minimum button width would take the law column's room
            button.setFixedWidth(button.fontMetrics().horizontalAdvance("Add") + 20)
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
        its marker. The FRFs of more levels than one plot holds are small multiples, as frf.png's
        (:func:`level_panels`)."""
        self.palette.include(r.control for r in view.runs)
        panels = level_panels(r.control for r in view.runs)
        plots = {c.key(): plot for plot, panel in zip(self._frf_panels(panels), panels) for c in panel}
        for plot in (*self.frf_panels, self.residual):
            plot.clear()
        runs = sorted(view.runs, key=lambda r: (r.control.order(), r.direction != "up", r.name))
        entries, sensors = [], {}
        for run in runs:
            color = self.palette.color(run.control)
            frf = plots[run.control.key()]
            order = np.argsort(run.frequency_hz)
            f = run.frequency_hz[order]
            predicted = view.predicted[run.name][order]
            for p, dof in enumerate(run.sensor_dofs):
                sensors.setdefault(dof, sensor_symbol(p))
                frf.plot(f, finite_log(np.abs(run.receptance[order, p])), pen=None, symbol=sensor_symbol(p),
                         symbolSize=5, symbolBrush=pg.mkBrush(color), symbolPen=None)
                frf.plot(f, finite_log(np.abs(predicted[:, p])), pen=pg.mkPen(color, width=1.5))
            self.residual.plot(f, finite_log(view.residual_map[run.name][order]), pen=pg.mkPen(color, width=1),
                               symbol="o", symbolSize=4, symbolBrush=pg.mkBrush(color), symbolPen=None)
            self._draw_other_branch(view, run, order, color, frf)
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

    def _draw_other_branch(self, view: AnalysisView, run, order, color, frf: pg.PlotItem) -> None:
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
            frf.plot(f, finite_log(np.abs(view.compared[run.name][lines, p])), pen=None, symbol="x",
                     symbolSize=12, symbolPen=pg.mkPen(color, width=2), symbolBrush=None)

    def _draw_history(self, view: AnalysisView) -> None:
        """The error after each step, a point per step numbered on the axis, each labelled with its action and
        error (:meth:`_place_history_labels`; the whole action in the label's tooltip)."""
        self.history.clear()
        steps = np.array([h.step for h in view.history], float)
        errors = np.array([h.error for h in view.history], float)
        self.history.plot(steps, finite_log(errors), pen=pg.mkPen("#1f77b4", width=2), symbol="o", symbolSize=8,
                          symbolBrush=pg.mkBrush("#1f77b4"))
        self._history_labels = []
        for h in view.history:
            # a white ground: where the line passes behind a label, the label stays readable
            label = pg.TextItem("", color="#333", fill=pg.mkBrush(255, 255, 255, 215))
            label.textItem.setFont(self._history_font)
            label.textItem.document().setDocumentMargin(1)
            label.setToolTip(f"step {h.step}: {h.action}; FRF error {h.error:.4g}")
            label.setZValue(20)
            self.history.addItem(label)
            label.setPos(h.step, np.log10(h.error) if h.error > 0 else 0.0)
            self._history_labels.append((h, label))
        self.history.setXRange(-0.5, max(len(view.history) - 0.5, 1.5), padding=0)
        ticks = [(h.step, str(h.step)) for h in view.history]
        self.history.getAxis("bottom").setTicks([ticks])
        self._place_history_labels()

    def _place_history_labels(self, *_) -> None:
        """Fit the history's labels to the plot as it is sized now (again at every resize), none over another,
        over a point or past the plot's edges.

        A label holds the step's action (elided in the middle to HISTORY_LABEL_WIDTH, whole in the tooltip) over
        its error, or the error alone where the action does not fit. It is centred on its point, HISTORY_GAP
        pixels over it where the line bends down there (the point at or above the mean of its neighbours) and
        under it where the line bends up; else on the other side, else moved along to stay inside the plot.
        The action is elided to two steps' width at most, and left out where fewer than HISTORY_MIN_LETTERS of
        its letters would stay. The errors are placed first, the last step's, then the first's, then the others in order, and each then
        takes its action over it where that finds room too; an error that finds no free place is left out (its
        point keeps its number on the axis, the label its tooltip). The error axis leaves a label's height
        over the highest point and under the lowest."""
        if not self._history_labels:
            return
        box = self.history.getViewBox()
        width, height = box.width(), box.height()
        if width <= 0 or height <= 0:
            return
        metrics = QFontMetrics(self._history_font)
        margin = self._history_labels[0][1].textItem.document().documentMargin()
        line = metrics.lineSpacing()
        logs = np.array([np.log10(h.error) if h.error > 0 else np.nan for h, _ in self._history_labels])
        known = logs[np.isfinite(logs)] if np.isfinite(logs).any() else np.zeros(1)
        low, high = float(known.min()), float(known.max())
        lines = 2 if (2 * line + 2 * margin + HISTORY_GAP) / height <= 0.3 else 1
        share = min((lines * line + 2 * margin + HISTORY_GAP) / height, 0.45)
        pad = share * max(high - low, 0.3) / (1 - 2 * share)
        y_low, y_high = low - pad, high + pad
        self.history.setYRange(y_low, y_high, padding=0)
        x_low, x_high = -0.5, max(len(self._history_labels) - 0.5, 1.5)

        def pixels(step: float, value: float) -> tuple[float, float]:
            return ((step - x_low) / (x_high - x_low) * width,
                    (y_high - (value if np.isfinite(value) else y_low)) / (y_high - y_low) * height)

        points = [pixels(h.step, v) for (h, _), v in zip(self._history_labels, logs)]
        n = len(self._history_labels)
        order = [n - 1] + list(range(n - 1))

        def sides(i: int) -> tuple[bool, bool]:
            neighbours = [logs[j] for j in (i - 1, i + 1) if 0 <= j < n and np.isfinite(logs[j])]
            above = not neighbours or not np.isfinite(logs[i]) or logs[i] >= np.mean(neighbours)
            return above, not above

        def place(i: int, text: str, others) -> tuple[QRectF, bool] | None:
            x, y = points[i]
            w = max(metrics.horizontalAdvance(t) for t in text.split("\n")) + 2 * margin + 2
            hgt = text.count("\n") * line + metrics.height() + 2 * margin
            left = min(max(x - w / 2, 0.0), width - w)
            for over in sides(i):
                top = y - HISTORY_GAP - hgt if over else y + HISTORY_GAP
                rect = QRectF(left, top, w, hgt)
                if left >= 0 and top >= 0 and rect.bottom() <= height and \
                        not any(rect.intersects(r) for r in others) and \
                        not any(rect.adjusted(-4, -4, 4, 4).contains(QPointF(*p)) for p in points):
                    return rect, over
            return None

        # the errors first, as many as find room; then each grows its action over it where that has room too
        texts, found = {}, {}
        for i in order:
            h = self._history_labels[i][0]
            texts[i] = f"{h.error:.3g}"
            spot = place(i, texts[i], [r for r, _ in found.values()])
            if spot is not None:
                found[i] = spot
        if lines == 2:
            for i in order:
                if i not in found:
                    continue
                h = self._history_labels[i][0]
                # at most two steps wide, so that a label reads as its own point's
                action = metrics.elidedText(h.action.replace("add ", "+ ", 1), Qt.TextElideMode.ElideMiddle,
                                            int(min(HISTORY_LABEL_WIDTH, 2 * width / (x_high - x_low))))
                if len(action.replace("…", "")) < HISTORY_MIN_LETTERS:
                    continue
                text = f"{action}\n{texts[i]}"
                spot = place(i, text, [r for j, (r, _) in found.items() if j != i])
                if spot is not None:
                    texts[i], found[i] = text, spot
        for i, (h, label) in enumerate(self._history_labels):
            label.setVisible(i in found)
            if i not in found:
                continue
            rect, over = found[i]
            label.setText(texts[i])
            # the anchor in shares of the label's own size, which the text item sets (a pixel or two off ours)
            size = label.boundingRect()
            gap = HISTORY_GAP / max(size.height(), 1.0)
            label.setAnchor(((points[i][0] - rect.left()) / max(size.width(), 1.0), 1.0 + gap if over else -gap))
