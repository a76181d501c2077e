"""The march of a hysteretic law over periodic motions, as the multi-harmonic balance asks for it, against the march
as it was.

    python benchmarks/periodic_march.py

``Law.march_periodic`` marches each period twice from rest and keeps the second (a hysteretic law settles on its
closed loop in the first). Now the first period visits only the samples where the motion turns (and its ends):
a rate-independent hysteretic law's update is exact along any monotone path between two calls, so its state after
them is the one the march through every sample leaves. And a law measured from the reference (``Law.relative``)
calls its law's kernel inlined: called from the wrapper, which the march calls in turn, it stayed a call. The
baseline, run in this process, is the march as it was: both periods through every sample, the relative law's
kernel wrapped as it was. Each case prints the CPU of one march of 400 motions of 512 samples (the comparison's
setting; median of five), the ratio, and whether the forces are the same to the bit.

The motions: a fundamental with up to eight harmonics and a mean, drawn at random (seed 5), about the law's slip
displacement.
"""
from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
from numba import njit

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from analysis.laws import LAWS  # noqa: E402
from analysis.laws.base import _periodic_marcher  # noqa: E402
from multiharmonic_batch import cpu  # noqa: E402  (median CPU of five calls)

CASES = [("jenkins", {"kt": 500.0, "fs": 0.2}), ("iwan", {"kt": 800.0, "fs": 0.3, "chi": -0.5, "beta": 0.1}),
         ("iwan", {"kt": 4.3e4, "fs": 2.0, "chi": 0.37, "beta": 0.0})]
ROWS, SAMPLES = 400, 512


def wrapped_as_it_was(kernel, at: int):
    """The relative law's kernel as it was: its law's cached kernel called from the wrapper, not inlined."""
    @njit
    def relative(x, v, p, s):
        return kernel(x, v, p, s) - p[at] * x
    return relative


def motions(slip: float) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(5)
    theta = 2 * np.pi * np.arange(SAMPLES) / SAMPLES
    x = np.empty((ROWS, SAMPLES))
    for b in range(ROWS):
        order = int(rng.integers(1, 9))
        size = slip * rng.uniform(0.1, 5.0) * rng.normal(size=order + 1) / np.arange(1, order + 2)
        phase = rng.uniform(0, 2 * np.pi, order + 1)
        x[b] = 0.2 * size[0] + sum(size[k] * np.sin(k * theta + phase[k]) for k in range(1, order + 1))
    return x, np.gradient(x, axis=1)


def main() -> None:
    print(f"{'law':48s} {'before s':>9s} {'now s':>8s} {'ratio':>6s} {'same bits':>10s}")
    for name, values in CASES:
        for relative in (False, True):
            law = LAWS[name].relative() if relative else LAWS[name]
            p = law.parameter_vector(**values)
            x, v = motions(values["fs"] / values["kt"])
            before_kernel = wrapped_as_it_was(LAWS[name].kernel, len(p) - 1) if relative else law.kernel
            s0 = law.initial_state(p)

            def before():
                f = np.empty(x.shape)
                _periodic_marcher(before_kernel)(x, v, p, s0, np.empty_like(s0), 2, False, f)
                return f

            before(), law.march_periodic(x[:2], v[:2], p)      # compiled first
            before_s, f_before = cpu(before)
            now_s, f_now = cpu(lambda: law.march_periodic(x, v, p))
            shown = ", ".join(f"{value:g}" for value in values.values())
            label = f"{name}{' from the reference' if relative else ''} ({shown})"
            print(f"{label:48s} {before_s:9.4f} {now_s:8.4f} {before_s / now_s:6.2f} "
                  f"{str(np.array_equal(f_before, f_now, equal_nan=True)):>10s}", flush=True)


if __name__ == "__main__":
    main()
