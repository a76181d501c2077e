"""The acceptance run: the product's whole conclusion on each acceptance case (docs/architecture.md, "tests/").

    python benchmarks/acceptance.py [pytest options...]

Runs ``python -m pytest -m acceptance`` (one worker per core, as README's test command) and prints one line per
case -- passed or failed, its seconds -- then the count and the wall time. An acceptance case runs model discovery
or the missing-effect loop end to end on one simulated, integrated or measured case and checks what the product
concludes there: the laws found, their values against the truth, the error's fall. README's test command leaves
these cases out (``-m 'not acceptance'`` in pyproject.toml): the suite checks every rule and component on its own,
and this run checks the whole path on the cases (docs/performance.md, "The test suite", has both times). Run it before a change
to analysis/ lands, and record its line in docs/performance.md. Exit status: pytest's (0 when every case passed).
"""
from __future__ import annotations

import subprocess
import sys
import tempfile
import time
import xml.etree.ElementTree as ET
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
_OUTCOMES = (("failure", "FAILED"), ("error", "ERROR"), ("skipped", "skipped"))     # JUnit element -> outcome


def cases(junit: Path) -> list[tuple[str, str, float]]:
    """(test id, outcome, seconds) of every case in a JUnit XML report, in the order run."""
    out = []
    for case in ET.parse(junit).getroot().iter("testcase"):
        outcome = next((name for tag, name in _OUTCOMES if case.find(tag) is not None), "passed")
        module = case.get("classname", "").replace(".", "/") + ".py"
        out.append((f"{module}::{case.get('name')}", outcome, float(case.get("time", 0.0))))
    return out


def main() -> None:
    if any(arg in ("-h", "--help") for arg in sys.argv[1:]):
        print(__doc__)
        return
    with tempfile.TemporaryDirectory() as tmp:
        junit = Path(tmp) / "acceptance.xml"
        command = [sys.executable, "-m", "pytest", "-q", "-m", "acceptance", "-p", "no:cacheprovider",
                   f"--junitxml={junit}", *sys.argv[1:]]
        start = time.perf_counter()
        done = subprocess.run(command, cwd=ROOT, capture_output=True, text=True)
        wall = time.perf_counter() - start
        found = cases(junit) if junit.exists() else []
    for test, outcome, seconds in sorted(found, key=lambda c: -c[2]):
        print(f"{outcome:7s} {seconds:7.1f} s  {test}", flush=True)
    passed = sum(outcome == "passed" for _, outcome, _ in found)
    print(f"acceptance: {passed} of {len(found)} passed, {sum(c[2] for c in found):.0f} s of test time, "
          f"{wall:.0f} s of wall time")
    if done.returncode != 0 or not found:
        print(done.stdout[-4000:])
    sys.exit(done.returncode or (0 if found else 1))     # no case run is no acceptance


if __name__ == "__main__":
    main()
