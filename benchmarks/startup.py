"""Start-up time of the command line: ``contactid --help`` and ``contactid laws`` in fresh interpreters.

Each command runs ``--runs`` times in a new process (as a user starts it: ``python -m app.cli ...``, without the
console script's own lookup); the median wall time is printed, and its ratio against ``python -c pass`` timed the
same way in the same run (the interpreter's own start-up on this machine under its current load). The target is
under 0.5 s for both commands (docs/performance.md, "Start-up").

Run: ``python benchmarks/startup.py [--runs 7]``
"""
from __future__ import annotations

import argparse
import statistics
import subprocess
import sys
import time

COMMANDS = {"python -c pass (baseline)": ["-c", "pass"],
            "contactid --help": ["-m", "app.cli", "--help"],
            "contactid laws": ["-m", "app.cli", "laws"],
            "contactid modes paper-beam": ["-m", "app.cli", "modes", "paper-beam"]}


def wall_time(args: list[str]) -> float:
    start = time.perf_counter()
    subprocess.run([sys.executable, *args], check=True, stdout=subprocess.DEVNULL)
    return time.perf_counter() - start


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=7)
    runs = parser.parse_args().runs
    times: dict[str, list[float]] = {name: [] for name in COMMANDS}
    for _ in range(runs):                    # interleaved, so that a change of load touches every command alike
        for name, args in COMMANDS.items():
            times[name].append(wall_time(args))
    baseline = statistics.median(times["python -c pass (baseline)"])
    for name, samples in times.items():
        median = statistics.median(samples)
        print(f"{name:30s} median {median:6.3f} s  (min {min(samples):.3f})  x{median / baseline:5.1f} the baseline")


if __name__ == "__main__":
    main()
