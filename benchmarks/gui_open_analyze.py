"""How often the lab window reads a session wrong when Analyze is pressed the moment the session opens.

Opening a session reads it in three threads at once: the window's (the runs table and the plot of the selected
run), the files worker (the measured backbones) and, when Analyze is pressed at once, the analysis worker. Each
iteration opens the session, selects its last run (read again in the window) and presses Analyze; the analysis
stops as soon as it has read the measurements, which are compared with the file as plain h5py reads it in one
thread. An iteration is wrong when the analysis refused the session, or read any array other than the file holds.

Usage: ``python benchmarks/gui_open_analyze.py SESSION MODEL [--runs N]`` (a session and a model of ``contactid
demo --quick``: ``contactid-demo/paper-beam.h5`` and ``contactid-demo/paper-beam.fitted.toml``).
"""
from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

os.environ.setdefault("QT_QPA_PLATFORM", "offscreen")

import h5py  # noqa: E402
import numpy as np  # noqa: E402
from PySide6.QtWidgets import QApplication  # noqa: E402

import app.gui.lab as lab_module  # noqa: E402
from analysis.common.errors import InputError  # noqa: E402
from app.gui.main_window import MainWindow  # noqa: E402


class Read(InputError):
    """Ends the analysis once its measurements are read (an input error: reported, not logged)."""


def truth(path) -> dict[tuple[str, str], np.ndarray]:
    """Every run's frequencies, read once by plain h5py in this thread alone."""
    with h5py.File(path, "r") as f:
        return {(name, "frequency"): g["frequency"][()] for name, g in f["runs"].items()}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("session")
    parser.add_argument("model")
    parser.add_argument("--runs", type=int, default=50)
    args = parser.parse_args(argv)
    expected = truth(args.session)
    read: list = []

    class Stopped:
        """The workbench's place: keeps the measurements it is given and ends the analysis there."""

        def __init__(self, model, measurements):
            read.append(measurements)
            raise Read("measurements read")
    lab_module.Workbench = Stopped

    app = QApplication.instance() or QApplication([])
    window = MainWindow("stress")
    window.lab.load_model_file(args.model)
    errors: list[str] = []
    window.lab.error.connect(errors.append)
    wrong, t0 = [], time.monotonic()
    for i in range(args.runs):
        errors.clear()
        read.clear()
        window.lab.open_session(args.session)
        window.session.runs.selectRow(window.session.runs.rowCount() - 1)
        window.model.analyze_button.click()
        while not errors or window.lab.analysis_tasks.busy or window.lab.file_tasks.busy:
            app.processEvents()
            time.sleep(0.002)
        refused = [e for e in errors if "measurements read" not in e]
        bad = []
        if read:
            m = read[0]
            runs = list(m.sine) + ([m.random] if m.random is not None else [])
            for run in runs:
                name = getattr(run, "name", "random")
                if not np.array_equal(run.frequency_hz, expected[(name, "frequency")]):
                    bad.append(name)
        if refused or bad:
            wrong.append((i, refused[:1], bad))
    window.lab.shutdown()
    window.close()
    print(f"{len(wrong)} of {args.runs} iterations read the session wrong ({time.monotonic() - t0:.0f} s)")
    for i, refused, bad in wrong[:10]:
        print(f"  {i}: {refused[0] if refused else ''} {('arrays wrong in ' + ', '.join(bad)) if bad else ''}")
    return 1 if wrong else 0


if __name__ == "__main__":
    sys.exit(main())
