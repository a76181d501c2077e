"""The automatic loop on a rig whose predictions jump: folds located for the report only.

    python benchmarks/fold_location.py [--session SESSION.h5]

A jump's fold (``Jump.fold_hz``) is found by continuation from the swept solution at the line before the jump,
many balances per jump. Only a report reads it (the text, the JSON, the GUI, ``contactid predict``); the errors
that judge a model do not. Now the loop's comparisons go without it, a report locates it once per comparison
(``Workbench.compare(folds=True)``, ``predict_session``), a fit's own comparison is kept where it has a jump, and
the continuation ends at the first fold. Baseline, run in this process: the code before 2026-12-08 where it
located folds (:class:`_Baseline`).

The work measured: ``run_auto`` from a model with a hardening cubic at x1 and nothing at x2, on a 2-DOF rig with
that cubic and Coulomb friction at x2 swept up at 0.5, 1 and 3 N (tests/test_jump_error.py's rig, simulated unless
a session is given): the cubic's jump is predicted at every level it reaches its fold. Prints the CPU of both, the
ratio, each run's steps and final error (they must be the same) and the folds the report gives (the same too).
"""
from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
import tomllib
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "tests"))

import analysis.loop.cross_check as cross_check  # noqa: E402
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
    """The code before 2026-12-08, where it located folds: every comparison of the workbench and every
    prediction of a held-out check located every jump's fold, a fit's own comparison was dropped where it had a
    jump (to be made again with its folds), and each continuation ran to the end of its span. The comparisons of
    the ranking and of discovery located none, then as now."""

    def __enter__(self):
        self.saved = (Workbench.compare, Workbench.fit, cross_check.predict_session, comparison.continue_response)
        compare, fit, predict_session, continuation = self.saved

        def fit_then_drop_a_comparison_with_jumps(wb, names=None):
            fit(wb, names)
            if wb._comparison is not None and wb._comparison.jumps:
                wb._comparison = None

        Workbench.compare = lambda wb, folds=False: compare(wb, folds=True)
        Workbench.fit = fit_then_drop_a_comparison_with_jumps
        cross_check.predict_session = lambda *args, folds=True, **kw: predict_session(*args, folds=True, **kw)
        comparison.continue_response = lambda *args, until_fold=False, **kw: continuation(*args, **kw)
        return self

    def __exit__(self, *exc):
        Workbench.compare, Workbench.fit, cross_check.predict_session, comparison.continue_response = self.saved


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
    os.environ.setdefault("CONTACTID_WORKERS", "1")      # one process: its CPU is all the work
    with tempfile.TemporaryDirectory() as tmp:
        path = args.session or session(Path(tmp) / "jump.h5")
        with open_session(path) as s:
            measurements = measurements_from_session(s)
    loop(measurements)                                    # compiles what both runs use
    with _Baseline():
        before = loop(measurements)
    after = loop(measurements)
    for name, (cpu, steps, error, folds) in (("the code before: the workbench's comparisons locate folds", before),
                                             ("folds for the report only", after)):
        print(f"{name}: CPU {cpu:.2f} s, final error {error:.6g}, folds {folds}")
        for line in steps:
            print(f"  {line}")
    same = before[1:] == after[1:]
    print(f"ratio x{before[0] / after[0]:.2f}; steps, error and folds the same: {same}")
    return 0 if same else 1


if __name__ == "__main__":
    sys.exit(main())
