"""The lab GUI, ``contactid gui`` (docs/gui.md).

Five tabs -- Rig, Acquire, Identify, Model, Session -- over the application layer: the GUI holds no numerics and
never touches a port. Long work runs on worker threads (:mod:`app.gui.workers`), live plots redraw at most
30 times a second (:mod:`app.gui.plots`), and closing the window switches the output off first.
"""
from __future__ import annotations

import sys

from PySide6.QtCore import QTimer
from PySide6.QtWidgets import QApplication

from drivers.safety import install_signal_handlers

SIGNAL_POLL_MS = 200
"""Python runs its signal handlers only between bytecodes: a timer lets SIGINT/SIGTERM through Qt's loop."""


def run(*, session: str | None = None, rig: str | None = None, shaker: str | None = None, daq: str | None = None,
        excitation: str | None = None, model: str | None = None, software_version: str = "") -> int:
    """Open the lab window and run until it is closed; returns the exit status.

    Parameters
    ----------
    session : str, optional
        A session file to open.
    rig : str, optional
        Built-in rig name or rig file to emulate (default: the first built-in rig).
    shaker, daq : str, optional
        Ports or pyserial URLs of real instruments (instead of a rig).
    excitation : str, optional
        DOF of the force gauge on real instruments.
    model : str, optional
        A model file.
    """
    from .main_window import MainWindow

    app = QApplication.instance() or QApplication(sys.argv[:1])
    app.setApplicationName("contactid")
    install_signal_handlers()           # SIGINT/SIGTERM switch every guarded output off
    window = MainWindow(software_version)
    previous_hook = sys.excepthook
    sys.excepthook = window.report_exception
    poll = QTimer(interval=SIGNAL_POLL_MS)
    poll.timeout.connect(lambda: None)
    poll.start()
    try:
        window.configure(session=session, rig=rig, shaker=shaker, daq=daq, excitation=excitation, model=model)
        window.show()
        return app.exec()
    finally:
        sys.excepthook = previous_hook
