"""Lines of a predicted sweep that do not converge at once: Newton that stops where it stalls, and restarts solved
all at once.

    python benchmarks/prediction_restarts.py [--session SESSION.h5]

Three changes to ``analysis.prediction.harmonic_balance``, measured together on the work where they matter:
- Newton stops an item as soon as no step of its line search lowers the residual (the same unknowns would give
  the same step again); before, it went on iterating such an item until every item of the batch was in that
  state, or for all 30 iterations.
- Such a stalled item counts as converged where its residual is at most ``IN_STEP`` (1e-8 of the line's linear
  response): a placed contact's describing function is only as exact as its own balance (1e-10 of X), below
  which Newton's 1e-11 cannot be reached. Before, such lines were marched one by one with every restart (94 %
  of the Newton solves that "did not converge" in the demo's loop had ended below 1e-8).
- The restarts of a line that does not converge from the line before are solved as one batch, taking the first
  in order that converges (the answer of trying them one after another); before, one Newton solve each.

Baseline, run in this process: ``_march_step``, ``_restarts`` and ``_newton`` as they were at commit
``BASELINE_COMMIT`` (read with ``git show``), put in the module's place. The work measured: the reference
updating, identification and ``run_auto`` of ``contactid demo --quick`` (the demo's model, no laws, on a
session of the quick plan, simulated unless one is given), the demo's costliest step. Prints the CPU of both, the
ratio, and the loop's steps and final error for both.
"""
from __future__ import annotations

import argparse
import os
import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import analysis.prediction.harmonic_balance as hb  # noqa: E402
from analysis.common.tables import load_toml  # noqa: E402
from analysis.loop.auto import run_auto  # noqa: E402
from analysis.loop.workbench import Workbench  # noqa: E402
from analysis.mechanics.model import load_model  # noqa: E402
from app.campaign.instruments import emulated_instruments  # noqa: E402
from app.campaign.measure import run_plan  # noqa: E402
from app.campaign.plan import load_plan  # noqa: E402
from app.models import asset  # noqa: E402
from app.session.data import measurements_from_session  # noqa: E402
from app.session.writer import open_session  # noqa: E402
from drivers.simulation.rig import load_rig  # noqa: E402

BASELINE_COMMIT = "711bbaa"
BASELINE_FUNCTIONS = ("_newton", "_march_step", "_restarts")


def baseline_functions() -> dict:
    """The functions of ``BASELINE_FUNCTIONS`` as they were at ``BASELINE_COMMIT``, bound to the module's names."""
    where = f"{BASELINE_COMMIT}:analysis/prediction/harmonic_balance.py"
    source = subprocess.run(["git", "-C", str(ROOT), "show", where], check=True, capture_output=True, text=True).stdout
    namespace = dict(hb.__dict__)
    for name in BASELINE_FUNCTIONS:
        match = re.search(rf"^def {name}\(.*?(?=^\S)", source, re.S | re.M)
        if match is None:
            raise SystemExit(f"{BASELINE_COMMIT}: no function {name} in harmonic_balance.py")
        exec(compile(match.group(0), f"{BASELINE_COMMIT}:{name}", "exec"), namespace)
    functions = {name: namespace[name] for name in BASELINE_FUNCTIONS}
    newton = functions["_newton"]
    functions["_newton"] = lambda fun, jac, z0, tol=1e-11, max_iter=30, stalled_tol=0.0: newton(fun, jac, z0, tol,
                                                                                                 max_iter)
    return functions


def loop(measurements):
    path = asset("paper-beam.model.toml")
    wb = Workbench(load_model(load_toml(path), str(path)), measurements)
    cpu = time.process_time()
    wb.update_reference()
    wb.start()
    result = run_auto(wb)
    return time.process_time() - cpu, [step.line() for step in result.steps], wb.history[-1].error


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--session", help="a session of the demo's quick plan (default: simulate one)")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        session = Path(args.session) if args.session else Path(tmp) / "paper-beam.h5"
        if not args.session:
            with emulated_instruments(load_rig("paper-beam"), seed=0) as inst:
                run_plan(load_plan(asset("paper-beam.quick.plan.toml")), inst, session)
        with open_session(session) as s:
            measurements = measurements_from_session(s)
    module = {name: getattr(hb, name) for name in BASELINE_FUNCTIONS}
    try:
        for name, fn in baseline_functions().items():
            setattr(hb, name, fn)
        base_cpu, base_steps, base_error = loop(measurements)
    finally:
        for name, fn in module.items():
            setattr(hb, name, fn)
    cpu, steps, error = loop(measurements)
    for name, lines, final in ((f"baseline ({BASELINE_COMMIT})", base_steps, base_error), ("now", steps, error)):
        print(f"{name}: final error {final:.6g}")
        for line in lines:
            print(f"  {line}")
    print(f"CPU: baseline {base_cpu:.1f} s, now {cpu:.1f} s (x{base_cpu / cpu:.2f})")
    return 0


if __name__ == "__main__":
    # the analysis on one core: its CPU seconds are this process's (analysis.common.parallel)
    os.environ.setdefault("CONTACTID_WORKERS", "1")
    sys.exit(main())
