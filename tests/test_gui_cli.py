"""``contactid gui`` from the command line: the window opens on the built-in simulated rig and the exit status
is 0 when it is closed; inconsistent instrument options are refused before any window opens."""
import pytest
from PySide6.QtCore import QTimer
from PySide6.QtWidgets import QApplication

from app.cli import main
from app.gui.main_window import MainWindow


@pytest.mark.slow
def test_gui_opens_on_the_simulated_rig_and_closes_cleanly(qapp, tmp_path):
    seen = {}

    def close_when_connected():
        windows = [w for w in QApplication.topLevelWidgets() if isinstance(w, MainWindow) and w.isVisible()]
        if windows and windows[0].lab.connected and windows[0].lab.model is not None:
            window = windows[0]
            seen["rig"] = window.lab.rig.name
            seen["model"] = [el.name for el in window.lab.model.elements]
            seen["plan"] = window.lab.plan is not None
            window.close()
            return
        QTimer.singleShot(100, close_when_connected)

    QTimer.singleShot(100, close_when_connected)
    assert main(["gui", "--rig", "paper-2dof"]) == 0
    assert seen == {"rig": "paper-2dof", "model": ["left", "right"], "plan": True}


def test_inconsistent_instrument_options_are_refused(capsys):
    assert main(["gui", "--shaker", "socket://localhost:5025"]) == 2
    assert "both --shaker URL and --daq URL" in capsys.readouterr().err
    assert main(["gui", "--rig", "paper-2dof", "--shaker", "socket://a:1", "--daq", "socket://a:2"]) == 2
    assert "either --rig or --shaker/--daq" in capsys.readouterr().err
