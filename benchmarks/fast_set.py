"""The fast test set's wall time, and the tests that break its rule (docs/architecture.md, "tests/").

    python benchmarks/fast_set.py [--limit 1.0] [pytest options...]

Runs ``python -m pytest -q -m "not slow" --durations=0`` (one worker per core, as README's command) and prints:
- the wall time of the whole run, against the target of 2 minutes on two cores (docs/performance.md);
- every test of the fast set whose call took more than ``--limit`` seconds: by the rule, each belongs in the slow
  set (``@pytest.mark.slow``) or should be made cheaper. A module fixture's setup is not counted against the first
  test that uses it: it is paid once, whichever test comes first.
A test's time moves with the machine's load (two workers on two cores here), so a test near the limit may cross it
in one run and not the next; the rule is about the ones well over it.
"""
from __future__ import annotations

import argparse
import re
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
TARGET_SECONDS = 120.0
_DURATION = re.compile(r"^\s*([\d.]+)s call\s+(\S.*)$")


def over_the_limit(report: str, limit: float) -> list[tuple[float, str]]:
    """(seconds, test id) of every call in pytest's ``--durations`` ``report`` that took more than ``limit``."""
    found = []
    for line in report.splitlines():
        m = _DURATION.match(line)
        if m and float(m.group(1)) > limit:
            found.append((float(m.group(1)), m.group(2)))
    return sorted(found, reverse=True)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--limit", type=float, default=1.0, help="seconds a fast test's call may take (default 1)")
    args, extra = ap.parse_known_args()
    command = [sys.executable, "-m", "pytest", "-q", "-m", "not slow", "--durations=0", "-p", "no:cacheprovider",
               *extra]
    start = time.perf_counter()
    done = subprocess.run(command, cwd=ROOT, capture_output=True, text=True)
    wall = time.perf_counter() - start
    summary = [line for line in done.stdout.splitlines() if " passed" in line or " failed" in line]
    print(summary[-1] if summary else done.stdout[-2000:])
    print(f"fast set: {wall:.0f} s of wall time (target {TARGET_SECONDS:.0f} s on two cores)")
    slow = over_the_limit(done.stdout, args.limit)
    print(f"{len(slow)} fast test(s) over {args.limit:g} s" + (":" if slow else ""))
    for seconds, test in slow:
        print(f"  {seconds:6.2f} s  {test}")
    sys.exit(done.returncode)


if __name__ == "__main__":
    main()
