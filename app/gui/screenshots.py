"""Regenerate the GUI screenshots of docs/gui.md (``python -m app.gui.screenshots [--out DIR]``).

A real session, not a mock-up: the window connects to the emulated paper-2dof rig, loads a short plan (a random
run, two force levels, a response-controlled level and a phase-resonance run at four forces) and runs it through
its widgets -- the Acquire and Rig tabs are taken while the phase-resonance run locks its last level, its
natural-frequency plot grown point by point -- then analyses the session with the model that knows the structure but no law, presses Auto
(the missing-effect loop, as ``contactid analyze --auto``), and grabs every tab (the Backbone tab with the
response level's and the phase-resonance run's curves, measured and as the model predicts them). Runs offscreen unless a display is asked
for with ``QT_QPA_PLATFORM``.
"""
from __future__ import annotations

import argparse
import os
import tempfile
import time
from pathlib import Path

TABS = ("rig", "acquire", "identify", "model", "backbone", "session")
SIZE = (1500, 950)
# the random run's rms force (0.3 N) is above the Coulomb slip force of paper-2dof (0.1 N), so its joint moves
PLAN = """
[random]
force_rms = 0.3
band = [0.5, 5.0]
duration = 32.0

[[stepped_sine]]
force = 0.4
start = 0.8
stop = 3.2
step = 0.05

[[stepped_sine]]
force = 0.8
start = 0.8
stop = 3.2
step = 0.05

[[stepped_sine]]
response = 2.0
dof = "x2"
start = 1.05
stop = 1.45
step = 0.025
refine = false

[[phase_resonance]]
dof = "x2"
forces = [0.2, 0.4, 0.8, 1.2]
start = 1.27

[limits]
max_force = 5.0
max_acceleration = 50.0
"""
AUTO_TIMEOUT_S = 900


def _wait(app, predicate, timeout_s: float, what: str) -> None:
    deadline = time.monotonic() + timeout_s
    while not predicate():
        if time.monotonic() > deadline:
            raise TimeoutError(f"gave up waiting for {what}")
        app.processEvents()
        time.sleep(0.01)


def _settle(app, seconds: float = 0.3) -> None:
    """Let queued signals and a few frame-clock redraws through before a grab."""
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        app.processEvents()
        time.sleep(0.01)


def take(out: Path) -> list[Path]:
    """Run the story and write one PNG per tab into ``out``; returns the files."""
    os.environ.setdefault("QT_QPA_PLATFORM", "offscreen")
    from PySide6.QtWidgets import QApplication

    from .main_window import MainWindow

    app = QApplication.instance() or QApplication([])
    out.mkdir(parents=True, exist_ok=True)
    window = MainWindow("screenshots")
    window.resize(*SIZE)
    window.show()
    lab = window.lab
    errors: list[str] = []
    lab.error.connect(errors.append)
    shots = {}

    def grab(tab: str) -> None:
        window.tabs.setCurrentIndex(TABS.index(tab))
        _settle(app)
        shots[tab] = out / f"{tab}.png"
        if not window.grab().save(str(shots[tab])):
            raise OSError(f"could not write {shots[tab]}")

    with tempfile.TemporaryDirectory() as tmp:
        window.rig.builtin_rig.setCurrentText("paper-2dof")
        window.rig.connect_selected()
        _wait(app, lambda: lab.connected, 60, "the emulated instruments")
        plan = Path(tmp) / "plan.toml"
        plan.write_text(PLAN, encoding="utf-8")
        window.acquire.editor.load(plan)
        window.rig.arm_button.click()
        window.acquire.output.setText(str(Path(tmp) / "paper-2dof.h5"))
        window.acquire.start_button.click()
        _wait(app, lambda: lab.live is not None and any(
            r.kind == "phase_resonance" and len(r.frequency) >= 3 for r in lab.live.runs())
            or not lab.campaign_running, 900, "the phase-resonance run's third point")
        grab("acquire")
        _settle(app, 1.5)             # one poll of the output state and the link health
        grab("rig")
        _wait(app, lambda: not lab.campaign_running and lab.session is not None, 300, "the end of the campaign")
        window.model.analyze_button.click()
        _wait(app, lambda: lab.analysis is not None, AUTO_TIMEOUT_S, "the analysis")
        window.model.auto_button.click()
        _wait(app, lambda: lab.analysis.auto or errors, AUTO_TIMEOUT_S, "the automatic loop")
        _wait(app, lambda: lab.identification is not None and not lab.identification.live, 60,
              "the identification")
        window.session.runs.selectRow(window.session.runs.rowCount() - 1)      # the highest level
        for tab in ("identify", "model", "backbone", "session"):
            grab(tab)
        if errors:
            raise RuntimeError("the window reported: " + "; ".join(errors))
        window.close()
    return [shots[t] for t in TABS]


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", default=str(Path(__file__).resolve().parents[2] / "docs" / "screenshots"),
                        help="folder for the PNG files (default: docs/screenshots of the checkout)")
    args = parser.parse_args(argv)
    for path in take(Path(args.out)):
        print(path)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
