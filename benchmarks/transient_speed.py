"""Shaker time of transient-aware line measurement against today's steady-state detection and the fixed
300-period practice, at equal FRF accuracy.

    python benchmarks/transient_speed.py [--rigs light,linear,hardening,friction,sticking] [--tolerances 1e-2]

The rigs, each through the full in-process stack (drivers + emulated instruments):

- **light**: tests/rigs/light-linear.toml (the structure of the friction rig below without its elements: modes
  1.59 and 2.76 Hz, zeta 0.5 and 0.29 %, an ideal force source), 1-3.5 Hz in 0.05 Hz steps at 0.5 N.
  Accuracy: largest relative error of the receptance against the analytic one.
- **linear**: tests/rigs/linear-shaker.toml (modes 7.1 and 14.2 Hz, about 1 % damping, a voltage-driven
  shaker), 5-17 Hz in 0.25 Hz steps at 0.5 N. Accuracy: largest relative error of the receptance against the
  analytic one.
- **hardening**: tests/rigs/hardening.toml (a Duffing oscillator that jumps), 8-13 Hz in 0.2 Hz steps at 0.5 N,
  up and down. Accuracy: largest relative difference from the settled value, the line of a run that waits a
  fixed 2000 periods (the fixed 300-period practice is measured against it too).
- **sticking** (`--rigs sticking`, not run by default): tests/rigs/stiff-sticking.toml (the campaign benchmark's
  stiff rig: hardening cubic and Coulomb friction that holds x2 for part of every cycle, modes 5.9 and 9.6 Hz),
  5-11 Hz in 0.2 Hz steps at 0.5 N, up and down; a rig the sequence's design was not measured on. Accuracy as
  for hardening.
- **friction**: tests/rigs/stiff-friction.toml (hardening cubic and Coulomb friction, modes 1.59 and 2.76 Hz,
  zeta 0.3-0.5 %), 1-3.5 Hz in 0.125 Hz steps at 1 N, up and down. Accuracy as for hardening: on this lightly
  damped rig 300 periods are about six decay times of the first mode, and the practice itself misses the
  settled value by up to 1.2 %.

Lines with harmonics are taken from their phasor sequence (app/campaign/transient_line.py), the others from
their fit of modes.

On the nonlinear rigs, whose structure carries an element, the benchmark also checks what the lines are for: the
element's kbar identified at each line (analysis/identification/identify.py, the rig's structure as the reference)
against the kbar of the same line settled for 2000 periods, in units of the two lines' combined standard deviation
(from the FRFs' stored uncertainty, which includes what is left of the transient): "kbar z" is the largest such
distance, "<= 3 std" the share of lines within three.

A line is on a wrong branch when its FRF magnitude differs from the settled one by more than BRANCH (25 %: the
jumps of these rigs change it 2-5 x). Shaker time is the DAQ time the sweeps spend at their lines (the
campaign summary's figure: from a line's first record to its last, drive corrections and their latency
included); "at records" is the part spent in the records a line used (periods / frequency). The machine's load
average is printed with the figures.
"""
from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
import tomllib
from pathlib import Path

# the fits are small least-squares problems: BLAS threads only fight over a loaded machine's cores
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from app.campaign.instruments import emulated_instruments  # noqa: E402
from app.campaign.measure import run_plan  # noqa: E402
from app.campaign.plan import parse_plan  # noqa: E402
from app.analyze import read_measurements  # noqa: E402
from analysis.identification.identify import identify_complex_stiffness  # noqa: E402
from analysis.mechanics.model import load_model  # noqa: E402
from app.session.writer import open_session  # noqa: E402
from drivers.simulation.rig import load_rig  # noqa: E402

BRANCH = 0.25
LIMITS = "[limits]\nmax_force = 5.0\nmax_acceleration = 400.0\n"
CASES = {
    "light": ("light-linear.toml", 0.5, 1.0, 3.5, 0.05, "up"),
    "linear": ("linear-shaker.toml", 0.5, 5.0, 17.0, 0.25, "up"),
    "hardening": ("hardening.toml", 0.5, 8.0, 13.0, 0.2, "both"),
    "friction": ("stiff-friction.toml", 1.0, 1.0, 3.5, 0.125, "both"),
    "sticking": ("stiff-sticking.toml", 0.5, 5.0, 11.0, 0.2, "both"),
}
METHODS = [("fixed 300 periods (practice)", "fixed_periods = 300"),
           ("steady-state detection (today)", 'method = "steady"'),
           ("transient-aware", 'method = "transient"')]
REFERENCE = "fixed_periods = 2000\nmax_periods = 5000"     # the settled value on the nonlinear rigs
TIGHT = [("steady-state detection, tol 1e-5", 'method = "steady"\ntolerance = 1e-5'),      # linear rigs only:
         ("transient-aware, tol 1e-5", 'method = "transient"\ntolerance = 1e-5')]         # equal accuracy


def sweep(rig, case, settle: str, out: Path):
    """Run one sweep; shaker seconds, seconds at records, wall seconds and per run (frequency, FRFs, transient
    flags)."""
    _, force, start, stop, step, direction = case
    text = (f"[settle]\n{settle}\n[[stepped_sine]]\nforce = {force}\nstart = {start}\nstop = {stop}\n"
            f"step = {step}\ndirection = \"{direction}\"\nrefine = false\n" + LIMITS)
    plan = parse_plan(tomllib.loads(text), text)
    t = time.perf_counter()
    with emulated_instruments(rig) as inst:
        summary = run_plan(plan, inst, out, overwrite=True)
    wall = time.perf_counter() - t
    runs, at_records = {}, 0.0
    with open_session(out) as s:
        for name in s.run_names():
            run = s.run(name)
            at_records += float(np.sum(run.arrays["settle_periods"] / run.arrays["measured_frequency"]))
            runs[name] = (run.arrays["measured_frequency"], np.stack([run.frf[d] for d in rig.sensor_dofs], 1),
                          run.arrays["transient"])
    return summary.shaker_seconds, at_records, wall, runs


def accuracy(rig, runs, reference) -> tuple[float, int]:
    """Largest relative FRF error (against the analytic receptance of a linear rig, else the reference run's
    line) and the lines on a wrong branch."""
    worst, wrong = 0.0, 0
    for name, (f, H, _) in runs.items():
        if reference is None:
            truth = rig.structure.frf(2 * np.pi * f, columns=[rig.excitation_dof])[:, :, 0]
        else:
            truth = reference[name][1]
        with np.errstate(invalid="ignore"):
            err = np.abs(H / truth - 1)
            worst = max(worst, float(np.nanmax(err)))
            wrong += int(np.sum(np.nanmax(np.abs(np.abs(H) / np.abs(truth) - 1), axis=1) > BRANCH))
    return worst, wrong


def element_kbar(model, session: Path) -> dict:
    """Run name -> (kbar, kbar_std), shape (L, r): every line of the session identified with the rig's structure
    (``model``, the rig file read as a model) as the reference and its elements as the unknowns."""
    out = {}
    for run in read_measurements(session).sine:
        ident = identify_complex_stiffness(model.structure, run.receptance, run.sensor_dofs, run.excitation_dof,
                                           model.elements, w=run.w, force=run.force_per_line,
                                           noise_std=run.receptance_std)
        out[run.name] = (ident.kbar, ident.kbar_std)
    return out


def kbar_agreement(kbar: dict, reference: dict) -> tuple[float, float]:
    """Largest |kbar - kbar_ref| / sqrt(std^2 + std_ref^2) over the lines and elements of every run, and the share
    within 3."""
    z = []
    for name, (k, s) in kbar.items():
        k_ref, s_ref = reference[name]
        with np.errstate(invalid="ignore", divide="ignore"):
            z.append((np.abs(k - k_ref) / np.hypot(s, s_ref)).ravel())
    z = np.concatenate(z)
    z = z[np.isfinite(z)]
    return float(z.max()), float(np.mean(z <= 3.0))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rigs", default="light,linear,hardening,friction", help="any of " + ",".join(CASES))
    ap.add_argument("--tolerances", default="", metavar="TOL,...",
                    help="the transient-aware lines also at these settle tolerances, on every rig: the comparison at "
                         "the fixed practice's own accuracy where it is coarser than the default's")
    args = ap.parse_args()
    looser = [(f"transient-aware, tol {t}", f'method = "transient"\ntolerance = {t}')
              for t in args.tolerances.split(",") if t]
    tmp = Path(tempfile.mkdtemp())
    print(f"load average at start: {os.getloadavg()[0]:.1f}")
    for key in args.rigs.split(","):
        case = CASES[key]
        rig_path = ROOT / "tests" / "rigs" / case[0]
        rig = load_rig(rig_path)
        model = load_model(tomllib.loads(rig_path.read_text()), str(rig_path))
        linear = key in ("light", "linear")
        methods = METHODS + (TIGHT if linear else []) + looser
        results, kbars = {}, {}
        for number, (name, settle) in enumerate(methods):
            results[name] = sweep(rig, case, settle, tmp / f"{key}-{number}.h5")
            if not linear:
                kbars[name] = element_kbar(model, tmp / f"{key}-{number}.h5")
        reference = None if linear else sweep(rig, case, REFERENCE, tmp / f"{key}-reference.h5")[3]
        kbar_reference = None if linear else element_kbar(model, tmp / f"{key}-reference.h5")
        fixed = results[METHODS[0][0]][0]
        today = results[METHODS[1][0]][0]
        print(f"\n{key} ({case[0]}, {case[2]:g}-{case[3]:g} Hz step {case[4]:g}, {case[1]:g} N, {case[5]}); "
              f"accuracy against {'the analytic receptance' if linear else 'the lines settled for 2000 periods'}")
        print(f"{'method':32s} {'shaker s':>9s} {'vs fixed':>9s} {'vs today':>9s} {'at records':>10s} "
              f"{'max FRF err':>12s} {'wrong br.':>9s} {'transient':>10s} {'wall s':>7s}"
              + ("" if linear else f" {'kbar z':>8s} {'<= 3 std':>8s}"))
        for name, _ in methods:
            shaker, records, wall, runs = results[name]
            err, wrong = accuracy(rig, runs, reference)
            n = sum(len(r[0]) for r in runs.values())
            via = sum(int(np.sum(r[2])) for r in runs.values())
            agreement = "" if linear else "{:9.2f} {:7.0%}".format(*kbar_agreement(kbars[name], kbar_reference))
            print(f"{name:32s} {shaker:9.1f} {fixed / shaker:8.1f}x {today / shaker:8.1f}x {records:10.1f} {err:12.1e} "
                  f"{wrong:9d} {via:4d}/{n:<5d} {wall:7.1f}{agreement}")
    print(f"\nload average at end: {os.getloadavg()[0]:.1f}")


if __name__ == "__main__":
    main()
