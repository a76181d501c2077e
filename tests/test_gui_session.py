"""The Session tab: following a session another process is still writing, exports (UFF58, CSV, PNG of every
plot) through its buttons, and a file that is not a session shown as a message."""
import csv
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import pyuff
from PySide6.QtGui import QImage

import app.gui.session_panel as session_panel
from app.export import run_file
from app.gui.main_window import MainWindow
from app.session.writer import open_session

ROOT = Path(__file__).resolve().parents[1]
RUN = "sine_0.8N_up"
# a writer in another process: one line every 50 ms until killed
WRITER = f"""
import sys, time
from app.session.writer import RunSpec, SessionWriter
w = SessionWriter(sys.argv[1], plan_text="[[stepped_sine]]", software_version="test")
w.begin_run(RunSpec("{RUN}", "stepped_sine", 0.8, "up", "x2", ["x1", "x2"], 100.0, ["force", "acc:x1", "acc:x2"],
                    ["N", "m/s^2", "m/s^2"]))
i = 0
while True:
    w.append_line(1.0 + 0.01 * i, {{"x1": complex(1.0, i), "x2": complex(2.0, -i)}})
    print(i, flush=True)
    i += 1
    time.sleep(0.05)
"""


@pytest.fixture
def window(qtbot):
    w = MainWindow("test")
    qtbot.addWidget(w)
    return w


def shown_lines(window) -> int:
    table = window.session.runs
    return int(table.item(0, 5).text()) if table.rowCount() else 0


@pytest.mark.slow
def test_a_session_being_written_by_another_process_is_followed(window, qtbot, tmp_path):
    path = tmp_path / "growing.h5"
    writer = subprocess.Popen([sys.executable, "-c", WRITER, str(path)], cwd=ROOT, stdout=subprocess.PIPE, text=True)
    try:
        for _ in range(5):                                   # a few lines written (the writer holds them a moment)
            writer.stdout.readline()
        qtbot.waitUntil(lambda: path.exists(), timeout=20000)
        window.lab.open_session(str(path))
        qtbot.waitUntil(lambda: shown_lines(window) >= 5, timeout=20000)
        first = shown_lines(window)
        assert window.session.runs.item(0, 4).text() == "running"
        assert "following" in window.session.follow_label.text()
        qtbot.waitUntil(lambda: shown_lines(window) >= first + 10, timeout=20000)
    finally:
        writer.kill()
        writer.wait()
    # the table and the plot show what the writer put in the file
    with open_session(path) as s:
        stored = s.run(RUN)
    shown = shown_lines(window)
    assert shown <= len(stored.frequency)
    x, y = window.session.phase.listDataItems()[0].getOriginalDataset()
    np.testing.assert_allclose(x, stored.frequency[:len(x)])
    np.testing.assert_allclose(y, np.degrees(np.angle(stored.frf["x1"][:len(x)])))


@pytest.fixture
def finished_session(tmp_path):
    """A closed session with one complete stepped-sine run (written in this process, then closed)."""
    from app.session.writer import RunSpec, SessionWriter
    path = tmp_path / "done.h5"
    w = SessionWriter(path, software_version="test")
    w.begin_run(RunSpec(RUN, "stepped_sine", 0.8, "up", "x2", ["x1", "x2"], 100.0, ["force", "acc:x1", "acc:x2"],
                        ["N", "m/s^2", "m/s^2"], {"force_amplitude": ("N", (), "f8")}))
    f = np.linspace(1.0, 2.0, 11)
    for i, fi in enumerate(f):
        w.append_line(fi, {"x1": 1e-3 / (1 + 1j * i), "x2": 2e-3 / (1 - 1j * i)}, {"force_amplitude": 0.8})
    w.end_run("complete")
    w.close()
    return path, f


@pytest.mark.slow
def test_exports_through_the_buttons(window, qtbot, tmp_path, monkeypatch, finished_session):
    path, f = finished_session
    window.lab.open_session(str(path))
    uff, csv_dir, png_dir = tmp_path / "out.uff", tmp_path / "csv", tmp_path / "png"
    monkeypatch.setattr(session_panel.QFileDialog, "getSaveFileName", lambda *a, **k: (str(uff), ""))
    with qtbot.waitSignal(window.lab.file_tasks.busyChanged, check_params_cb=lambda busy: not busy, timeout=30000):
        window.session.uff_button.click()
    run_uff = run_file(uff, RUN)                       # one file per run, named after the dialog's file
    records = [r for r in pyuff.UFF(str(run_uff)).read_sets() if r.get("func_type") == 4]
    assert len(records) == 2
    with open_session(path) as s:
        stored = s.run(RUN)
    for record in records:
        dof = record["rsp_ent_name"].strip()
        np.testing.assert_allclose(record["x"], f, rtol=1e-6)
        np.testing.assert_allclose(record["data"], stored.frf[dof], rtol=1e-6)
    assert f"records to {run_uff.name}" in window.session.export_label.text()

    monkeypatch.setattr(session_panel.QFileDialog, "getExistingDirectory", lambda *a, **k: str(csv_dir))
    with qtbot.waitSignal(window.lab.file_tasks.busyChanged, check_params_cb=lambda busy: not busy, timeout=30000):
        window.session.csv_button.click()
    with open(csv_dir / f"{RUN}.csv", newline="") as fh:
        rows = list(csv.reader(fh))
    assert len(rows) == 3 + len(f) and float(rows[3][0]) == pytest.approx(f[0])      # sentence, run line, columns

    written = window.session.export_plots(png_dir)
    names = {p.name for p in written}
    assert {"session_session_frf_magnitude.png", "session_session_frf_phase.png"} <= names
    for p in written:
        image = QImage(str(p))
        assert not image.isNull() and image.width() == 1600


def test_a_file_that_is_not_a_session_is_a_message_not_a_crash(window, tmp_path):
    bogus = tmp_path / "notes.h5"
    bogus.write_text("not hdf5", encoding="utf-8")
    assert not window.lab.act(window.lab.open_session, str(bogus))
    assert window.error_bar.isVisibleTo(window) and "not a readable HDF5 session" in window.error_bar.label.text()
    assert window.lab.session is None and window.session.path_label.text() == "no session open"


def test_runs_table_counts_the_lines_measured_from_their_transients():
    from types import SimpleNamespace

    from app.gui.session_panel import _from_transient
    assert _from_transient(SimpleNamespace(arrays={"transient": np.array([False, True, True])})) == "2/3"
    assert _from_transient(SimpleNamespace(arrays={"transient": np.zeros(4, bool)})) == "—"
    assert _from_transient(SimpleNamespace(arrays={})) == "—"          # a random run, or an older session
