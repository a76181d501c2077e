"""Regenerate the GUI screenshots of docs/gui.md (``python -m app.gui.screenshots [--out DIR] [--brb MAT]
[--check-out DIR]``).

A real session, not a mock-up: the window connects to the emulated paper-2dof rig, loads a short plan (a random
run, two force levels, a response-controlled level and a phase-resonance run at four forces) and runs it through
its widgets -- the Acquire and Rig tabs are taken while the phase-resonance run locks its last level, its
natural-frequency plot grown point by point -- then analyses the session with the model that knows the structure but no law, presses Auto
(the missing-effect loop, as ``contactid analyze --auto``), and grabs every tab (the Backbone tab with the
response level's and the phase-resonance run's curves, measured and as the model predicts them).

Then two sessions of many levels, each opened as a lab user opens it:

- the Brake-Reuss beam's 12 measured levels (4 force-held, 8 held at an acceleration; ``--brb`` names its
  ForcedFrequencyResponses.mat, by default ``$CONTACTID_REALDATA/brb/``; without it this part is left out, said
  on the way), converted by docs/examples/brb_to_csv.py and imported through the window with the force sign the
  file needs; *Reference from session*, Analyze and Auto; the Identify, Model and Backbone tabs (brb_*.png);
- a synthetic session of 30 levels (20 force-held, 10 held at an acceleration) of a one-mode structure with a
  softening, slipping joint, made by harmonic balance (:func:`thirty_levels_csv`) and imported the same way;
  analysed with the structure and a joint without laws; the Identify, Model and Backbone tabs (levels30_*.png).

Every picture is taken at SIZE, a 1366 x 768 screen, the smallest the window is made for; ``--check-out`` also
takes each at CHECK_SIZE into another folder, to look at. Runs offscreen unless a display is asked for with
``QT_QPA_PLATFORM``.
"""
from __future__ import annotations

import argparse
import os
import tempfile
import time
from pathlib import Path

TABS = ("rig", "acquire", "identify", "model", "backbone", "session")
SIZE = (1366, 768)
CHECK_SIZE = (1600, 1000)
MANY_LEVEL_TABS = ("identify", "model", "backbone")
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


# the synthetic session of many levels: one mode near 80 Hz and a joint that softens and slips (a Jenkins element)
THIRTY_STRUCTURE = {"type": "lumped", "dofs": ["x1"], "mass": [[1.0]], "stiffness": [[252662.0]],
                    "damping": [[5.0]]}
THIRTY_LAWS = [{"law": "cubic", "k3": -2.0e9}, {"law": "jenkins", "kt": 5000.0, "fs": 0.5}]
THIRTY_FORCES = 20          # force-held levels, 0.05 to 2 N
THIRTY_RESPONSES = 10       # levels held at an acceleration of x1, 10 to 250 m/s^2
THIRTY_MODEL = """[structure]
type = "lumped"
dofs = ["x1"]
mass = [[1.0]]
stiffness = [[252662.0]]
damping = [[5.0]]

[[element]]
name = "joint"
dof = "x1"
laws = []
"""


def thirty_levels_csv(path: Path, seed: int = 0) -> Path:
    """A long CSV (docs/import.md) of THIRTY_FORCES force-held and THIRTY_RESPONSES response-held up-sweeps of the
    one-mode structure with THIRTY_LAWS at x1, 0.1 % noise: the force levels by harmonic balance, the response
    levels from the dynamic stiffness at the held amplitude (one DOF: the force that holds it is that stiffness
    times the displacement)."""
    import numpy as np

    from analysis.mechanics.model import load_model
    from analysis.prediction.harmonic_balance import predict_sweep

    model = load_model({"structure": THIRTY_STRUCTURE, "element": [{"name": "joint", "dof": "x1",
                                                                    "laws": THIRTY_LAWS}]})
    (joint,) = model.elements
    f = np.round(np.linspace(77.0, 83.0, 61), 3)
    w = 2 * np.pi * f
    rng = np.random.default_rng(seed)
    m, k, c = (THIRTY_STRUCTURE[key][0][0] for key in ("mass", "stiffness", "damping"))
    rows = ["frequency_hz,force_n,dof,re,im,force_amplitude_n,control_dof,control_quantity,control_target"]

    def noisy(h):
        return h * (1 + 1e-3 * (rng.standard_normal(h.shape) + 1j * rng.standard_normal(h.shape)))

    for force in np.round(np.geomspace(0.05, 2.0, THIRTY_FORCES), 4):
        h = noisy(predict_sweep(model.structure, model.elements, "x1", w, float(force), "up").receptance[:, 0, 0])
        rows += [f"{fi},{force},x1,{hi.real:.9e},{hi.imag:.9e},{force},,," for fi, hi in zip(f, h)]
    for target in np.round(np.geomspace(10.0, 250.0, THIRTY_RESPONSES), 1):
        X = target / w**2
        stiffness = k - w**2 * m + 1j * w * c + joint.describing_function(X, w)
        h, force = noisy(1 / stiffness), np.abs(stiffness) * X
        rows += [f"{fi},,x1,{hi.real:.9e},{hi.imag:.9e},{fa:.6g},x1,acceleration,{target}"
                 for fi, hi, fa in zip(f, h, force)]
    path.write_text("\n".join(rows) + "\n", encoding="utf-8")
    return path


def _brb_csv(mat: Path, path: Path) -> Path:
    """The beam's MATLAB file as a long CSV, by the script docs/import.md shows."""
    import importlib.util

    script = Path(__file__).resolve().parents[2] / "docs" / "examples" / "brb_to_csv.py"
    spec = importlib.util.spec_from_file_location("brb_to_csv", script)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    module.write_csv(str(mat), str(path))
    return path


def take(out: Path, brb: Path | None = None, check_out: Path | None = None) -> list[Path]:
    """Run the stories and write one PNG per tab into ``out`` (and at CHECK_SIZE into ``check_out``); returns the
    files written into ``out``."""
    os.environ.setdefault("QT_QPA_PLATFORM", "offscreen")
    from PySide6.QtWidgets import QApplication

    from app.importers.runs import SourceOptions
    from app.importers.store import ImportRequest

    from .main_window import MainWindow

    app = QApplication.instance() or QApplication([])
    out.mkdir(parents=True, exist_ok=True)
    if check_out is not None:
        check_out.mkdir(parents=True, exist_ok=True)
    window = MainWindow("screenshots")
    window.resize(*SIZE)
    window.show()
    lab = window.lab
    errors: list[str] = []
    lab.error.connect(errors.append)
    shots: list[Path] = []

    def grab(tab: str, name: str | None = None) -> None:
        window.tabs.setCurrentIndex(TABS.index(tab))
        for size, folder in ((SIZE, out), (CHECK_SIZE, check_out)):
            if folder is None:
                continue
            window.resize(*size)
            _settle(app)
            path = folder / f"{name or tab}.png"
            if not window.grab().save(str(path)):
                raise OSError(f"could not write {path}")
            if folder is out:
                shots.append(path)
        window.resize(*SIZE)

    def imported(csv: Path, session: Path, options: SourceOptions) -> None:
        request = ImportRequest([(str(csv), options)], str(session), software_version="screenshots")
        lab.import_measurements(request, lambda _: None, errors.append)
        _wait(app, lambda: lab.session_path == str(session) or errors, 300, f"the import of {csv.name}")

    def analysed(auto: bool) -> None:
        before = lab.analysis
        window.model.analyze_button.click()
        _wait(app, lambda: lab.analysis not in (None, before) or errors, AUTO_TIMEOUT_S, "the analysis")
        if auto and not errors:
            window.model.auto_button.click()
            _wait(app, lambda: lab.analysis.auto or errors, AUTO_TIMEOUT_S, "the automatic loop")
        _wait(app, lambda: lab.identification is not None and not lab.identification.live or errors, 60,
              "the identification")
        _wait(app, lambda: lab.backbone is not None and lab.backbone.predicted or errors, 120, "the backbones")

    def check() -> None:
        if errors:
            raise RuntimeError("the window reported: " + "; ".join(errors))

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
        analysed(auto=True)
        window.session.runs.selectRow(window.session.runs.rowCount() - 1)      # the highest level
        for tab in ("identify", "model", "backbone", "session"):
            grab(tab)
        check()

        if brb is None or not brb.is_file():
            print(f"left out: the Brake-Reuss beam's screenshots (its data are not at {brb})" if brb else
                  "left out: the Brake-Reuss beam's screenshots (give --brb ForcedFrequencyResponses.mat)")
        else:
            imported(_brb_csv(brb, Path(tmp) / "brb.csv"), Path(tmp) / "brb.h5",
                     SourceOptions(excitation="x1", force_sign=-1.0))
            check()
            window.model.reference_button.click()
            _wait(app, lambda: lab.reference is not None or errors, 300, "the reference")
            check()
            analysed(auto=True)
            for tab in MANY_LEVEL_TABS:
                grab(tab, f"brb_{tab}")
            check()

        imported(thirty_levels_csv(Path(tmp) / "levels30.csv"), Path(tmp) / "levels30.h5",
                 SourceOptions(excitation="x1"))
        check()
        model = Path(tmp) / "levels30.toml"
        model.write_text(THIRTY_MODEL, encoding="utf-8")
        lab.load_model_file(str(model))
        analysed(auto=False)
        for tab in MANY_LEVEL_TABS:
            grab(tab, f"levels30_{tab}")
        check()
        window.close()
    return shots


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", default=str(Path(__file__).resolve().parents[2] / "docs" / "screenshots"),
                        help="folder for the PNG files (default: docs/screenshots of the checkout)")
    realdata = os.environ.get("CONTACTID_REALDATA")
    parser.add_argument("--brb", default=str(Path(realdata) / "brb" / "ForcedFrequencyResponses.mat")
                        if realdata else None, help="the Brake-Reuss beam's ForcedFrequencyResponses.mat "
                        "(default: $CONTACTID_REALDATA/brb/; none: its screenshots are left out)")
    parser.add_argument("--check-out", default=None,
                        help=f"also take each picture at {CHECK_SIZE[0]} x {CHECK_SIZE[1]} into this folder")
    args = parser.parse_args(argv)
    for path in take(Path(args.out), Path(args.brb) if args.brb else None,
                     Path(args.check_out) if args.check_out else None):
        print(path)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
