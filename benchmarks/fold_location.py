"""The automatic loop on a rig whose predictions jump: folds located for the report only.

    python benchmarks/fold_location.py [--session SESSION.h5]

A jump's fold (``Jump.fold_hz``) is found by continuation from the swept solution at the line before the jump,
many balances per jump. Only a report reads it (the text, the JSON, the plots, the GUI); the errors that judge a
model do not. Now the loop's comparisons go without it, a report locates it once per comparison
(``Workbench.compare(folds=True)``), and the continuation ends at the first fold. Baseline, run in this process:
every comparison, the held-out checks' predictions included, locates every jump's fold by a continuation carried
to its end, as before 2026-12-08.

The work measured: ``run_auto`` from a model with a hardening cubic at x1 and nothing at x2, on a 2-DOF rig with
that cubic and Coulomb friction at x2 swept up at 0.5, 1 and 3 N (tests/test_jump_error.py's rig, simulated unless
a session is given): the cubic's jump is predicted at every level it reaches its fold. Prints the CPU of both, the
ratio, each run's steps and final error (they must be the same) and the folds the report gives (the same too).
"""
from __future__ import annotations

import argparse
import sys
import tempfile
import time
import tomllib
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "tests"))

import analysis.prediction.comparison as comparison  # noqa: E402
from analysis.loop.auto import run_auto  # noqa: E402
from analysis.loop.workbench import Workbench  # noqa: E402
from analysis.mechanics.model import load_model  # noqa: E402
from app.campaign.instruments import emulated_instruments  # noqa: E402
from app.campaign.measure import run_plan  # noqa: E402
from app.campaign.plan import parse_plan  # noqa: E402
from app.session.data import measurements_from_session  # noqa: E402
from app.session.writer import open_session  # noqa: E402
from drivers.simulation.rig import parse_rig  # noqa: E402
from test_hidden_effects import LUMPED, LUMPED_IO, element  # noqa: E402
from test_jump_error import PLAN, RIG_ELEMENTS  # noqa: E402

MODEL = LUMPED + element("a", "x1", '"cubic"') + element("b", "x2", "")


def session(path: Path) -> Path:
    """The jump rig's three levels, simulated into ``path``."""
    rig = parse_rig('name = "jump"\n' + LUMPED + RIG_ELEMENTS + LUMPED_IO, "jump.toml")
    with emulated_instruments(rig) as inst:
        if run_plan(parse_plan(tomllib.loads(PLAN), PLAN), inst, path).aborted:
            raise SystemExit("the jump rig's campaign was aborted")
    return path


class _Baseline:
    """Every comparison locates its folds, and each continuation runs to the end of its span (before 2026-12-08)."""

    def __enter__(self):
        self.compare, self.continuation = comparison.Predictor.compare, comparison.continue_response
        compare, continuation = self.compare, self.continuation
        comparison.Predictor.compare = lambda predictor, kbar_fns=None, locate_folds=False, harmonics=None: compare(
            predictor, kbar_fns, True, harmonics)
        comparison.continue_response = lambda *args, until_fold=False, **kw: continuation(*args, **kw)
        return self

    def __exit__(self, *exc):
        comparison.Predictor.compare, comparison.continue_response = self.compare, self.continuation


def loop(measurements) -> tuple[float, list[str], float, list[float | None]]:
    """CPU of ``run_auto`` from the cubic-only model, its steps, its final error and the report's folds (Hz)."""
    wb = Workbench(load_model(tomllib.loads(MODEL)), measurements)
    cpu = time.process_time()
    wb.start()
    result = run_auto(wb)
    cpu = time.process_time() - cpu
    folds = [j.fold_hz for j in wb.compare(folds=True).jumps]
    return cpu, [step.line() for step in result.steps], wb.history[-1].error, folds


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--session", type=Path, help="a session of the jump rig (default: simulate one)")
    args = ap.parse_args(argv)
    with tempfile.TemporaryDirectory() as tmp:
        path = args.session or session(Path(tmp) / "jump.h5")
        with open_session(path) as s:
            measurements = measurements_from_session(s)
    loop(measurements)                                    # compiles what both runs use
    with _Baseline():
        before = loop(measurements)
    after = loop(measurements)
    for name, (cpu, steps, error, folds) in (("every comparison locates its folds", before),
                                             ("folds for the report only", after)):
        print(f"{name}: CPU {cpu:.2f} s, final error {error:.6g}, folds {folds}")
        for line in steps:
            print(f"  {line}")
    same = before[1:] == after[1:]
    print(f"ratio x{before[0] / after[0]:.2f}; steps, error and folds the same: {same}")
    return 0 if same else 1


if __name__ == "__main__":
    sys.exit(main())
