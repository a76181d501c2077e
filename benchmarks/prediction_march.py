"""Single-harmonic prediction of short sweeps: marched line by line against solved all at once.

    python benchmarks/prediction_march.py

``analysis.prediction.harmonic_balance`` marches a sweep of at most ``MARCHED_STEPS`` lines line by line (Newton at
each line from the line before) and solves a longer one at all its lines at once, then checks it is what the march
gives (``_speculative_sweep``). Where the describing functions cost a Python call each (an Iwan element's, a
Jenkins element's), a march pays that call at every line and Newton step, and a batch once per step for all its
lines. The baseline is the earlier setting (``MARCHED_STEPS = 64``: every sweep of the cases below marched), run in
this process; the fast path is the setting in the module. Each case prints the CPU per prediction (both sweep
directions, every level) for both, the ratio, and the largest difference of the phasors and of the convergence and
stability flags (the same to Newton's tolerance is the requirement).

Cases, all with the laws of the rig that made them (nothing fitted): the paper-beam rig (an Iwan element at the
tangential contact, a spring at the normal one) on the lines of ``contactid demo --quick`` (36 lines, 3 levels);
an SDOF with a Jenkins joint (tests/rk4_rig.py's values) on 41 lines at 4 levels; the paper's 2-DOF on 49 lines at
2 levels.
"""
from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import analysis.prediction.harmonic_balance as hb  # noqa: E402
from analysis import load_elements, load_structure  # noqa: E402
from drivers.simulation.rig import load_rig  # noqa: E402

BASELINE_MARCHED_STEPS = 64
REPEATS = 3

JENKINS_SDOF = ({"type": "lumped", "dofs": ["x1"], "mass": [[1.0]], "stiffness": [[15791.367]],
                 "damping": [[2.884]]},
                {"element": [{"name": "joint", "dof": "x1", "laws": [{"law": "jenkins", "kt": 5000.0, "fs": 0.05}]}]})
PAPER_2DOF = ({"type": "lumped", "dofs": ["x1", "x2"], "mass": [[1.0, 0.0], [0.0, 2.0]],
               "stiffness": [[200.0, -100.0], [-100.0, 200.0]]},
              {"element": [
                  {"name": "left", "dof": "x1",
                   "laws": [{"law": "cubic", "k3": -500.0}, {"law": "quadratic_damping", "c2": 1.0}]},
                  {"name": "right", "dof": "x2",
                   "laws": [{"law": "cubic", "k3": -750.0}, {"law": "coulomb", "fs": 0.1}]}]})


def cases():
    beam = load_rig("paper-beam")
    yield ("paper-beam (iwan + spring), 36 lines x 3 levels", beam.structure, beam.elements, beam.excitation_dof,
           2 * np.pi * np.arange(51.0, 54.55, 0.1), [0.02, 0.3, 1.2])
    for name, (structure, elements), exc, hz, forces in (
            ("SDOF with a Jenkins joint, 41 lines x 4 levels", JENKINS_SDOF, "x1", np.linspace(19.0, 25.0, 41),
             [0.002, 0.01, 0.03, 0.06]),
            ("paper 2-DOF (cubic, quadratic damping, Coulomb), 49 lines x 2 levels", PAPER_2DOF, "x2",
             np.linspace(0.8, 3.2, 49), [0.4, 0.8])):
        s = load_structure(structure)
        yield name, s, load_elements(elements, s), exc, 2 * np.pi * hz, forces


def timed(structure, elements, exc, w, forces, marched_steps: int):
    hb.MARCHED_STEPS = marched_steps
    start = time.process_time()
    for _ in range(REPEATS):
        out = hb.predict_sweeps(structure, elements, exc, w, forces)
    return (time.process_time() - start) / REPEATS, out


def main() -> None:
    fast_setting = hb.MARCHED_STEPS
    print(f"marched up to {BASELINE_MARCHED_STEPS} lines (baseline) against up to {fast_setting} (the module's)")
    try:
        for name, structure, elements, exc, w, forces in cases():
            base_t, base = timed(structure, elements, exc, w, forces, BASELINE_MARCHED_STEPS)
            fast_t, fast = timed(structure, elements, exc, w, forces, fast_setting)
            diff = max(float(np.max(np.abs(a.y - b.y)) / np.max(np.abs(b.y))) for a, b in zip(fast, base))
            same = all((a.converged == b.converged).all() and (a.stable == b.stable).all()
                       for a, b in zip(fast, base))
            print(f"{name}: {base_t * 1e3:.1f} ms -> {fast_t * 1e3:.1f} ms per prediction (x{base_t / fast_t:.2f}); "
                  f"largest phasor difference {diff:.1e} of the largest phasor; flags {'the same' if same else 'DIFFER'}")
    finally:
        hb.MARCHED_STEPS = fast_setting


if __name__ == "__main__":
    main()
