"""Speed of the automatic missing-effect loop (``contactid analyze --auto``) on the paper-beam quick session.

    python benchmarks/auto_loop.py [--session PAPER_BEAM_QUICK.h5]

The demo's model (no laws) on a session of the demo's quick plan (simulated first when no session is given):
start (reference updating, identification, fit), then ``run_auto`` to its end. Target: the whole loop < 60 s.
Baseline in the same process: one candidate ranking of the final model (``Workbench.candidates``), so the ratio
says how many rankings' worth the loop costs; wall and CPU time are both printed (a loaded machine stretches
the wall time, not the CPU time).
"""
from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from analysis.auto import run_auto  # noqa: E402
from analysis.model import load_model  # noqa: E402
from analysis.tables import load_toml  # noqa: E402
from analysis.workbench import Workbench  # noqa: E402
from app.instruments import emulated_instruments  # noqa: E402
from app.measure import run_plan  # noqa: E402
from app.models import asset  # noqa: E402
from app.plan import load_plan  # noqa: E402
from app.session import open_session  # noqa: E402
from app.session_data import measurements_from_session  # noqa: E402
from drivers.simulation.rig import load_rig  # noqa: E402


def quick_session(folder: Path) -> Path:
    path = folder / "paper-beam-quick.h5"
    with emulated_instruments(load_rig("paper-beam")) as inst:
        run_plan(load_plan(asset("paper-beam.quick.plan.toml")), inst, path)
    return path


def timed(fn):
    wall, cpu = time.perf_counter(), time.process_time()
    out = fn()
    return out, time.perf_counter() - wall, time.process_time() - cpu


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--session", help="a paper-beam session of the quick plan (default: simulate one)")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        session = Path(args.session) if args.session else quick_session(Path(tmp))
        with open_session(session) as s:
            measurements = measurements_from_session(s)
    path = asset("paper-beam.model.toml")
    wb = Workbench(load_model(load_toml(path), str(path)), measurements)
    _, start_wall, start_cpu = timed(wb.start)
    result, loop_wall, loop_cpu = timed(lambda: run_auto(wb))
    _, rank_wall, rank_cpu = timed(wb.candidates)
    for step in result.steps:
        print(f"  {step.line()}")
    print(f"  stopped: {result.stopped}")
    lines = sum(len(r.frequency_hz) for r in measurements.sine)
    print(f"session: {lines} lines in {len(measurements.sine)} runs")
    print(f"start (reference, identification, fit): {start_wall:.1f} s wall, {start_cpu:.1f} s CPU")
    print(f"auto loop: {loop_wall:.1f} s wall, {loop_cpu:.1f} s CPU; start + loop {start_wall + loop_wall:.1f} s "
          f"(target < 60 s)")
    print(f"baseline, one ranking of the final model: {rank_wall:.1f} s wall, {rank_cpu:.1f} s CPU; "
          f"loop / ranking = {loop_cpu / rank_cpu:.1f} x (CPU)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
