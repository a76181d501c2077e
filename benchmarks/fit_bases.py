"""A fit's law bases kept across its passes: what it saves where fits leave outliers out.

    python benchmarks/fit_bases.py [--repeats N]

The loop from an empty joint on the RK4 rig of tests/test_auto.py (one joint with a hardening cubic spring and
quadratic damping, two force levels, receptances integrated in time, no harmonics: every kbar fit of discovery
leaves outliers out, from a reweighted start). A robust fit is many passes over the same samples -- Huber
reweightings, outlier passes, a placed contact's refits -- each a local search that starts where the last ended.
Their law bases are now kept by the fit's samples (``analysis.fitting.samples._Bases``), evaluated once at every
sample and shared by every pass and subset. Baseline, run in this process: each pass's problem keeps its own bases
over its own samples, as before. Runs alternate; prints the CPU of each, the ratio of the medians, and both runs'
steps and final errors (they must agree).
"""
from __future__ import annotations

import argparse
import os
import statistics
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "tests"))

import analysis.fitting.projection as projection  # noqa: E402
from analysis.common.measurements import Measurements  # noqa: E402
from analysis.fitting.samples import _Bases  # noqa: E402
from analysis.loop.auto import run_auto  # noqa: E402
import test_auto  # noqa: E402


class _PerProblem:
    """The baseline: every problem its own bases over its own samples."""

    def __init__(self):
        self.init = projection._Problem.__init__

    def __enter__(self):
        init = self.init

        def own(problem, terms, X, w, kbar, w_re, w_im, rank_rtol, bases, rows):
            init(problem, terms, X, w, kbar, w_re, w_im, rank_rtol, _Bases(X, w), None)
        projection._Problem.__init__ = own

    def __exit__(self, *exc):
        projection._Problem.__init__ = self.init


def loop(data: Measurements) -> tuple[float, list[str], float]:
    wb = test_auto.started(data, test_auto.element("a", "x1", ""))
    start = time.process_time()
    result = run_auto(wb)
    return time.process_time() - start, [s.line() for s in result.steps], wb.compare().error


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=2)
    args = parser.parse_args()
    data = test_auto.rk4_joint_measurements()
    loop(data)                                   # compile and warm up once
    kept, own = [], []
    for i in range(args.repeats):
        cpu, steps, error = loop(data)
        kept.append(cpu)
        with _PerProblem():
            cpu0, steps0, error0 = loop(data)
        own.append(cpu0)
        print(f"run {i + 1}: bases kept by the fit {cpu:.1f} s, by each pass {cpu0:.1f} s", flush=True)
        if steps != steps0 or abs(error - error0) > 1e-9 * error0:
            raise SystemExit(f"the two runs differ:\n  {steps}, {error}\n  {steps0}, {error0}")
    print(f"steps: {steps}; error {error:.4g} (both runs)")
    print(f"CPU of the loop: {statistics.median(own):.1f} -> {statistics.median(kept):.1f} s "
          f"(x{statistics.median(own) / statistics.median(kept):.2f})")


if __name__ == "__main__":
    # the analysis on one core: its CPU seconds are this process's (analysis.common.parallel)
    os.environ.setdefault("CONTACTID_WORKERS", "1")
    main()
