"""The noise of FRFs that came without it: estimated from their smoothness over neighbouring lines.

An imported FRF (another system's UFF58 or CSV) carries no standard deviation, but the analysis weighs every
line by one. A receptance is a smooth function of frequency between its lines, so what a line departs from the
smooth curve through its neighbours is noise: the second divided difference over three neighbouring lines
``c0 H[i-1] + c1 H[i] + c2 H[i+1]`` (``c = (h2, -(h1 + h2), h1)`` for spacings h1, h2; it removes any straight
line) has ``E|.|^2 = sigma^2 sum c^2`` for circular complex noise of ``E|n|^2 = sigma^2``. Each line takes the
running median of ``|.|^2 / sum c^2`` over ``WINDOW`` neighbouring triples, divided by ln 2 (the median of an
exponential variable over its mean) so a few lines of real curvature -- a resonance peak -- do not count as
noise. Where the curvature dominates, the estimate is larger than the noise: the line counts less, never
more. A noise-free record is floored at ``FLOOR`` of the largest FRF value (its round-off).
"""
from __future__ import annotations

import numpy as np

WINDOW = 11
FLOOR = 1e-9
METHOD = (f"from the scatter of each FRF about a smooth curve: running median over {WINDOW} lines of the "
          "second differences between neighbouring lines")


def smoothness_noise(frequency_hz, receptance) -> np.ndarray | None:
    """Estimated ``sqrt(E|n|^2)`` per line and sensor, shape (L, P), m/N; None with fewer than 3 lines.

    Lines may come in any order (a down sweep); they are taken in order of frequency."""
    f = np.asarray(frequency_hz, float)
    H = np.asarray(receptance, complex).reshape(len(f), -1)
    if len(f) < 3:
        return None
    order = np.argsort(f, kind="stable")
    fs, Hs = f[order], H[order]
    h1, h2 = np.diff(fs)[:-1], np.diff(fs)[1:]
    c = np.stack([h2, -(h1 + h2), h1], axis=1)
    norm = np.sum(c ** 2, axis=1)[:, None]
    norm = np.where(norm > 0, norm, np.inf)
    second = c[:, :1] * Hs[:-2] + c[:, 1:2] * Hs[1:-1] + c[:, 2:] * Hs[2:]
    variance = np.abs(second) ** 2 / norm                       # (L - 2, P), one per inner line
    half = WINDOW // 2
    padded = np.pad(variance, ((half, half), (0, 0)), mode="edge")
    windows = np.lib.stride_tricks.sliding_window_view(padded, WINDOW, axis=0)
    local = np.median(windows, axis=-1) / np.log(2.0)
    local = np.concatenate([local[:1], local, local[-1:]])       # the end lines take their neighbour's
    std = np.empty_like(local)
    std[order] = np.sqrt(local)
    return np.maximum(std, FLOOR * np.abs(H).max())
