"""Campaign speed: wall time of the paper-2dof campaign through the full in-process stack, and shaker time of
steady-state detection against the fixed 300-settle-cycle practice at equal FRF accuracy.

    python benchmarks/campaign_speed.py

Shaker time is the DAQ time (simulated seconds) a stepped sine spends driving; FRF accuracy is the largest
relative error of the measured receptance against the analytic one of a linear rig with a voltage-driven
shaker (tests/rigs/linear-shaker.toml: modes at 7.1 and 14.2 Hz, about 1 % damping).
"""
from __future__ import annotations

import sys
import tempfile
import time
import tomllib
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from app.campaign.instruments import emulated_instruments  # noqa: E402
from app.campaign.measure import run_plan  # noqa: E402
from app.campaign.plan import load_plan, parse_plan  # noqa: E402
from app.session.writer import open_session  # noqa: E402
from app.models import builtin_plan_path  # noqa: E402
from drivers.simulation.rig import load_rig  # noqa: E402

SWEEP = """
[[stepped_sine]]
force = 0.5
start = 5.0
stop = 17.0
step = 0.25
direction = "up"
refine = false
[limits]
max_force = 5.0
max_acceleration = 150.0
"""


def sweep(rig, settle: str, out: Path):
    text = settle + SWEEP
    plan = parse_plan(tomllib.loads(text), text)
    t = time.perf_counter()
    with emulated_instruments(rig) as inst:
        summary = run_plan(plan, inst, out, overwrite=True)
    wall = time.perf_counter() - t
    with open_session(out) as s:
        run = s.run("sine_0.5N_up")
        f = run.arrays["measured_frequency"]
        H = rig.structure.frf(2 * np.pi * f, columns=[rig.excitation_dof])[:, :, 0]
        err = max(np.abs(run.frf[d] / H[:, p] - 1).max() for p, d in enumerate(rig.sensor_dofs))
    return summary.shaker_seconds, err, wall, len(f)


def main() -> None:
    tmp = Path(tempfile.mkdtemp())
    rig2 = load_rig("paper-2dof")
    t = time.perf_counter()
    with emulated_instruments(rig2) as inst:
        summary = run_plan(load_plan(builtin_plan_path("paper-2dof")), inst, tmp / "p.h5")
    wall = time.perf_counter() - t
    print(f"paper-2dof default plan through drivers + in-process emulator: {wall:.2f} s wall "
          f"({summary.lines} lines, {summary.shaker_seconds:.0f} s on the shaker, "
          f"{summary.shaker_seconds / wall:.0f} x real time; target < 10 s)")

    rig = load_rig(ROOT / "tests" / "rigs" / "linear-shaker.toml")
    rows = [("fixed 300 periods (practice)", "[settle]\nfixed_periods = 300\n"),
            ("steady-state detection, tolerance 2e-3 (default)", ""),
            ("steady-state detection, tolerance 1e-5", "[settle]\ntolerance = 1e-5\n")]
    results = {}
    print(f"\n{'settling':52s} {'shaker s':>9s} {'max FRF error':>14s} {'wall s':>7s} {'lines':>6s}")
    for name, settle in rows:
        results[name] = sweep(rig, settle, tmp / "s.h5")
        shaker, err, w, n = results[name]
        print(f"{name:52s} {shaker:9.1f} {err:14.2e} {w:7.2f} {n:6d}")
    fixed = results[rows[0][0]]
    for name, _ in rows[1:]:
        shaker, err, _, _ = results[name]
        print(f"ratio fixed/detection ({name}): {fixed[0] / shaker:.1f} x less shaker time, "
              f"max error {err:.1e} vs {fixed[1]:.1e}")


if __name__ == "__main__":
    main()
