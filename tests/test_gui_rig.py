"""The Rig tab on real instruments: the emulated shaker controller and DAQ served over TCP by another process
(``contactid emulate --tcp``) and reached through ``socket://`` URLs, exactly as a bench would be."""
import subprocess
import sys
from pathlib import Path

import pytest

from app.gui.main_window import MainWindow

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(params=["SC-1", "33500B"])
def served_instruments(request):
    """URLs of paper-2dof's instruments served by ``contactid emulate`` in another process (shaker controller:
    the SC-1, or a bench function generator), and the shaker model."""
    proc = subprocess.Popen([sys.executable, "-m", "app.cli", "emulate", "paper-2dof", "--tcp", "127.0.0.1:0",
                             "--fast", "--shaker-model", request.param], cwd=ROOT, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)
    try:
        urls = dict(proc.stdout.readline().strip().split(": ", 1) for _ in range(2))
        urls["model"] = request.param
        yield urls
    finally:
        proc.terminate()
        proc.wait(10)


@pytest.mark.slow
def test_real_instruments_over_socket_urls(qtbot, served_instruments):
    window = MainWindow("test")
    qtbot.addWidget(window)
    rig = window.rig
    rig.select_source(shaker=served_instruments["shaker"], daq=served_instruments["daq"], excitation="x2")
    assert rig.use_real.isChecked()
    rig.connect_button.click()
    qtbot.waitUntil(lambda: window.lab.connected, timeout=30000)
    idn = "contactid,SC-1," if served_instruments["model"] == "SC-1" else "Keysight Technologies,33521B,"
    assert rig.shaker_idn.text().startswith(idn) and served_instruments["shaker"] in rig.shaker_idn.text()
    # what protects the output: the SC-1's own ramp and watchdog, or the driver's ramp and the guardian
    protects = ("instrument watchdog", "ramped: instrument") if served_instruments["model"] == "SC-1" \
        else ("host killed: guardian process", "ramped: driver (host)")
    assert all(text in rig.protections.text() for text in protects) and "nothing" not in rig.protections.text()
    assert rig.daq_idn.text().startswith("contactid,DAQ-1,")
    assert "force at x2, accelerometers at x1, x2" in rig.daq_setup.text()
    assert window.lab.rig is None and window.lab.model is None          # nothing is known of a real structure
    qtbot.waitUntil(lambda: rig.output_state.text() == "OFF" and rig.fault.text() == "none", timeout=10000)
    # the plan is checked against these instruments: paper-2dof's DAQ samples at 256 Hz
    window.acquire.editor.set_levels([{"force": 0.8, "start": 1.0, "stop": 150.0, "step": 10.0,
                                       "direction": "up", "refine": False}])
    assert "Nyquist" in window.acquire.editor.validation.text()
    window.acquire.editor.set_levels([{"force": 0.8, "start": 1.0, "stop": 3.0, "step": 0.5,
                                       "direction": "up", "refine": False}])
    rig.arm_button.click()
    assert window.lab.armed_plan is not None and window.acquire.start_button.isEnabled()
    rig.disconnect_button.click()
    assert window.lab.armed_plan is None and not window.lab.connected
    assert not window.acquire.start_button.isEnabled()


@pytest.mark.slow
def test_a_port_that_does_not_answer_is_a_message(qtbot):
    window = MainWindow("test")
    qtbot.addWidget(window)
    window.rig.select_source(shaker="socket://127.0.0.1:1", daq="socket://127.0.0.1:2", excitation="x2")
    with qtbot.waitSignal(window.lab.error, timeout=30000) as failed:
        window.rig.connect_button.click()
    assert "127.0.0.1:1" in failed.args[0]
    assert window.error_bar.isVisibleTo(window) and not window.lab.connected
    qtbot.waitUntil(lambda: window.rig.connect_button.isEnabled())
    assert window.rig.connection.text() == "not connected"
