"""What the report plots (kbar.png, frf.png, ...) and the GUI's tabs share: the colour, marker and order of the
levels, the axis an element judged linear is drawn on, and the fitted model drawn as a path per level
(docs/workbench.md, "kbar plots"; docs/gui.md, "Levels")."""
from __future__ import annotations

from dataclasses import dataclass
from typing import Iterable, Sequence

import numpy as np

from analysis.common.measurements import Control

LEVEL_MAP = "turbo"
"""The ordered colour map the levels are sampled from: neighbouring levels get neighbouring hues."""
LEVEL_SPAN = (0.05, 0.95)     # turbo's ends are near black
MIN_CONTRAST = 3.0            # against the white background (WCAG 2.1, graphical objects): its greens would fade
LEVEL_SYMBOLS = {"force": "o", "response": "s", "open_loop": "d"}
"""Marker of a level's measured points by how it was held: force- and response-controlled levels apart."""


def _luminance(rgb: np.ndarray) -> float:
    c = np.asarray(rgb, float) / 255.0
    c = np.where(c > 0.04045, ((c + 0.055) / 1.055) ** 2.4, c / 12.92)
    return float(c @ [0.2126, 0.7152, 0.0722])


def level_colours(n: int) -> list[tuple[int, int, int]]:
    """The colours of ``n`` levels in :meth:`Control.order` (force levels by force, then response levels): LEVEL_MAP
    sampled evenly over LEVEL_SPAN, so the order of the levels reads as the order of the hues, each darkened until
    it stands MIN_CONTRAST:1 against white. Twelve levels stay apart (no two closer than CIE76 dE 16); many more
    shade into each other as neighbours."""
    import pyqtgraph as pg

    cmap = pg.colormap.get(LEVEL_MAP)
    positions = [LEVEL_SPAN[0]] if n == 1 else np.linspace(*LEVEL_SPAN, n)
    out = []
    for p in positions:
        rgb = np.asarray(cmap.map(float(p), mode="byte"), float)[:3]
        while 1.05 / (_luminance(rgb) + 0.05) < MIN_CONTRAST:
            rgb = rgb * 0.95
        out.append(tuple(int(v) for v in np.round(rgb)))
    return out


PANEL_LEVELS = 12
"""The most levels one plot of FRFs holds: as many as :func:`level_colours` keeps apart. More are drawn as small
multiples (:func:`level_panels`)."""
LEGEND_ROWS = 24
"""The most entries a legend stacks in one column; a longer one takes more columns, so that it fits beside plots a
1366 x 768 screen leaves about 560 px high."""


def level_panels(controls: Iterable[Control]) -> list[list[Control]]:
    """The levels of a plot of FRFs shared out among small multiples, in :meth:`Control.order`.

    Up to PANEL_LEVELS levels stay in one panel. More than that overlap into a band no colour tells apart, so each
    way of holding a level (force, a response at one DOF and quantity) gets panels of its own, and each such group
    is cut into runs of consecutive levels, as even as can be, of at most PANEL_LEVELS: a panel holds neighbours,
    its title their range (:func:`panel_title`), and every level keeps its colour of the whole session."""
    levels = ordered_levels(controls)
    if len(levels) <= PANEL_LEVELS:
        return [levels] if levels else []
    groups: dict[tuple, list[Control]] = {}
    for c in levels:
        groups.setdefault(c.key()[:3], []).append(c)
    panels = []
    for group in groups.values():
        count = -(-len(group) // PANEL_LEVELS)
        bounds = np.linspace(0, len(group), count + 1).round().astype(int)
        panels += [group[a:b] for a, b in zip(bounds[:-1], bounds[1:])]
    return panels


def panel_title(panel: Sequence[Control]) -> str:
    """The levels a panel holds, by how they were held: ``0.2 N`` or ``5 ... 40 m/s^2 at x1``."""
    if len(panel) == 1:
        return panel[0].label()
    first, last = panel[0].label(), panel[-1].label()
    unit = last.split(" ", 1)[1]                    # a panel's levels share how they were held
    return f"{first.split(' ', 1)[0]} ... {last}" if first.split(" ", 1)[1] == unit else f"{first} ... {last}"


def level_symbol(control: Control) -> str:
    return LEVEL_SYMBOLS.get(control.mode, "o")


def ordered_levels(controls: Iterable[Control]) -> list[Control]:
    """One Control per level (by :meth:`Control.key`), in :meth:`Control.order`."""
    return sorted({c.key(): c for c in controls}.values(), key=Control.order)


def level_masks(sample_level: np.ndarray, runs: Sequence) -> list[tuple[Control, np.ndarray]]:
    """Which kbar samples belong to which level, in :meth:`Control.order`. A sample carries its run's force
    (``ElementSamples.level``); a response-controlled run's force is its measured median, so each level gathers
    the forces of its own runs (up and down sweeps may differ)."""
    level = np.asarray(sample_level, float)
    out = []
    for control in ordered_levels(r.control for r in runs):
        forces = [r.force for r in runs if r.control.key() == control.key()]
        mask = np.zeros(len(level), bool)
        for f in forces:
            mask |= np.isclose(level, f, rtol=1e-9, atol=0.0)
        out.append((control, mask))
    return out

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


def level_path(X, w, level, model) -> ModelPath:
    """The :func:`model_paths` of one level's samples as one path, broken between its runs (a response level's
    up and down sweeps each carry their own median force)."""
    paths = model_paths(X, w, level, model)
    gap_x, gap_k = np.array([np.nan]), np.array([np.nan + 0j])
    x = np.concatenate([a for p in paths for a in (p.X, gap_x)][:-1])
    k = np.concatenate([a for p in paths for a in (p.kbar, gap_k)][:-1])
    return ModelPath(paths[0].level, x, k)


def level_style(control: Control, colour, size: float = 5) -> dict:
    """Plot style of a level's measured points: its colour, the marker of how it was held, no line."""
    return {"pen": None, "symbol": level_symbol(control), "symbolSize": size, "symbolBrush": colour,
            "symbolPen": None}


def legend_column(layout, entries: Sequence[tuple[dict, str]], row: int, col: int, rowspan: int = 1,
                  label_size: str = "8pt"):
    """A legend in a cell of its own of a pyqtgraph ``layout`` (a GraphicsLayout), beside the plots and never over
    the data: one row per ``(plot style, words)`` in the order given, at the top of its cell and as wide as its
    longest entry; in as many columns as LEGEND_ROWS asks, filled column by column."""
    import pyqtgraph as pg
    from PySide6.QtCore import Qt

    legend = pg.LegendItem(labelTextSize=label_size, verSpacing=-4, frame=False)
    for style, name in entries:
        # one point: pyqtgraph styles an item's markers only once it holds data (the sample is never drawn)
        legend.addItem(pg.PlotDataItem([0.0], [0.0], **style), name)
    columns = -(-len(entries) // LEGEND_ROWS)
    if columns > 1:
        # read down each column, as a one-column legend reads (pyqtgraph's own columns fill a row first)
        rows = -(-len(entries) // columns)
        for sample, label in legend.items:
            legend.layout.removeItem(sample)
            legend.layout.removeItem(label)
        for k, (sample, label) in enumerate(legend.items):
            legend.layout.addItem(sample, k % rows, 2 * (k // rows))
            legend.layout.addItem(label, k % rows, 2 * (k // rows) + 1)
        legend.updateSize()
    size = legend.layout.preferredSize()
    # a layout cell stretches what it holds: held at its own size, the entries keep their spacing
    legend.setFixedWidth(size.width())
    legend.setFixedHeight(size.height())
    layout.addItem(legend, row=row, col=col, rowspan=rowspan)
    layout.layout.setAlignment(legend, Qt.AlignmentFlag.AlignTop | Qt.AlignmentFlag.AlignLeft)
    return legend
