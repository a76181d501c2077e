"""Campaign speed: wall time of the paper-2dof campaign through the full in-process stack, shaker time of
steady-state detection against the fixed 300-settle-cycle practice at equal FRF accuracy, and the whole
campaign's speed per CPU second against the rig's integration alone on stiff rigs with sticking friction.

    python benchmarks/campaign_speed.py                 # everything
    python benchmarks/campaign_speed.py --cpu-only      # only the per-CPU-second figures

Shaker time is the DAQ time (simulated seconds) a stepped sine spends driving; FRF accuracy is the largest
relative error of the measured receptance against the analytic one of a linear rig with a voltage-driven
shaker (tests/rigs/linear-shaker.toml: modes at 7.1 and 14.2 Hz, about 1 % damping).
"""
from __future__ import annotations

import argparse
import os
import resource
import sys
import tempfile
import time
import tomllib
from pathlib import Path

# the line fits are small least-squares problems: an idle BLAS worker spinning after each would count in the
# process's CPU time (contactid's command line sets the same)
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from app.campaign.instruments import emulated_instruments  # noqa: E402
from app.campaign.measure import run_plan  # noqa: E402
from app.campaign.plan import load_plan, parse_plan  # noqa: E402
from app.session.writer import open_session  # noqa: E402
from app.models import builtin_plan_path  # noqa: E402
from drivers.simulation.rig import load_rig  # noqa: E402
from drivers.simulation.simulator import RigSimulator  # noqa: E402

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


# One level of 148 lines, steady-state detection (simulate's default), no refinement: (rig, force N, start Hz,
# stop Hz, step Hz, the kernel's sine for the integration-alone figure (Hz, N)).
CPU_CASES = {
    # tests/rigs/stiff-friction.toml: the simulator benchmark's stiff rig; at 0.3 N the friction holds x2 for part
    # of every cycle (DAQ 256 Hz)
    "stiff-friction 0.3 N": ("stiff-friction.toml", 0.3, 1.0, 3.5, 0.0171, (2.0, 0.3)),
    # tests/rigs/stiff-sticking.toml: the hidden-effect structure (3000 N/m), DAQ 512 Hz, cubic + Coulomb
    "stiff-sticking 0.5 N": ("stiff-sticking.toml", 0.5, 5.0, 10.88, 0.04, (6.0, 0.5)),
}
CPU_LIMITS = "[limits]\nmax_force = 20.0\nmax_acceleration = 1500.0\n"


def cpu_seconds() -> float:
    """CPU time of this process (every thread) and of its waited-for children (the session writer)."""
    own, children = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    return own.ru_utime + own.ru_stime + children.ru_utime + children.ru_stime


def kernel_speed(rig, frequency: float, force: float, seconds: float = 20.0) -> float:
    """Simulated seconds per CPU second of ``RigSimulator.advance`` alone in one-second blocks (as
    benchmarks/simulator_speed.py): the median of five timings."""
    sim = RigSimulator(rig)
    sim.set_sine(frequency, force)
    sim.set_output(True)
    sim.advance(2 * int(sim.sample_rate))
    speeds = []
    for _ in range(5):
        start = time.process_time()
        for _ in range(int(seconds / 5)):
            sim.advance(int(sim.sample_rate))
        speeds.append(int(seconds / 5) / (time.process_time() - start))
    return float(np.median(speeds))


def campaign_cpu(case, out: Path) -> tuple[float, float, int]:
    """A whole simulated campaign through the real drivers (instruments opened, session writer process started
    and closed): its shaker seconds, CPU seconds and lines."""
    rig_file, force, start, stop, step, _ = case
    text = (f"[[stepped_sine]]\nforce = {force}\nstart = {start}\nstop = {stop}\nstep = {step}\n"
            f'direction = "up"\nrefine = false\n' + CPU_LIMITS)
    plan = parse_plan(tomllib.loads(text), text)
    rig = load_rig(ROOT / "tests" / "rigs" / rig_file)
    cpu = cpu_seconds()
    with emulated_instruments(rig) as inst:
        summary = run_plan(plan, inst, out, overwrite=True)
    return summary.shaker_seconds, cpu_seconds() - cpu, summary.lines


def per_cpu_second(tmp: Path, repeats: int) -> None:
    """Shaker seconds per CPU second of the whole campaign against the kernel's on the same rig, alternated in
    this process; the best of ``repeats`` of each (a shared machine only ever adds CPU time)."""
    print(f"\nwhole simulated campaign per CPU second (process + session writer), load average "
          f"{os.getloadavg()[0]:.1f}")
    print(f"{'case':24s} {'lines':>5s} {'shaker s':>9s} {'CPU s':>6s} {'campaign x':>11s} {'kernel x':>9s} "
          f"{'share in kernel':>16s}")
    for name, case in CPU_CASES.items():
        rig = load_rig(ROOT / "tests" / "rigs" / case[0])
        kernel_speed(rig, *case[5], seconds=2.0)           # loads the compiled kernels
        runs, kernels = [], []
        for _ in range(repeats):
            runs.append(campaign_cpu(case, tmp / "cpu.h5"))
            kernels.append(kernel_speed(rig, *case[5]))
        shaker, cpu, lines = min(runs, key=lambda r: r[1] / r[0])
        kernel = max(kernels)
        print(f"{name:24s} {lines:5d} {shaker:9.0f} {cpu:6.2f} {shaker / cpu:10.0f}x {kernel:8.0f}x "
              f"{shaker / kernel / cpu:15.0%}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cpu-only", action="store_true", help="only the per-CPU-second figures")
    parser.add_argument("--repeats", type=int, default=3, help="campaigns per CPU case (the best is printed)")
    args = parser.parse_args()
    tmp = Path(tempfile.mkdtemp())
    if args.cpu_only:
        per_cpu_second(tmp, args.repeats)
        return
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
    per_cpu_second(tmp, args.repeats)


if __name__ == "__main__":
    main()
