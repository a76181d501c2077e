"""How often a session read in three threads at once is read wrong, as the lab window reads the one it opens.

The window keeps the session open and reads its runs in its own thread (the runs table, the selected run's
plot); the backbones' and the analysis's workers each open it and read every run in theirs. For ``--seconds``
two threads open and read the session over and over while this one reads it through a session held open. Every
run's frequencies and FRFs are compared with the file as plain h5py reads it in one thread beforehand; a read
is wrong when any line differs.

Usage: ``python benchmarks/session_read_threads.py SESSION [--seconds S]`` (a session with a run of more than 64
lines, e.g. ``contactid demo --quick``'s ``contactid-demo/paper-beam.h5``).
"""
from __future__ import annotations

import argparse
import sys
import threading
import time

import h5py
import numpy as np

from app.session.writer import open_session


def truth(path) -> dict[str, dict[str, np.ndarray]]:
    """Every run's frequencies and FRFs, read once by plain h5py in this thread alone."""
    with h5py.File(path, "r") as f:
        return {name: {"frequency": g["frequency"][()], **{f"frf/{d}": ds[()] for d, ds in g["frf"].items()}}
                for name, g in f["runs"].items()}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("session")
    parser.add_argument("--seconds", type=float, default=20.0)
    args = parser.parse_args(argv)
    expected = truth(args.session)
    stop = time.monotonic() + args.seconds
    counts = {"reads": 0, "wrong": 0}
    lock = threading.Lock()

    def read_all(session) -> None:
        for name in session.run_names():
            run = session.run(name)
            got = {"frequency": run.frequency, **{f"frf/{d}": v for d, v in run.frf.items()}}
            wrong = any(not np.array_equal(got[k], v) for k, v in expected[name].items())
            with lock:
                counts["reads"] += 1
                counts["wrong"] += wrong

    def worker() -> None:
        while time.monotonic() < stop:
            with open_session(args.session) as s:
                read_all(s)
    threads = [threading.Thread(target=worker) for _ in range(2)]
    for t in threads:
        t.start()
    with open_session(args.session) as held:
        while time.monotonic() < stop:
            read_all(held)
            time.sleep(0.01)
    for t in threads:
        t.join()
    print(f"{counts['wrong']} of {counts['reads']} run reads wrong in {args.seconds:g} s")
    return 1 if counts["wrong"] else 0


if __name__ == "__main__":
    sys.exit(main())
