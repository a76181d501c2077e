"""Speed of the automatic loop (``contactid analyze --auto``, discovery first) from a model with no laws.

    python benchmarks/auto_loop.py [--rig paper-2dof|paper-beam] [--session SESSION.h5]

paper-beam: the demo's model (no laws) on a session of the demo's quick plan. paper-2dof: the paper's structure
with both elements at ``laws = []`` on a session of the rig's built-in plan (seed 3). Sessions are simulated
first when none is given. Start (reference updating, identification, fit), then ``run_auto`` to its end.
Targets (CPU, docs/performance.md): paper-2dof at most 30 s, paper-beam at most 60 s. Baseline in the same
process: one candidate ranking of the final model (``Workbench.candidates``), so the ratio says how many
rankings' worth the loop costs; wall and CPU time are both printed (a loaded machine stretches the wall time,
not the CPU time).
"""
from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from analysis.loop.auto import run_auto  # noqa: E402
from analysis.mechanics.model import load_model  # noqa: E402
from analysis.common.tables import load_toml  # noqa: E402
from analysis.loop.workbench import Workbench  # noqa: E402
from app.campaign.instruments import emulated_instruments  # noqa: E402
from app.campaign.measure import run_plan  # noqa: E402
from app.models import asset  # noqa: E402
from app.campaign.plan import load_plan  # noqa: E402
from app.session.writer import open_session  # noqa: E402
from app.session.data import measurements_from_session  # noqa: E402
from drivers.simulation.rig import builtin_rig_path, load_rig  # noqa: E402


@dataclass(frozen=True)
class Bench:
    rig: str
    plan: str               # a built-in plan asset
    seed: int
    target_cpu: float       # s


BENCHES = {"paper-beam": Bench("paper-beam", "paper-beam.quick.plan.toml", 0, 60.0),
           "paper-2dof": Bench("paper-2dof", "paper-2dof.plan.toml", 3, 30.0)}


def simulated(bench: Bench, folder: Path) -> Path:
    path = folder / f"{bench.rig}.h5"
    with emulated_instruments(load_rig(bench.rig), seed=bench.seed) as inst:
        run_plan(load_plan(asset(bench.plan)), inst, path)
    return path


def model_of(bench: Bench):
    """paper-beam: the demo's model; paper-2dof: the rig's own structure and elements, every law taken away."""
    if bench.rig == "paper-2dof":
        doc = load_toml(builtin_rig_path("paper-2dof"))
        for element in doc["element"]:
            element["laws"] = []
        return load_model(doc, "paper-2dof, no laws")
    path = asset("paper-beam.model.toml")
    return load_model(load_toml(path), str(path))


def timed(fn):
    wall, cpu = time.perf_counter(), time.process_time()
    out = fn()
    return out, time.perf_counter() - wall, time.process_time() - cpu


def run(bench: Bench, session: Path | None) -> None:
    with tempfile.TemporaryDirectory() as tmp:
        session = session or simulated(bench, Path(tmp))
        with open_session(session) as s:
            measurements = measurements_from_session(s)
    wb = Workbench(model_of(bench), measurements)
    _, start_wall, start_cpu = timed(wb.start)
    result, loop_wall, loop_cpu = timed(lambda: run_auto(wb))
    _, rank_wall, rank_cpu = timed(wb.candidates)
    print(f"{bench.rig}:")
    for step in result.steps:
        print(f"  {step.line()}")
    print(f"  stopped: {result.stopped}")
    lines = sum(len(r.frequency_hz) for r in measurements.sine)
    print(f"  session: {lines} lines in {len(measurements.sine)} runs")
    print(f"  start (reference, identification, fit): {start_wall:.1f} s wall, {start_cpu:.1f} s CPU")
    print(f"  auto loop: {loop_wall:.1f} s wall, {loop_cpu:.1f} s CPU; start + loop {start_cpu + loop_cpu:.1f} s CPU "
          f"(target at most {bench.target_cpu:g} s)")
    print(f"  baseline, one ranking of the final model: {rank_wall:.1f} s wall, {rank_cpu:.1f} s CPU; "
          f"loop / ranking = {loop_cpu / rank_cpu:.1f} x (CPU)")


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rig", choices=sorted(BENCHES), action="append",
                        help="the bench (default: both)")
    parser.add_argument("--session", help="a session of that bench's plan (default: simulate one)")
    args = parser.parse_args()
    rigs = args.rig or sorted(BENCHES)
    if args.session and len(rigs) != 1:
        parser.error("--session goes with one --rig")
    for rig in rigs:
        run(BENCHES[rig], Path(args.session) if args.session else None)
    return 0


if __name__ == "__main__":
    # the analysis on one core: its CPU seconds are this process's (analysis.common.parallel)
    os.environ.setdefault("CONTACTID_WORKERS", "1")
    sys.exit(main())
