"""Session tab: open a session file (also while another process is still writing it: the tab follows the new
lines), browse its runs, events and provenance, plot a run's FRFs, export UFF58 / CSV, and save any plot of
the window as PNG."""
from __future__ import annotations

import html
from pathlib import Path
from typing import Callable

import numpy as np
import pyqtgraph as pg
from PySide6.QtCore import Qt, QTimer
from PySide6.QtGui import QColor
from PySide6.QtWidgets import (QAbstractItemView, QFileDialog, QGroupBox, QHBoxLayout, QHeaderView, QLabel,
                               QListWidget, QPushButton, QSplitter, QTableWidget, QTableWidgetItem, QTextBrowser,
                               QVBoxLayout, QWidget)

from analysis.common.errors import InputError

from .lab import Lab
from .live import ALARM_COLOR, is_alarm
from .plots import (LevelPalette, configure_plot, export_png, finite_log, random_pen, run_control, safe_file_name,
                    sensor_symbol, side_legend)

RUN_COLUMNS = ("Run", "Kind", "Force [N]", "Direction", "Status", "Lines", "From transient")
FOLLOW_INTERVAL_MS = 1000


def _from_transient(run) -> str:
    """Lines of a stepped-sine run measured from their transient fits, of all ("—": none could be, method
    "steady" or a random run)."""
    transient = run.arrays.get("transient")
    if transient is None or not np.any(transient):
        return "—"
    return f"{int(np.sum(transient))}/{len(transient)}"


class SessionPanel(QWidget):
    """The Session tab (module docstring).

    Parameters
    ----------
    plots : callable
        Every plot of the window, ``{name: PlotItem}``, for the PNG export.
    """

    def __init__(self, lab: Lab, palette: LevelPalette, plots: Callable[[], dict], parent: QWidget | None = None):
        super().__init__(parent)
        self.lab = lab
        self.palette = palette
        self.all_plots = plots
        layout = QVBoxLayout(self)
        bar = QHBoxLayout()
        open_button = QPushButton("Open session…")
        open_button.clicked.connect(self._open_clicked)
        self.path_label = QLabel("no session open")
        self.path_label.setTextInteractionFlags(Qt.TextInteractionFlag.TextSelectableByMouse)
        self.follow_label = QLabel("")
        refresh = QPushButton("Refresh")
        refresh.clicked.connect(self._refresh)
        bar.addWidget(open_button)
        bar.addWidget(self.path_label, 1)
        bar.addWidget(self.follow_label)
        bar.addWidget(refresh)
        layout.addLayout(bar)

        splitter = QSplitter(Qt.Orientation.Horizontal)
        layout.addWidget(splitter, 1)
        left = QWidget()
        column = QVBoxLayout(left)
        column.setContentsMargins(0, 0, 0, 0)
        runs_box = QGroupBox("Runs")
        self.runs = QTableWidget(0, len(RUN_COLUMNS))
        self.runs.setHorizontalHeaderLabels(RUN_COLUMNS)
        self.runs.verticalHeader().setVisible(False)
        self.runs.setSelectionBehavior(QAbstractItemView.SelectionBehavior.SelectRows)
        self.runs.setEditTriggers(QAbstractItemView.EditTrigger.NoEditTriggers)
        self.runs.horizontalHeader().setSectionResizeMode(QHeaderView.ResizeMode.ResizeToContents)
        self.runs.horizontalHeader().setStretchLastSection(True)
        self.runs.itemSelectionChanged.connect(self._draw_selected)
        QVBoxLayout(runs_box).addWidget(self.runs)
        column.addWidget(runs_box, 2)
        events_box = QGroupBox("Events")
        self.events = QListWidget()
        QVBoxLayout(events_box).addWidget(self.events)
        column.addWidget(events_box, 2)
        prov_box = QGroupBox("Provenance")
        self.provenance = QTextBrowser()
        QVBoxLayout(prov_box).addWidget(self.provenance)
        column.addWidget(prov_box, 2)
        export_box = QGroupBox("Export")
        row = QHBoxLayout(export_box)
        self.uff_button = QPushButton("UFF58…")
        self.uff_button.setToolTip("Every FRF of the session as universal-file dataset 58 records")
        self.uff_button.clicked.connect(self._export_uff)
        self.csv_button = QPushButton("CSV…")
        self.csv_button.setToolTip("One CSV file per run into a folder")
        self.csv_button.clicked.connect(self._export_csv)
        png_button = QPushButton("Plots as PNG…")
        png_button.setToolTip("Every plot of every tab as a PNG file into a folder "
                              "(one plot: right-click it, Export…)")
        png_button.clicked.connect(self._export_png)
        for b in (self.uff_button, self.csv_button, png_button):
            row.addWidget(b)
        self.export_label = QLabel("")
        self.export_label.setWordWrap(True)
        column.addWidget(export_box)
        column.addWidget(self.export_label)
        splitter.addWidget(left)

        self.graphics = pg.GraphicsLayoutWidget()
        self.magnitude = configure_plot(self.graphics.addPlot(0, 0), "Selected run: receptance |H|", "frequency",
                                        "Hz", "|H|", "m/N", log_y=True)
        self.phase = configure_plot(self.graphics.addPlot(1, 0), "Selected run: phase", "frequency", "Hz",
                                    "phase", "°")
        self.phase.setXLink(self.magnitude)
        self.legend = side_legend(self.graphics.ci, self.magnitude, 0, 1, rowspan=2)    # beside, not over the data
        splitter.addWidget(self.graphics)
        splitter.setSizes([560, 860])

        self._follow = QTimer(self, interval=FOLLOW_INTERVAL_MS)
        self._follow.timeout.connect(self._follow_tick)
        self._follow.start()
        lab.sessionChanged.connect(self._show_session)
        self._show_session()

    def plots(self) -> dict[str, pg.PlotItem]:
        return {"session_frf_magnitude": self.magnitude, "session_frf_phase": self.phase}

    # ------------------------------------------------------------------ actions
    def _open_clicked(self) -> None:
        path, _ = QFileDialog.getOpenFileName(self, "Session file", "", "Sessions (*.h5);;All files (*)")
        if path:
            self.lab.act(self.lab.open_session, path)

    def _refresh(self) -> None:
        if self.lab.session is not None:
            self.lab.refresh_session()
            self._show_session()

    def _follow_tick(self) -> None:
        """Follow a session another process is writing: re-read it while its writer lives."""
        session = self.lab.session
        if session is not None and session.writer_alive and self.lab.refresh_session():
            self._show_session()

    def _export_uff(self) -> None:
        path, _ = QFileDialog.getSaveFileName(self, "Export UFF58", "session.uff", "Universal files (*.uff *.unv)")
        if path:
            self.lab.act(self.lab.export, "uff", path, self.export_label.setText)

    def _export_csv(self) -> None:
        folder = QFileDialog.getExistingDirectory(self, "Export CSV into folder")
        if folder:
            self.lab.act(self.lab.export, "csv", folder, self.export_label.setText)

    def _export_png(self) -> None:
        folder = QFileDialog.getExistingDirectory(self, "Save every plot as PNG into folder")
        if folder:
            self.lab.act(lambda: self.export_label.setText(
                f"wrote {len(self.export_plots(folder))} PNG files to {folder}"))

    def export_plots(self, folder) -> list[Path]:
        """Every plot of the window as ``<name>.png`` in ``folder`` (plots with nothing drawn are skipped).
        A folder already holding one of those files is refused (InputError) before anything is written."""
        folder = Path(folder)
        folder.mkdir(parents=True, exist_ok=True)
        plots = {folder / f"{safe_file_name(name)}.png": plot for name, plot in self.all_plots().items()
                 if plot.listDataItems()}
        there = [path.name for path in plots if path.exists()]
        if there:
            raise InputError(f"holds {', '.join(there)} already; choose an empty folder", str(folder))
        return [export_png(plot, path) for path, plot in plots.items()]

    # ------------------------------------------------------------------ views
    def _show_session(self) -> None:
        session = self.lab.session
        self.uff_button.setEnabled(session is not None)
        self.csv_button.setEnabled(session is not None)
        if session is None:
            self.path_label.setText("no session open")
            self.follow_label.setText("")
            self.runs.setRowCount(0)
            self.events.clear()
            self.provenance.clear()
            return
        self.path_label.setText(str(self.lab.session_path))
        writing = session.writer_alive and any(session.run(n).status == "running" for n in session.run_names())
        self.follow_label.setText("a run is being written: following its lines" if writing else "")
        selected = self._selected_run()
        names = session.run_names()
        self.runs.setRowCount(len(names))
        for row, name in enumerate(names):
            run = session.run(name)
            status = run.status + (" (incomplete)" if run.incomplete else "")
            cells = (name, run.kind, f"{run.force:g}", run.direction, status, str(len(run.frequency)),
                     _from_transient(run))
            for col, text in enumerate(cells):
                item = QTableWidgetItem(text)
                if col == 4 and run.status != "complete":
                    item.setForeground(QColor(ALARM_COLOR))
                self.runs.setItem(row, col, item)
        if names:
            self.runs.selectRow(names.index(selected) if selected in names else 0)
        self.events.clear()
        for e in session.events():
            self.events.addItem(f"{e['iso_time']}  {e['run'] or '—'}  {e['kind']}: {e['message']}")
            if is_alarm(e["kind"], e["message"]):
                self.events.item(self.events.count() - 1).setForeground(QColor(ALARM_COLOR))
        self.provenance.setHtml(self._provenance_html())
        self._draw_selected()

    def _selected_run(self) -> str | None:
        rows = {i.row() for i in self.runs.selectedIndexes()}
        if not rows:
            return None
        item = self.runs.item(min(rows), 0)
        return None if item is None else item.text()

    def _provenance_html(self) -> str:
        session = self.lab.session
        attrs = session.attrs
        lines = [f"<p>created {html.escape(str(attrs.get('created', '')))}, software "
                 f"{html.escape(str(attrs.get('software_version', '')))}</p>"]
        plan = session.provenance("plan")
        if plan:
            lines.append(f"<p><b>Plan</b></p><pre>{html.escape(plan, quote=False)}</pre>")
        if session.provenance("rig") is not None:
            lines.append("<p>simulated session (the rig file is kept under /provenance/rig)</p>")
        return "".join(lines)

    def _draw_selected(self) -> None:
        for plot in (self.magnitude, self.phase):
            plot.clear()
            if plot.legend is not None:
                plot.legend.clear()
        name = self._selected_run()
        if name is None or self.lab.session is None:
            return
        run = self.lab.session.run(name)
        if not len(run.frequency):
            return
        order = np.argsort(run.frequency)
        f = run.frequency[order]
        for p, (dof, h) in enumerate(run.frf.items()):
            if run.kind == "random":          # a continuous spectrum at one low level: grey, a style per sensor
                style = {"pen": random_pen(p)}
            else:                             # the level's colour on every tab, sensors by symbol
                color = self.palette.color(run_control(run))
                style = {"pen": pg.mkPen(color, width=1.2), "symbol": sensor_symbol(p), "symbolSize": 5,
                         "symbolBrush": pg.mkBrush(color), "symbolPen": None}
            self.magnitude.plot(f, finite_log(np.abs(h[order])), name=f"{dof}", **style)
            self.phase.plot(f, np.degrees(np.angle(h[order])), **style)
