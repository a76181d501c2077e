"""Workbench speed: harmonic-balance prediction and the missing-effect ranking.

    python benchmarks/workbench_speed.py [--session PAPER_BEAM.h5]

1. Prediction of 200 lines x 6 force levels for the paper's 2-element model (cubic + quadratic damping at x1,
   cubic + Coulomb at x2): the batched condensed Newton of analysis.prediction.harmonic_balance against a plain baseline
   in the same process -- scipy.optimize.fsolve on the full (uncondensed) single-harmonic equations, line by
   line and level by level, started from the previous line. Target < 1 s.
2. The whole candidate ranking for a paper-beam session (default plan; simulated first when no session is
   given): reference updating, identification, fit, linear correction, then every (element, law) candidate
   fitted and predicted. Target < 30 s.
"""
from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import scipy.optimize

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from analysis import load_elements, load_structure  # noqa: E402
from analysis.prediction.harmonic_balance import condense, predict_sweep, predict_sweeps  # noqa: E402

STRUCTURE = {"type": "lumped", "dofs": ["x1", "x2"], "mass": [[1.0, 0.0], [0.0, 2.0]],
             "stiffness": [[200.0, -100.0], [-100.0, 200.0]], "rayleigh": [0.0, 0.005]}
ELEMENTS = {"element": [
    {"name": "left", "dof": "x1", "laws": [{"law": "cubic", "k3": -500.0}, {"law": "quadratic_damping", "c2": 1.0}]},
    {"name": "right", "dof": "x2", "laws": [{"law": "cubic", "k3": -750.0}, {"law": "coulomb", "fs": 0.1}]}]}


def baseline(structure, elements, w, forces):
    """fsolve on Z(w) x + Delta(|x|) x = F e_q for every line and level, real and imaginary parts."""
    n = structure.n
    q = structure.index("x2")
    E = np.stack([el.vector(structure) for el in elements], axis=1)
    out = np.zeros((len(w), len(forces), n), complex)
    for b, F in enumerate(forces):
        x = np.zeros(n, complex)
        for i, wi in enumerate(w):
            Z = structure.dynamic_stiffness([wi])[0]
            rhs = np.zeros(n)
            rhs[q] = F

            def residual(v):
                xx = v[:n] + 1j * v[n:]
                y = E.T @ xx
                k = np.array([el.describing_function(max(abs(y[j]), 1e-12), wi) for j, el in enumerate(elements)])
                R = Z @ xx + E @ (k * y) - rhs
                return np.r_[R.real, R.imag]

            if not x.any():
                x = np.linalg.solve(Z, rhs)
            v = scipy.optimize.fsolve(residual, np.r_[x.real, x.imag], xtol=1e-12)
            x = v[:n] + 1j * v[n:]
            out[i, b] = x / F
    return out


def prediction_benchmark():
    s = load_structure(STRUCTURE)
    els = load_elements(ELEMENTS, s, None, True)
    w = 2 * np.pi * np.linspace(0.8, 3.2, 200)
    # levels where the Coulomb contact slides (below about 0.3 N it holds: no single-harmonic solution)
    forces = [0.3, 0.4, 0.5, 0.6, 0.7, 0.8]
    predict_sweep(s, els, "x2", w[:3], forces)                  # imports and first calls out of the timing
    t = time.perf_counter()
    pred = predict_sweep(s, els, "x2", w, forces, "up", system=condense(s, els, "x2", w))
    fast = time.perf_counter() - t
    t = time.perf_counter()
    ref = baseline(s, els, w, forces)
    slow = time.perf_counter() - t
    agree = np.abs(pred.receptance - ref).max() / np.abs(ref).max()
    t = time.perf_counter()
    both = predict_sweeps(s, els, "x2", w, forces, ("up", "down"), system=condense(s, els, "x2", w))
    two_way = time.perf_counter() - t
    same = np.abs(both[0].receptance - pred.receptance).max()
    print(f"prediction 200 lines x 6 levels, 2 elements: {fast:.3f} s (target < 1 s); fsolve baseline "
          f"{slow:.2f} s; ratio {slow / fast:.0f} x; converged {pred.converged.mean():.3f}; "
          f"max difference {agree:.1e} of the largest receptance")
    print(f"both sweep directions in one batch (the jump-robust error): {two_way:.3f} s, {two_way / fast:.2f} x "
          f"one direction; up sweep identical to {same:.1e}")


def ranking_benchmark(session: Path | None):
    from analysis.mechanics.model import load_model
    from analysis.common.tables import load_toml
    from analysis.loop.workbench import Workbench
    from app.campaign.instruments import emulated_instruments
    from app.campaign.measure import run_plan
    from app.campaign.plan import load_plan
    from app.session.writer import open_session
    from app.session.data import measurements_from_session
    from app.models import builtin_plan_path
    from drivers.simulation.rig import load_rig

    if session is None:
        session = Path(tempfile.mkdtemp()) / "paper-beam.h5"
        t = time.perf_counter()
        with emulated_instruments(load_rig("paper-beam")) as inst:
            summary = run_plan(load_plan(builtin_plan_path("paper-beam")), inst, session)
        print(f"paper-beam default plan simulated: {summary.lines} lines in {time.perf_counter() - t:.0f} s")
    with open_session(session) as s:
        measurements = measurements_from_session(s)
    model = load_model(load_toml(ROOT / "app" / "models" / "paper-beam.model.toml"))
    t = time.perf_counter()
    wb = Workbench(model, measurements)
    wb.update_reference()
    wb.start()
    wb.apply_linear_corrections(wb.linear_corrections())
    t_start = time.perf_counter() - t
    t = time.perf_counter()
    comp = wb.predictor.compare(locate_folds=True, harmonics=wb.harmonics)
    t_report = time.perf_counter() - t
    t = time.perf_counter()
    single = wb.predictor.compare()
    t_single = time.perf_counter() - t
    print(f"paper-beam comparison for the report (both sweeps, folds located, {sum(m.sum() for m in comp.multiharmonic.values())} "
          f"lines multi-harmonic): {t_report:.2f} s; single-harmonic comparison {t_single:.2f} s; error "
          f"{comp.error:.4g} (single-harmonic {single.error:.4g})")
    t = time.perf_counter()
    ranked = wb.candidates()
    t_rank = time.perf_counter() - t
    lines = sum(len(r.frequency_hz) for r in measurements.sine)
    print(f"paper-beam ranking: {len(ranked)} candidates over {lines} lines in {len(measurements.sine)} runs: "
          f"{t_rank:.1f} s (+ {t_start:.1f} s reference, identification and fit; target < 30 s in all); "
          f"top {ranked[0].element}:{ranked[0].law} (x{ranked[0].gain:.1f})")


def main():
    parser = argparse.ArgumentParser()
    parser.add_argument("--session", type=Path, help="a paper-beam session (default: simulate one)")
    args = parser.parse_args()
    prediction_benchmark()
    ranking_benchmark(args.session)


if __name__ == "__main__":
    # the analysis on one core: its CPU seconds are this process's (analysis.common.parallel)
    os.environ.setdefault("CONTACTID_WORKERS", "1")
    main()
