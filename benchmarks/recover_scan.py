"""``contactid recover``'s checksum scan of a session with many runs.

    python benchmarks/recover_scan.py [--runs 2000]

A session simulated on paper-2dof (two stepped-sine runs of five lines), its first run copied ``--runs`` times
(the shape of the fuzz corpus's "thousands of runs" session), then ``app.session.writer.damaged_data`` on it:
- now: the file walked without an h5py object per group, each dataset read once in its file's own type, a chunk
  at a time only where that read fails;
- baseline, in this process: the scan before it (below), every group and dataset made an h5py object, every
  chunk read through h5py's high-level indexing.
Prints the CPU of both and the ratio; both must find nothing damaged.
"""
from __future__ import annotations

import argparse
import sys
import tempfile
import time
import tomllib
from pathlib import Path

import h5py

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from app.campaign.instruments import emulated_instruments  # noqa: E402
from app.campaign.measure import run_plan  # noqa: E402
from app.campaign.plan import parse_plan  # noqa: E402
from app.session.writer import _open_for_reading, damaged_data  # noqa: E402
from drivers.simulation.rig import load_rig  # noqa: E402

PLAN = "".join(f"[[stepped_sine]]\nforce = {F}\nstart = 1.0\nstop = 1.2\nstep = 0.05\ndirection = \"up\"\n"
               for F in (0.8, 0.4)) + "[limits]\nmax_force = 5.0\nmax_acceleration = 50.0\n"


def session(path: Path, runs: int) -> Path:
    with emulated_instruments(load_rig("paper-2dof"), seed=0) as inst:
        assert run_plan(parse_plan(tomllib.loads(PLAN), PLAN), inst, path).complete
    with h5py.File(path, "r+") as f:
        first = "runs/sine_0.8N_up"
        del f[first]["raw"]
        for i in range(runs):
            f.copy(f[first], f"runs/sine_{1 + i}N_up")
    return path


def damaged_before(path) -> list[str]:
    """The scan as it was: h5py objects for every group and dataset, every chunk read through indexing."""
    found = []
    with _open_for_reading(Path(path)) as f:
        datasets: list[h5py.Dataset] = []
        f.visititems(lambda _, obj: datasets.append(obj) if isinstance(obj, h5py.Dataset) else None)
        for ds in datasets:
            if ds.shape is None:
                continue
            if not ds.shape:
                try:
                    ds[()]
                except OSError:
                    found.append(f"{ds.name}: its value")
                continue
            n = ds.shape[0]
            step = ds.chunks[0] if ds.chunks else max(n, 1)
            for start in range(0, n, step):
                try:
                    ds[start:min(start + step, n)]
                except OSError:
                    found.append(f"{ds.name}: {start}")
    return found


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=2000)
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        path = session(Path(tmp) / "s.h5", args.runs)
        damaged_data(path)                      # warm: the file in the page cache for both
        timings = {}
        for label, scan in (("baseline", damaged_before), ("now", damaged_data)):
            t = time.process_time()
            found = scan(path)
            timings[label] = time.process_time() - t
            print(f"{label:9s} {timings[label]:6.2f} s CPU  damaged: {found or 'none'}")
        print(f"ratio     x{timings['baseline'] / timings['now']:.2f}  ({args.runs + 2} runs)")


if __name__ == "__main__":
    main()
