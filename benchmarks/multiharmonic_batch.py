"""Multi-harmonic balance of independent lines: solved all at once against line by line.

    python benchmarks/multiharmonic_batch.py

``analysis.prediction.multiharmonic.predict_multiharmonic`` started from each line's single-harmonic solution
(what the comparison with harmonics and the fundamental's bias ask) solves every line at once: Broyden's method
from a difference Jacobian, every row of the batch and its perturbations marched through the laws in one compiled
call per element (``_quasi_newton``, ``_MultiharmonicLines``). The baseline, run in this process, is how it was
done before: scipy's ``hybr`` at each line on its own from the same start (``_MultiharmonicLines.solve_one``). Each
case prints the CPU of one prediction both ways (median of five), the ratio, the lines converged both ways and
the largest difference of the element phasors where both converged, relative to the largest phasor.

Cases: the 2-DOF chain of tests/test_harmonic_balance.py (masses 1 and 1, springs 3000/-1000/2000 N/m, Rayleigh
damping) driven at x2 with 0.5 N on 31 lines from 5 to 11 Hz, 7 harmonics and 512 points per period (the
comparison's setting), with Anderson-Ferri friction, Coulomb friction, a clearance, an Iwan element, and a Jenkins
element at x2 beside a cubic spring at x1.
"""
from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from analysis import load_elements, load_structure  # noqa: E402
from analysis.prediction.harmonic_balance import predict_sweep  # noqa: E402
from analysis.prediction.multiharmonic import _MultiharmonicLines, predict_multiharmonic  # noqa: E402

CHAIN = {"type": "lumped", "dofs": ["x1", "x2"], "mass": [[1.0, 0.0], [0.0, 1.0]],
         "stiffness": [[3000.0, -1000.0], [-1000.0, 2000.0]], "rayleigh": [0.3, 1.0e-4]}
CASES = {
    "anderson_ferri": [{"name": "b", "dof": "x2", "laws": [{"law": "anderson_ferri", "a": 0.1, "b": 30.0, "c": 0.0}]}],
    "coulomb": [{"name": "b", "dof": "x2", "laws": [{"law": "coulomb", "fs": 0.15}]}],
    "gap": [{"name": "b", "dof": "x2", "laws": [{"law": "gap", "k": 3000.0, "gap": 0.002}]}],
    "iwan": [{"name": "b", "dof": "x2", "laws": [{"law": "iwan", "kt": 800.0, "fs": 0.3, "chi": -0.5, "beta": 0.1}]}],
    "jenkins + cubic": [{"name": "b", "dof": "x2", "laws": [{"law": "jenkins", "kt": 500.0, "fs": 0.2}]},
                        {"name": "a", "dof": "x1", "laws": [{"law": "cubic", "k3": 3e6}]}],
}
H, N_TIME, FORCE, REPEATS = 7, 512, 0.5, 5


def cpu(fn) -> tuple[float, object]:
    times, out = [], None
    for _ in range(REPEATS):
        start = time.process_time()
        out = fn()
        times.append(time.process_time() - start)
    return float(np.median(times)), out


def main() -> None:
    w = 2 * np.pi * np.arange(5.0, 11.01, 0.2)
    print(f"{'case':18s} {'batch s':>9s} {'per line s':>11s} {'ratio':>7s} {'converged':>11s} {'max diff':>9s}")
    for name, spec in CASES.items():
        s = load_structure(CHAIN)
        els = load_elements({"element": spec}, s, None, True)
        y1 = predict_sweep(s, els, "x2", w, FORCE).y[:, 0]
        start = np.zeros((len(w), H + 1, len(els)), complex)
        start[:, 1] = y1
        idx = np.arange(len(w))

        def per_line():
            lines = _MultiharmonicLines(s, els, "x2", w, np.full(len(w), FORCE), H, N_TIME)
            z = np.array([lines.solve_one(i, start[i]) for i in idx])
            return lines, z

        predict_multiharmonic(s, els, "x2", w[:2], FORCE, H, N_TIME, y_start=y1[:2])      # compiled first
        batch_s, mh = cpu(lambda: predict_multiharmonic(s, els, "x2", w, FORCE, H, N_TIME, y_start=y1))
        line_s, (lines, z) = cpu(per_line)
        ok = np.linalg.norm(lines.residual(z, idx), axis=1) < 1e-8
        both = ok & mh.converged
        diff = np.abs(mh.element_harmonics[both] - lines.unpack(z, idx)[both]).max(initial=0.0)
        rel = diff / np.abs(mh.element_harmonics).max()
        print(f"{name:18s} {batch_s:9.3f} {line_s:11.3f} {line_s / batch_s:7.1f} "
              f"{f'{mh.converged.sum()}/{ok.sum()}/{len(w)}':>11s} {rel:9.1e}")


if __name__ == "__main__":
    main()
