"""Discovery from an empty model: what its law fits, describing functions and predicted sweeps cost.

    python benchmarks/discovery_speed.py [--session SESSION.h5]

Four changes, measured together on the paper's 2-DOF example from a model with no law (two force levels, 0.4 and
0.8 N, through the emulated rig: the shape of tests/test_discovery.py's empty-model case):
- The reweighted (Huber) start of a robust fit stops once a pass moves no sample's distance from the fit by more
  than 1 % of the larger of one standard deviation and the fit's rms distance
  (``analysis.fitting.robust._settled``). Before, it stopped only when the weights agreed within 1e-3: the law
  sets that miss the samples by tens of standard deviations converge linearly and took all 20 passes.
- A law's basis no longer broadcasts amplitudes and lines that already share a shape
  (``analysis.laws.base.broadcast``): ``np.broadcast_arrays`` cost more than a small law's arithmetic in the
  harmonic balance's Newton steps.
- A predicted line's restarts, solved as one batch, stop once an earlier restart of the same line has converged
  (``analysis.prediction.harmonic_balance._after_the_first``): only a line's first converged restart is taken.
  Before, the batch went on until its slowest restart ended, most often one that never converges.
- A law's march over a sampled history is compiled with its kernel fixed (``analysis.laws.base._marcher``);
  before, the kernel was an argument of one compiled march, which numba typed anew at every call (about 25 us,
  more than the march itself: the AFT and a placed contact's balance march thousands of times).

Baseline, run in this process: ``_settled`` answering "not yet" (the weights' rule alone), every module's
``broadcast`` replaced by ``np.broadcast_arrays``, no restart stopped early, and the kernel passed to one
compiled march. Prints the CPU of both, the ratio, and both runs' steps and
final errors (they must agree).
"""
from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
import tomllib
from pathlib import Path

import numpy as np
from numba import njit

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "tests"))

import analysis.fitting.robust as robust  # noqa: E402
import analysis.prediction.harmonic_balance as hb  # noqa: E402
from analysis.laws import base  # noqa: E402
from analysis.loop.auto import run_auto  # noqa: E402
from analysis.loop.workbench import Workbench  # noqa: E402
from analysis.mechanics.model import load_model  # noqa: E402
from app.campaign.instruments import emulated_instruments  # noqa: E402
from app.campaign.measure import run_plan  # noqa: E402
from app.campaign.plan import parse_plan  # noqa: E402
from app.session.data import measurements_from_session  # noqa: E402
from app.session.writer import open_session  # noqa: E402
from drivers.simulation.rig import load_rig  # noqa: E402
from paper_structure import PAPER_STRUCTURE  # noqa: E402

MODEL = PAPER_STRUCTURE + """
[[element]]
name = "left"
dof = "x1"
laws = []

[[element]]
name = "right"
dof = "x2"
laws = []
"""
PLAN = "".join(f"[[stepped_sine]]\nforce = {F}\nstart = 0.8\nstop = 3.2\nstep = 0.025\ndirection = \"up\"\n"
               for F in (0.4, 0.8)) + "[limits]\nmax_force = 5.0\nmax_acceleration = 50.0\n"


def session(path: Path) -> Path:
    with emulated_instruments(load_rig("paper-2dof"), seed=3) as inst:
        assert run_plan(parse_plan(tomllib.loads(PLAN), PLAN), inst, path).complete
    return path


def discovery(measurements) -> tuple[float, list[str], float]:
    """CPU seconds of identification and ``run_auto`` from the empty model, its steps and final error."""
    t = time.process_time()
    wb = Workbench(load_model(tomllib.loads(MODEL)), measurements)
    wb.start()
    result = run_auto(wb)
    return time.process_time() - t, [s.line() for s in result.steps], wb.history[-1].error


def _broadcast_before(X, w):
    return np.broadcast_arrays(np.asarray(X), np.asarray(w))


@njit
def _march_with_the_kernel_an_argument(kernel, x, v, p, s):
    f = np.empty(x.shape[0])
    for i in range(x.shape[0]):
        f[i] = kernel(x[i], v[i], p, s)
    return f


def _marcher_before(kernel):
    return lambda x, v, p, s: _march_with_the_kernel_an_argument(kernel, x, v, p, s)


def baseline_patches() -> list[tuple[object, str, object]]:
    """(module, name, value) of the baseline: the weights' rule alone, ``np.broadcast_arrays`` everywhere, every
    restart solved to its end, the kernel an argument of the march."""
    patches = [(robust, "_settled", lambda distance, before: False),
               (hb, "_after_the_first", lambda which: lambda converged: np.zeros(len(which), bool)),
               (base, "_marcher", _marcher_before)]
    for module in list(sys.modules.values()):
        if getattr(module, "__name__", "").startswith("analysis.") and getattr(module, "broadcast", None) is base.broadcast:
            patches.append((module, "broadcast", _broadcast_before))
    return patches


def baseline_discovery(measurements) -> tuple[float, list[str], float]:
    """:func:`discovery` with the baseline's patches in place."""
    saved = [(m, n, getattr(m, n)) for m, n, _ in baseline_patches()]
    for module, name, value in baseline_patches():
        setattr(module, name, value)
    try:
        return discovery(measurements)
    finally:
        for module, name, value in saved:
            setattr(module, name, value)


def paper_measurements(path: Path | None):
    """The measurements of a session of the plan above: ``path``'s, or a fresh campaign's."""
    with tempfile.TemporaryDirectory() as tmp:
        with open_session(path or session(Path(tmp) / "paper-2dof.h5")) as s:
            return measurements_from_session(s)


def alternated(pairs: int, baseline, current, show) -> None:
    """``baseline()`` and ``current()`` run in turn ``pairs`` times after one warming run of ``current`` (numba's
    law kernels and every lazy import, paid once), each pair shown by ``show(old, new)``: a shared machine's speed
    drifts by 10-20 % over minutes."""
    current()
    for _ in range(pairs):
        old = baseline()
        show(old, current())


def _show(old, new) -> None:
    for label, (cpu, steps, error) in (("baseline", old), ("now", new)):
        print(f"{label:9s} {cpu:7.1f} s CPU  final error {error:.6g}")
        for line in steps:
            print(f"          {line}")
    print(f"ratio     x{old[0] / new[0]:.2f}  (same steps: {old[1] == new[1]})")


def benchmark_main(description: str, default_pairs: int, runs, show) -> None:
    """The command line of a benchmark on a session of the plan above (``--session``, ``--pairs``):
    ``runs(measurements)`` gives its (baseline, current) pair of runs, alternated (:func:`alternated`)."""
    ap = argparse.ArgumentParser(description=description)
    ap.add_argument("--session", type=Path, help="a session of discovery_speed.py's plan (simulated if not given)")
    ap.add_argument("--pairs", type=int, default=default_pairs,
                    help=f"baseline and current runs, alternated (default {default_pairs})")
    args = ap.parse_args()
    alternated(args.pairs, *runs(paper_measurements(args.session)), show)


def main() -> None:
    benchmark_main(__doc__.splitlines()[0], 2,
                   lambda m: (lambda: baseline_discovery(m), lambda: discovery(m)), _show)


if __name__ == "__main__":
    # the analysis on one core: its CPU seconds are this process's (analysis.common.parallel)
    os.environ.setdefault("CONTACTID_WORKERS", "1")
    main()
