"""The phasor sequence of a transient-aware line (analysis/signals/phasor_sequence.py): its windows' harmonics
projected in one batch against window by window, and its pencil's Hankel matrix built at once against column by
column, on a Duffing line integrated here (the hardening rig's oscillator, solve_ivp); the same numbers.

    python benchmarks/phasor_sequence_speed.py

A line taken from its sequence refits the sequence at every record (three fits: all its windows and without a
quarter or a half of them), so these two costs are most of a transient-aware campaign's CPU on a nonlinear rig.
Printed: each path's time per call, the ratio, and the largest relative difference of their results.
"""
from __future__ import annotations

import os
import sys
import time
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np  # noqa: E402
import scipy.integrate  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from analysis.signals.harmonics import HarmonicProjector  # noqa: E402
from analysis.signals.phasor_sequence import _hankel, fit_sequence, window_phasors  # noqa: E402

FS, F, PERIODS = 512.0, 10.0, 120


def duffing_line() -> np.ndarray:
    """Force and acceleration of the hardening rig's oscillator (M 1, K 3947.8, C 1.5, 4e7 x^3) driven at 0.5 N,
    F Hz, from rest: PERIODS periods of its transient."""
    def rhs(t, s):
        x, v = s
        return [v, 0.5 * np.sin(2 * np.pi * F * t) - 1.5 * v - 3947.8 * x - 4e7 * x**3]
    t = np.arange(int(PERIODS * FS / F)) / FS
    y = scipy.integrate.solve_ivp(rhs, (0, t[-1]), [0.0, 0.0], t_eval=t, method="DOP853", rtol=1e-10,
                                  atol=1e-13).y
    acc = np.array([rhs(ti, si)[1] for ti, si in zip(t, y.T)])
    noise = np.random.default_rng(7).standard_normal((len(t), 2)) * [1e-4, 1e-3]
    return np.column_stack([0.5 * np.sin(2 * np.pi * F * t), acc]) + noise


def window_by_window(data, origin):
    """The baseline: each window projected on its own."""
    per_window = 2 * FS / F
    n = int(np.ceil(per_window))
    starts = np.round(np.arange(int(data.shape[0] // per_window) + 1) * per_window).astype(int)
    starts = starts[starts + n <= data.shape[0]]
    project = HarmonicProjector(F, FS, n, 5)
    h = np.arange(6)[:, None]
    P, noise = [], []
    for s in starts:
        H = project(data[s:s + n])
        P.append(H.amplitudes * np.exp(1j * 2 * np.pi * F * h * (origin - s) / FS))
        noise.append(2 * H.residual_rms / np.sqrt(n))
    return np.array(P), np.array(noise)[:, None, :]


def column_by_column(D, L):
    """The baseline: the columns' Hankel matrices stacked one by one."""
    return np.vstack([np.lib.stride_tricks.sliding_window_view(D[:, c], L + 1) for c in range(D.shape[1])])


def timed(call, repeats=40):
    start = time.process_time()
    for _ in range(repeats):
        out = call()
    return (time.process_time() - start) / repeats, out


def main() -> None:
    data = duffing_line()
    origin = data.shape[0] - 300
    t_base, (P0, n0) = timed(lambda: window_by_window(data, origin))
    t_new, (P1, n1) = timed(lambda: window_phasors(data, FS, F, 2, 5, origin))
    diff = max(np.max(np.abs(P1 - P0)) / np.max(np.abs(P0)), np.max(np.abs(n1 - n0)) / np.max(n0))
    print(f"window phasors, {len(P0)} windows: {t_base * 1e3:.2f} ms window by window, {t_new * 1e3:.2f} ms in one "
          f"batch, x{t_base / t_new:.1f}; largest relative difference {diff:.1e}")
    D = np.diff(P1[-60:].reshape(len(P1[-60:]), -1), axis=0)     # the differences the pencil takes
    L = max(min(D.shape[0] // 2, D.shape[0] - 2), 1)
    t_base, H0 = timed(lambda: column_by_column(D, L), 200)
    t_new, H1 = timed(lambda: _hankel(D, L), 200)
    print(f"pencil's Hankel matrix {H0.shape}: {t_base * 1e6:.0f} us column by column, {t_new * 1e6:.0f} us at once, "
          f"x{t_base / t_new:.1f}; identical: {np.array_equal(H0, H1)}")
    t_fit, _ = timed(lambda: fit_sequence(P1[-60:], n1[-60:]))
    print(f"fit_sequence of {len(P1[-60:])} windows: {t_fit * 1e3:.2f} ms")


if __name__ == "__main__":
    main()
