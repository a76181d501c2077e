"""A law set refined against the FRFs: what its Jacobian costs.

    python benchmarks/frf_refinement_speed.py [--session SESSION.h5] [--pairs N]

The paper's 2-DOF example at two force levels through the emulated rig (benchmarks/discovery_speed.py's session),
its four laws started 20 % off Table 1, each element's laws refined against the FRFs in turn with the other held
(``analysis.prediction.frf_refinement.refine_against_frfs``). The Jacobian's forward differences predict every
run once per parameter. Now each difference's prediction starts at every line from the prediction at the point it
steps from (``Predictor.predict``'s ``near``): a few Newton steps per line at once, not a sweep. Baseline, run in
this process: ``near`` ignored, each difference a whole sweep, as scipy's own differences did. Prints the CPU of
both, the ratio, and both runs' refined values and chi-square (they must agree within the standard errors).
"""
from __future__ import annotations

import os
import sys
import time
import tomllib
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))
sys.path.insert(0, str(ROOT / "tests"))

from analysis.mechanics.elements import LawTerm  # noqa: E402
from analysis.mechanics.model import load_model  # noqa: E402
from analysis.prediction.comparison import Predictor  # noqa: E402
from analysis.prediction.frf_refinement import refine_against_frfs, terms_function  # noqa: E402
from discovery_speed import benchmark_main  # noqa: E402
from paper_structure import PAPER_STRUCTURE  # noqa: E402

TABLE_1 = {"left": {"cubic": {"k3": -500.0}, "quadratic_damping": {"c2": 1.0}},
           "right": {"cubic": {"k3": -750.0}, "coulomb": {"fs": 0.1}}}
MODEL = PAPER_STRUCTURE + "".join(f'\n[[element]]\nname = "{n}"\ndof = "{d}"\nlaws = {list(TABLE_1[n])!r}\n'
                                  .replace("'", '"') for n, d in (("left", "x1"), ("right", "x2")))


def refinements(predictor: Predictor) -> tuple[float, list[str]]:
    """CPU seconds of refining each element's laws from 20 % off Table 1 with the other at Table 1, and what
    each refinement gave."""
    truth = {i: [LawTerm(t.law, dict(TABLE_1[e.name][t.law.name])) for t in e.laws]
             for i, e in enumerate(predictor.model.elements)}
    out = []
    t = time.process_time()
    for i, terms in truth.items():
        start = [LawTerm(term.law, {n: 1.2 * v for n, v in term.values.items()}) for term in terms]
        others = {j: terms_function(held) for j, held in truth.items() if j != i}
        r = refine_against_frfs(predictor, i, start, [list(term.law.param_names) for term in terms], others)
        out.append(f"{predictor.model.elements[i].name}: chi2 {r.chi_square:.6g} in {r.evaluations} evaluations; "
                   + "; ".join(f"{t.law.name} {r.size_text(j)}" for j, t in enumerate(r.terms)))
    return time.process_time() - t, out


def baseline_refinements(predictor: Predictor) -> tuple[float, list[str]]:
    """:func:`refinements` with ``near`` ignored: every difference swept."""
    predict = Predictor.predict
    Predictor.predict = lambda self, kbar_fns=None, near=None: predict(self, kbar_fns)
    try:
        return refinements(predictor)
    finally:
        Predictor.predict = predict


def _show(old, new) -> None:
    for label, (cpu, lines) in (("baseline", old), ("now", new)):
        print(f"{label:9s} {cpu:7.2f} s CPU")
        for line in lines:
            print(f"    {line}")
    print(f"ratio     x{old[0] / new[0]:.2f}  (same refinements: {old[1] == new[1]})")


def main() -> None:
    def runs(measurements):
        predictor = Predictor(load_model(tomllib.loads(MODEL)), measurements)
        return lambda: baseline_refinements(predictor), lambda: refinements(predictor)
    benchmark_main(__doc__.splitlines()[0], 3, runs, _show)


if __name__ == "__main__":
    # the analysis on one core: its CPU seconds are this process's (analysis.common.parallel)
    os.environ.setdefault("CONTACTID_WORKERS", "1")
    main()
