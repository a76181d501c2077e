"""How often a fixed-count acquisition over a fast TCP emulator fails: the rate the suite's three-acquisition
check (tests/test_campaign_integrity.py) can only bound.

    python benchmarks/fixed_count_settling.py [--runs N]

paper-2dof served by `emulate --fast` over TCP from a thread of this process; N acquisitions in a row of
`[settle] fixed_periods = 10`, five lines at 0.8 N, each checked as the suite checks it (tests/served_rig.py):
complete, every line within 1 % of its force, the force never above its target. Printed: each failure, the
count of failures with its 95 % upper bound, and the wall time per acquisition.
"""
from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "tests"))

from served_rig import fixed_count_acquisition, served_paper_2dof  # noqa: E402


def upper_bound_95(failures: int, runs: int) -> float:
    """One-sided 95 % upper bound of a failure probability from ``failures`` in ``runs`` (Clopper-Pearson)."""
    from scipy.stats import beta
    return 1.0 if failures >= runs else float(beta.ppf(0.95, failures + 1, runs - failures))


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=24)
    args = parser.parse_args(argv)
    failures = 0
    start = time.monotonic()
    with tempfile.TemporaryDirectory() as folder, served_paper_2dof() as urls:
        for attempt in range(args.runs):
            problems = fixed_count_acquisition(urls, Path(folder) / f"f{attempt}.h5")
            if problems:
                failures += 1
                print(f"acquisition {attempt}: {'; '.join(problems)}", flush=True)
    wall = time.monotonic() - start
    print(f"{failures} of {args.runs} acquisitions failed (95 % upper bound of the rate "
          f"{upper_bound_95(failures, args.runs):.3f}); {wall / args.runs:.1f} s of wall time each")
    return 1 if failures else 0


if __name__ == "__main__":
    sys.exit(main())
