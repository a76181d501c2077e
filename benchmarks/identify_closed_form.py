"""Closed-form identification versus the paper's per-line root solve, same process.

Paper 2DOF example (section 3): K = 100 [[2, -1], [-1, 2]] N/m, M = diag(1, 2) kg,
force 0.8 N on x2, elements grounded at x1 and x2 with the describing functions of
eqs. 30-31 (kn1 = 500, cn = 1, kn2 = 750, mu = 0.1). The element amplitudes are
prescribed as 0.8 N times the receptance of the reference with C = 0.02 K (so they
have the paper's size without a harmonic-balance solve); the "measured" receptance
is then (Z + Delta)^-1 by a direct solve, exact to round-off.

Run:  python benchmarks/identify_closed_form.py [--lines 2001]
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT), str(ROOT / "tests")]

from test_identify import FORCE, paper_case  # noqa: E402  (one definition of the paper case)
from analysis.identification.identify import identify_complex_stiffness  # noqa: E402
from analysis.identification.sherman_morrison import solve_per_line  # noqa: E402


def paper_data(n_lines: int):
    """The test suite's paper case (tests/test_identify.py): reference H, measured rows, true kbar."""
    s, w, kbar, measured = paper_case(n_lines)
    return s.frf(w), measured, kbar


def best_time(fn, repeats: int) -> float:
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        fn()
        times.append(time.perf_counter() - start)
    return min(times)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--lines", type=int, default=2001)
    args = parser.parse_args()
    H, measured, kbar_true = paper_data(args.lines)
    rows, column, elements = [0, 1], 1, [(0,), (1,)]

    def closed_form():
        return identify_complex_stiffness(H, measured, rows, column, elements, force=FORCE)

    closed = closed_form()
    t_closed = best_time(closed_form, 20)
    start = time.perf_counter()
    root = solve_per_line(H, measured, rows, column, elements)
    t_root = time.perf_counter() - start

    ok = root.converged
    agreement = np.abs(root.kbar[ok] - closed.kbar[ok]) / np.abs(closed.kbar[ok])
    closed_error = np.abs(closed.kbar - kbar_true) / np.abs(kbar_true)
    print(f"paper 2DOF, {args.lines} lines, 2 elements")
    print(f"closed form          : {t_closed * 1e3:8.2f} ms (best of 20)")
    print(f"root solve, zero start: {t_root * 1e3:8.1f} ms ({root.evaluations.mean():.1f} residual evaluations/line)")
    print(f"speed ratio          : {t_root / t_closed:8.0f} x")
    print(f"root solve failed on : {np.count_nonzero(~ok)} of {args.lines} lines")
    print(f"max |difference| / |kbar| on converged lines: {agreement.max():.2e}")
    print(f"closed form vs truth : max relative error {closed_error.max():.2e}; "
          f"{np.count_nonzero(closed.ill_conditioned)} lines flagged ill-conditioned "
          f"(max cond {closed.cond.max():.3g})")


if __name__ == "__main__":
    main()
