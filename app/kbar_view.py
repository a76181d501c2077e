"""What the kbar plots of the report (kbar.png) and the GUI's Identify tab share: the axis an element judged linear
is drawn on, and the fitted model drawn as a path per force level (docs/workbench.md, "kbar plots")."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

FLAT_VIEW = 0.05     # an element judged linear is drawn on at least +-5 % of its mean: a flat element looks flat


@dataclass(frozen=True)
class LinearAxis:
    """The value range of one part (Re or Im) of a linear element's kbar, and how far its samples spread."""
    low: float
    high: float
    spread: float        # (max - min) / |mean| of the samples

    def words(self) -> str:
        return (f"samples within {self.spread:.2%} of their mean; axis ±{(self.high - self.low) / 2 / self.centre:.0%}"
                " of it")

    @property
    def centre(self) -> float:
        return abs(self.high + self.low) / 2 or 1.0


def linear_axis(values) -> LinearAxis | None:
    """The axis of an element judged linear: centred on the samples' mean, half-height the larger of
    FLAT_VIEW of the mean and the samples' own half-spread (with a margin), so that a 0.04 % spread is not
    stretched to the full height and reads as the flat line it is. None for a mean of zero (no scale to
    compare the spread with)."""
    v = np.asarray(values, float)
    v = v[np.isfinite(v)]
    if len(v) == 0:
        return None
    mean = float(v.mean())
    if mean == 0.0:
        return None
    half = max(FLAT_VIEW * abs(mean), 1.1 * float(np.abs(v - mean).max()))
    return LinearAxis(mean - half, mean + half, float(np.ptp(v)) / abs(mean))


JUMP = 2.0           # consecutive lines whose amplitudes differ by more than this factor are a jump, not a step


@dataclass(frozen=True)
class ModelPath:
    """The fitted model at one force level's samples, in frequency order: the path the measured points of that
    level trace (a law that depends on w as well as X is not a function of X alone, so a line sorted by X would
    zigzag between the two sides of the resonance). The path is broken (NaN; draw with ``connect="finite"``)
    where the amplitude jumps between neighbouring lines -- a fold, or another sweep's branch at the same level --
    so that no straight segment crosses the plot where nothing was measured."""
    level: float
    X: np.ndarray
    kbar: np.ndarray


def model_paths(X, w, level, model) -> list[ModelPath]:
    """One :class:`ModelPath` per force level present in ``level``."""
    X, w, level, model = (np.asarray(a) for a in (X, w, level, model))
    paths = []
    for force in np.unique(np.round(level, 12)):
        sel = np.flatnonzero(np.isclose(level, force))
        order = sel[np.argsort(w[sel], kind="stable")]
        x, k = X[order].astype(float), model[order].astype(complex)
        jumps = np.flatnonzero(np.abs(np.diff(np.log(x))) > np.log(JUMP)) + 1
        paths.append(ModelPath(float(force), np.insert(x, jumps, np.nan), np.insert(k, jumps, np.nan)))
    return paths


LEGEND_OFFSETS = {"top right": (-10, 10), "top left": (10, 10), "bottom right": (-10, -10), "bottom left": (10, -10)}


def emptiest_corner(x, y, log_x: bool = True, box: tuple[float, float] = (0.35, 0.3)) -> str:
    """The corner of the plot (a key of LEGEND_OFFSETS) whose ``box`` (fractions of the width and height of the
    data's range) holds the fewest points: where a legend hides the least data. Ties go to the top right."""
    x, y = np.asarray(x, float), np.asarray(y, float)
    if log_x:
        x = np.log10(np.where(x > 0, x, np.nan))
    ok = np.isfinite(x) & np.isfinite(y)
    x, y = x[ok], y[ok]
    if len(x) == 0:
        return "top right"
    u = (x - x.min()) / (np.ptp(x) or 1.0)
    v = (y - y.min()) / (np.ptp(y) or 1.0)
    right, top = u > 1 - box[0], v > 1 - box[1]
    left, bottom = u < box[0], v < box[1]
    counts = {"top right": np.sum(right & top), "top left": np.sum(left & top),
              "bottom right": np.sum(right & bottom), "bottom left": np.sum(left & bottom)}
    return min(counts, key=lambda k: counts[k])       # dicts keep order: the top right wins a tie


def legend_to(legend, corner: str) -> None:
    """Move a pyqtgraph legend into ``corner`` of its plot (a key of LEGEND_OFFSETS), remembering where it is."""
    offset = LEGEND_OFFSETS[corner]
    anchor = (0 if offset[0] > 0 else 1, 0 if offset[1] > 0 else 1)
    legend.anchor(itemPos=anchor, parentPos=anchor, offset=offset)
    legend.corner = corner
