"""The lab window: six tabs over one :class:`~app.gui.lab.Lab`, an error bar, and a close that switches the
output off first."""
from __future__ import annotations

import logging
import traceback

import pyqtgraph as pg
from PySide6.QtCore import Qt
from PySide6.QtGui import QAction, QCloseEvent, QKeySequence
from PySide6.QtWidgets import (QFileDialog, QFrame, QHBoxLayout, QLabel, QMainWindow, QPushButton, QTabWidget,
                               QVBoxLayout, QWidget)

from . import gc_guard
from .acquire_panel import AcquirePanel
from .backbone_panel import BackbonePanel
from .identify_panel import IdentifyPanel
from .import_dialog import ImportDialog
from .lab import Lab
from .model_panel import ModelPanel
from .plots import FrameClock, LevelPalette
from .rig_panel import RigPanel
from .session_panel import SessionPanel
from .workers import describe_error

log = logging.getLogger("contactid.gui")
ERROR_STYLE = "background:#fde0dc; color:#8b1a10; padding:6px; border:1px solid #d62728"


class ErrorBar(QFrame):
    """A message line above the tabs: errors stay visible until dismissed, never in a blocking dialog."""

    def __init__(self, parent: QWidget | None = None):
        super().__init__(parent)
        self.setStyleSheet(ERROR_STYLE)
        row = QHBoxLayout(self)
        row.setContentsMargins(4, 2, 4, 2)
        self.label = QLabel()
        self.label.setWordWrap(True)
        self.label.setTextInteractionFlags(Qt.TextInteractionFlag.TextSelectableByMouse)
        dismiss = QPushButton("Dismiss")
        dismiss.clicked.connect(self.hide)
        row.addWidget(self.label, 1)
        row.addWidget(dismiss)
        self.hide()

    def show_message(self, message: str) -> None:
        self.label.setText(message)
        self.show()


class MainWindow(QMainWindow):
    """The ``contactid gui`` window.

    Parameters
    ----------
    software_version : str
        Written into the sessions the window's campaigns make.
    """

    def __init__(self, software_version: str = ""):
        super().__init__()
        gc_guard.acquire()
        self._collecting = True
        self.setWindowTitle("contactid — lab")
        self.lab = Lab(software_version, self)
        self.clock = FrameClock(parent=self)
        self.palette = LevelPalette()
        # another session, other levels: its views recolour them in order (before any view draws)
        self.lab.sessionChanged.connect(self.palette.reset)
        self.rig = RigPanel(self.lab)
        self.acquire = AcquirePanel(self.lab, self.clock, self.palette)
        self.identify = IdentifyPanel(self.lab, self.clock, self.palette)
        self.model = ModelPanel(self.lab, self.palette)
        self.backbone = BackbonePanel(self.lab)
        self.session = SessionPanel(self.lab, self.palette, self.all_plots)
        self.tabs = QTabWidget()
        for panel, title in ((self.rig, "Rig"), (self.acquire, "Acquire"), (self.identify, "Identify"),
                             (self.model, "Model"), (self.backbone, "Backbone"), (self.session, "Session")):
            self.tabs.addTab(panel, title)
        central = QWidget()
        layout = QVBoxLayout(central)
        layout.setContentsMargins(4, 4, 4, 4)
        self.error_bar = ErrorBar()
        layout.addWidget(self.error_bar)
        layout.addWidget(self.tabs, 1)
        self.setCentralWidget(central)
        self._menus()
        self.lab.error.connect(self.show_error)
        self.lab.campaignStarted.connect(lambda _: self.statusBar().showMessage("campaign running"))
        self.lab.campaignFinished.connect(
            lambda text, aborted: self.statusBar().showMessage(("campaign aborted: " if aborted else
                                                                "campaign finished: ") + text.splitlines()[-1]))
        self.lab.sessionChanged.connect(lambda: self.statusBar().showMessage(
            f"session: {self.lab.session_path}" if self.lab.session_path else "no session"))
        # a result that went through replaces whatever the status bar said before (an old refusal included)
        self.lab.analysisUpdated.connect(
            lambda view: self.statusBar().showMessage(f"analysed: FRF error {view.error:.4g}"))
        self.lab.predictionUpdated.connect(lambda _: self.statusBar().showMessage("predicted, nothing refitted"))
        self.lab.modelChanged.connect(lambda: self.statusBar().showMessage(f"model: {self.lab.model_label}"))
        self._import: ImportDialog | None = None        # kept as the operator left it until an import goes through
        self.resize(1500, 950)

    def _menus(self) -> None:
        menu = self.menuBar().addMenu("&File")
        for text, slot, key in (("Open session…", self._open_session, QKeySequence.StandardKey.Open),
                                ("Import…", self.import_dialog, None),
                                ("Open model…", self.model.open_model_dialog, None),
                                ("Quit", self.close, QKeySequence.StandardKey.Quit)):
            action = QAction(text, self)
            action.triggered.connect(slot)
            if key is not None:
                action.setShortcut(key)
            menu.addAction(action)

    def _open_session(self) -> None:
        path, _ = QFileDialog.getOpenFileName(self, "Session file", "", "Sessions (*.h5);;All files (*)")
        if path:
            self.lab.act(self.lab.open_session, path)
            self.tabs.setCurrentWidget(self.session)

    def import_dialog(self) -> ImportDialog:
        """File > Import…: other systems' files into a session, then the Identify tab on it. A refused import
        leaves the dialog as it was, its refusal under the files, for the next File > Import… to correct; an
        import that went through starts the next one empty."""
        if self._import is None:
            self._import = ImportDialog(self.lab.software_version, self)
            self._import.accepted.connect(lambda: self.start_import(self._import))
        self._import.open()
        return self._import

    def start_import(self, dialog: ImportDialog) -> None:
        def done(message: str) -> None:
            if self._import is dialog:
                self._import = None
                dialog.deleteLater()
            self.statusBar().showMessage(message.splitlines()[0])
            self.tabs.setCurrentWidget(self.identify)
        dialog.message.setText("")
        self.lab.act(lambda: self.lab.import_measurements(dialog.request(), done, dialog.message.setText))

    def all_plots(self) -> dict[str, pg.PlotItem]:
        """Every plot of every tab, named ``<tab>_<plot>``."""
        out = {}
        for prefix, panel in (("acquire", self.acquire), ("identify", self.identify), ("model", self.model),
                              ("backbone", self.backbone), ("session", self.session)):
            out.update({f"{prefix}_{name}": plot for name, plot in panel.plots().items()})
        return out

    def show_error(self, message: str) -> None:
        self.error_bar.show_message(message)
        self.statusBar().showMessage(message.splitlines()[0] if message else "")

    def report_exception(self, exc_type, exc, tb) -> None:
        """``sys.excepthook`` of the GUI: an unexpected error becomes a message, the window stays."""
        if issubclass(exc_type, KeyboardInterrupt):
            self.close()
            return
        log.error("unexpected error:\n%s", "".join(traceback.format_exception(exc_type, exc, tb)))
        self.show_error(f"unexpected error: {describe_error(exc)}")

    def configure(self, *, session: str | None = None, rig: str | None = None, shaker: str | None = None,
                  daq: str | None = None, excitation: str | None = None, model: str | None = None) -> None:
        """Apply the command line: instruments to connect, a model and a session to open."""
        self.rig.select_source(rig=rig, shaker=shaker, daq=daq, excitation=excitation)
        if model:
            self.lab.act(self.lab.load_model_file, model)
        if session:
            if self.lab.act(self.lab.open_session, session):
                self.tabs.setCurrentWidget(self.session)
        self.rig.connect_selected()

    def closeEvent(self, event: QCloseEvent) -> None:  # noqa: N802 (Qt API)
        """Output off before anything closes: abort the campaign and wait for it, then release everything."""
        self.statusBar().showMessage("closing: switching the output off …")
        self.clock.stop()
        self.lab.shutdown()
        if self._collecting:
            self._collecting = False
            gc_guard.release()
        event.accept()
