"""Rig simulator speed: simulated seconds per wall-clock second on the built-in rigs and a stiff one.

For each case (a rig and a sine drive): the first-call cost (rig load, law callbacks,
compile or cache load of the integration kernels, first block) measured in a fresh
interpreter, then the steady speed of ``RigSimulator.advance`` read in one-second
blocks and in 10 ms chunks (as the instrument emulator advances while it paces or
ramps), and the ratio to a plain vectorised-numpy RK4 of the same (reduced) rig at the
same internal step, whose element forces come from the same law kernels. The speeds
are process CPU time (the machine is shared), the median of five timings; the load
average is printed. Prints one
line per case; the figures go to docs/performance.md ("## Rig simulator").

Usage: python benchmarks/simulator_speed.py [--seconds S] [--cases CASE ...]
"""
from __future__ import annotations

import argparse
import os
import subprocess
import sys
import time
from pathlib import Path

# The simulator runs in one thread; BLAS worker threads left spinning after a small matrix product would
# count in the process CPU time measured here (set before numpy loads BLAS)
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from drivers.simulation.rig import load_rig, parse_rig  # noqa: E402
from drivers.simulation.simulator import RigSimulator  # noqa: E402
from tests.test_hidden_effects import LUMPED, LUMPED_IO, SCENARIOS, element  # noqa: E402

STIFF = str(ROOT / "tests" / "rigs" / "stiff-friction.toml")
# case: (rig, sine frequency Hz, amplitude)
CASES = {
    "paper-2dof": ("paper-2dof", 1.27, 0.8),
    "paper-beam": ("paper-beam", 53.0, 1.0),
    # hardening cubic stiffened about 6 x, friction sliding most of the cycle
    "stiff 3 N": (STIFF, 2.0, 3.0),
    # the same rig at 0.3 N: friction sticks for part of every cycle
    "stiff 0.3 N": (STIFF, 2.0, 0.3),
}
# the 2-DOF rigs of the hidden-effect tests (tests/test_hidden_effects.py: DAQ 512 Hz, modes 5.9 and 9.6 Hz),
# each at the largest force of their plan near the first mode; rigs given as TOML text
HIDDEN = {name: rig_elements for name, (rig_elements, _) in SCENARIOS.items()}
HIDDEN["cubic at x1 (nothing missing)"] = element("a", "x1", '{ law = "cubic", k3 = 2.0e5 }')
for name, rig_elements in HIDDEN.items():
    CASES[f"hidden: {name}"] = ("name = \"hidden\"\n" + LUMPED + rig_elements + element("b", "x2", "") + LUMPED_IO,
                                6.0, 3.0)

REPEATS = 5  # timings per speed figure, of which the median is printed

FIRST_CALL = """
import time
t0 = time.perf_counter()
from drivers.simulation.simulator import RigSimulator
from drivers.simulation.rig import parse_rig
rig = {rig!r}
sim = RigSimulator(parse_rig(rig, "benchmark.toml") if "\\n" in rig else rig)
sim.set_sine({f}, {a})
sim.set_output(True)
sim.advance(int(sim.sample_rate))
print(time.perf_counter() - t0)
"""


def first_call_seconds(case: str) -> float:
    """Import, load, compile-or-cache-load and one simulated second, in a fresh interpreter."""
    rig, f, a = CASES[case]
    out = subprocess.run([sys.executable, "-c", FIRST_CALL.format(rig=rig, f=f, a=a)], cwd=ROOT,
                         capture_output=True, text=True, check=True)
    return float(out.stdout.strip().splitlines()[-1])


def case_rig(case: str):
    """The case's rig: a built-in name or file, or TOML text."""
    rig = CASES[case][0]
    return parse_rig(rig, "benchmark.toml") if "\n" in rig else load_rig(rig)


def simulator_speed(case: str, seconds: float, chunk_seconds: float) -> float:
    """Simulated seconds per CPU second, read in chunks of ``chunk_seconds`` after a warm-up: the median
    of REPEATS timings of ``seconds / REPEATS`` each (one timing of a few ms of CPU on a shared machine
    can be off by a factor of two)."""
    _, f, a = CASES[case]
    sim = RigSimulator(case_rig(case))
    sim.set_sine(f, a)
    sim.set_output(True)
    sim.advance(int(sim.sample_rate) * 2)
    chunk = max(1, round(chunk_seconds * sim.sample_rate))
    calls = max(1, round(seconds * sim.sample_rate / chunk / REPEATS))
    speeds = []
    for _ in range(REPEATS):
        start = time.process_time()
        for _ in range(calls):
            sim.advance(chunk)
        speeds.append(calls * chunk / sim.sample_rate / (time.process_time() - start))
    return float(np.median(speeds))


def rk4_speed(case: str, seconds: float) -> float:
    """A plain RK4 of the same reduced rig in numpy, law forces from the law kernels (with states)."""
    _, f, a = CASES[case]
    rig = case_rig(case)
    sim = RigSimulator(rig)
    model = rig.linear
    from drivers.simulation.simulator import _state_space
    A, b_u, B_g, Cy, *_ = _state_space(rig, model, True)
    r = len(rig.elements)
    terms = [(e, t.law, t.law.parameter_vector(**t.values)) for e, el in enumerate(rig.elements) for t in el.laws]
    states = [law.initial_state(p) for _, law, p in terms]
    h = sim.step
    z = np.zeros(A.shape[0])

    def element_force(zz, commit):
        y = Cy @ zz
        g = -model.k0 * y[:r] - model.c0 * y[r:]
        for k, (e, law, p) in enumerate(terms):
            s = states[k] if commit else states[k].copy()
            g[e] += law.kernel(y[e], y[r + e], p, s)
        return g

    def rate(zz, t):
        return A @ zz + b_u * (a * np.sin(2 * np.pi * f * t)) + B_g @ element_force(zz, False)

    n = int(seconds / h)
    start = time.process_time()
    t = 0.0
    for _ in range(n):
        k1 = rate(z, t)
        k2 = rate(z + 0.5 * h * k1, t + 0.5 * h)
        k3 = rate(z + 0.5 * h * k2, t + 0.5 * h)
        k4 = rate(z + h * k3, t + h)
        z = z + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
        element_force(z, True)
        t += h
    return n * h / (time.process_time() - start)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=60.0, help="simulated seconds per timing")
    parser.add_argument("--cases", nargs="+", choices=list(CASES), default=list(CASES), metavar="CASE",
                        help="cases to run (default all)")
    args = parser.parse_args()
    print(f"load average {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores")
    print(f"{'case':44s} {'first call s':>12s} {'x real time':>12s} {'10 ms chunks':>13s} {'RK4 x real time':>16s} "
          f"{'ratio':>6s} {'ratio 10 ms':>12s}")
    for case in args.cases:
        first = first_call_seconds(case)
        fast = simulator_speed(case, args.seconds, 1.0)  # one second per call, as a campaign reads a settled line
        short = simulator_speed(case, args.seconds / 4, 0.01)
        baseline = rk4_speed(case, min(args.seconds, 2.0))
        print(f"{case:44s} {first:12.2f} {fast:12.0f} {short:13.0f} {baseline:16.2f} {fast / baseline:6.0f} "
              f"{short / baseline:12.0f}")
    print(f"load average {os.getloadavg()[0]:.1f}")


if __name__ == "__main__":
    main()
