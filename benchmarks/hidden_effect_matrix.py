"""The hidden-effect matrix: every case of tests/matrix_cases.py measured, diagnosed from a model without the
hidden laws, and scored; the confusion table regenerated in docs/workbench.md.

    python benchmarks/hidden_effect_matrix.py              # the whole matrix: results file and docs table
    python benchmarks/hidden_effect_matrix.py --only beam  # cases whose name contains "beam"; writes nothing
    python benchmarks/hidden_effect_matrix.py --from-results  # the docs table again from the stored outcomes
    python benchmarks/hidden_effect_matrix.py --only "rk4 2dof gap" --into-results  # a new case into them

One line per case as it finishes (fit for a terminal and a log), then the summary and the table. The whole
matrix writes the outcomes to benchmarks/hidden_effect_matrix.json (what the docs table is checked against by
tests/test_hidden_effect_matrix.py) and replaces the table between its markers in docs/workbench.md.
"""
from __future__ import annotations

import argparse
import os
import datetime
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "tests"))

import matrix_cases as mc  # noqa: E402

RESULTS = ROOT / "benchmarks" / "hidden_effect_matrix.json"
DOCS = ROOT / "docs/workbench.md"
# The loop and what its decisions rest on, as the rooms it runs through (analysis/__init__.py): the mechanics (a
# contact placed in its structure), the fit, the comparison, the model-form check, the detector. A change to any
# module of them is a change of the loop.
LOOP_FILES = ("analysis/mechanics", "analysis/fitting", "analysis/prediction", "analysis/missing", "analysis/search",
              "analysis/loop")


def loop_commit() -> str:
    """The last commit that changed the loop's code, and whether the work tree changes it further."""
    commit = subprocess.run(["git", "log", "-1", "--format=%h", "--", *LOOP_FILES], cwd=ROOT, capture_output=True,
                            text=True).stdout.strip()
    dirty = subprocess.run(["git", "status", "--porcelain", "--", *LOOP_FILES], cwd=ROOT, capture_output=True,
                           text=True).stdout.strip()
    return f"{mc.LOOP_NAME} at commit {commit}" + (" with uncommitted changes" if dirty else "")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--only", action="append", default=[], help="run the cases whose name contains this text")
    ap.add_argument("--into-results", action="store_true",
                    help="with --only: put the outcomes of the cases run into the stored ones (same loop only) and "
                         "rewrite the docs table")
    ap.add_argument("--from-results", action="store_true",
                    help="run nothing: rewrite the docs table from the stored outcomes (after a change of its format)")
    args = ap.parse_args()
    if args.from_results:
        recorded = json.loads(RESULTS.read_text(encoding="utf-8"))
        outcomes = [mc.Outcome.from_json(o) for o in recorded["outcomes"]]
        section = mc.render(outcomes, recorded["date"], recorded["loop"])
        DOCS.write_text(mc.replace_section(DOCS.read_text(encoding="utf-8"), section), encoding="utf-8")
        print(section)
        return 0
    cases = [c for c in mc.CASES if not args.only or any(s in c.name for s in args.only)]
    if not cases:
        print(f"no case matches {args.only}", file=sys.stderr)
        return 2
    loop, date = loop_commit(), datetime.date.today().isoformat()
    outcomes = []
    sessions: dict[str, Path] = {}          # a case's "from empty" variant analyses the same data
    with tempfile.TemporaryDirectory() as tmp:
        for i, c in enumerate(cases, 1):
            folder = Path(tmp) / f"case{i}"
            folder.mkdir()
            t0 = time.monotonic()
            try:
                if c.data_name not in sessions:
                    sessions[c.data_name] = mc.case_session(c, folder)
                outcomes.append(mc.run_case(c, folder, sessions[c.data_name]))
            except Exception as exc:       # a case that breaks is scored as found nothing, with the reason shown
                outcomes.append(mc.Outcome.broken(c, f"{type(exc).__name__}: {exc}".splitlines()[0]))
            print(mc.progress_line(i, len(cases), outcomes[-1], time.monotonic() - t0), flush=True)
    section = mc.render(outcomes, date, loop)
    print("\n" + section)
    if args.into_results:
        recorded = json.loads(RESULTS.read_text(encoding="utf-8"))
        if recorded["loop"] != loop:
            print(f"the stored outcomes are of {recorded['loop']}, not {loop}: run the whole matrix", file=sys.stderr)
            return 2
        new = {o.case: o for o in outcomes}
        old = {o["case"]: mc.Outcome.from_json(o) for o in recorded["outcomes"]}
        outcomes = [new.get(c.name) or old[c.name] for c in mc.CASES]
        section = mc.render(outcomes, recorded["date"], loop)
    if not args.only or args.into_results:
        RESULTS.write_text(json.dumps({"date": date, "loop": loop, "outcomes": [o.to_json() for o in outcomes]},
                                      indent=1) + "\n", encoding="utf-8")
        DOCS.write_text(mc.replace_section(DOCS.read_text(encoding="utf-8"), section), encoding="utf-8")
        print(f"\nwritten: {RESULTS.relative_to(ROOT)}, {DOCS.relative_to(ROOT)}")
    return 0


if __name__ == "__main__":
    # the analysis on one core: its CPU seconds are this process's (analysis.common.parallel)
    os.environ.setdefault("CONTACTID_WORKERS", "1")
    sys.exit(main())
