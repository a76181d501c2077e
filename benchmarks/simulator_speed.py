"""Rig simulator speed: simulated seconds per wall-clock second on the built-in rigs.

For each built-in rig: the first-call cost (rig load, law callbacks, compile or cache
load of the integration kernels, first block) measured in a fresh interpreter, then
the steady speed of ``RigSimulator.advance`` under a sine drive near the first mode,
and the ratio to a plain vectorised-numpy RK4 of the same (reduced) rig at the same
internal step, whose element forces come from the same law kernels. Prints one line
per rig; the figures go to docs/performance.md ("## Rig simulator").

Usage: python benchmarks/simulator_speed.py [--seconds S]
"""
from __future__ import annotations

import argparse
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from drivers.simulation.rig import load_rig  # noqa: E402
from drivers.simulation.simulator import RigSimulator  # noqa: E402

DRIVE = {"paper-2dof": (1.27, 0.8), "paper-beam": (53.0, 1.0)}

FIRST_CALL = """
import time
t0 = time.perf_counter()
from drivers.simulation.simulator import RigSimulator
sim = RigSimulator({name!r})
sim.set_sine({f}, {a})
sim.set_output(True)
sim.advance(int(sim.sample_rate))
print(time.perf_counter() - t0)
"""


def first_call_seconds(name: str) -> float:
    """Import, load, compile-or-cache-load and one simulated second, in a fresh interpreter."""
    f, a = DRIVE[name]
    out = subprocess.run([sys.executable, "-c", FIRST_CALL.format(name=name, f=f, a=a)], cwd=ROOT,
                         capture_output=True, text=True, check=True)
    return float(out.stdout.strip().splitlines()[-1])


def simulator_speed(name: str, seconds: float) -> float:
    """Simulated seconds per wall-clock second, after a warm-up."""
    f, a = DRIVE[name]
    sim = RigSimulator(name)
    sim.set_sine(f, a)
    sim.set_output(True)
    block = int(sim.sample_rate)  # one second per call, as a campaign reads a settled line
    sim.advance(block * 2)
    start = time.perf_counter()
    for _ in range(int(seconds)):
        sim.advance(block)
    return seconds / (time.perf_counter() - start)


def rk4_speed(name: str, seconds: float) -> float:
    """A plain RK4 of the same reduced rig in numpy, law forces from the law kernels (with states)."""
    f, a = DRIVE[name]
    rig = load_rig(name)
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
    start = time.perf_counter()
    t = 0.0
    for _ in range(n):
        k1 = rate(z, t)
        k2 = rate(z + 0.5 * h * k1, t + 0.5 * h)
        k3 = rate(z + 0.5 * h * k2, t + 0.5 * h)
        k4 = rate(z + h * k3, t + h)
        z = z + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
        element_force(z, True)
        t += h
    return n * h / (time.perf_counter() - start)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=60.0, help="simulated seconds per timing")
    args = parser.parse_args()
    print(f"{'rig':12s} {'first call s':>12s} {'x real time':>12s} {'RK4 x real time':>16s} {'ratio':>8s}")
    for name in ("paper-2dof", "paper-beam"):
        first = first_call_seconds(name)
        fast = simulator_speed(name, args.seconds)
        baseline = rk4_speed(name, min(args.seconds, 2.0))
        print(f"{name:12s} {first:12.2f} {fast:12.0f} {baseline:16.2f} {fast / baseline:8.0f}")


if __name__ == "__main__":
    main()
