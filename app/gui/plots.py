"""Plot building blocks shared by the tabs: one colour per level (the report's too, app/kbar_view.py), axis set-up,
PNG export, and the frame clock that paces every live redraw.

Live data never draws itself: whoever receives it marks a :class:`Redraw` dirty, and the window-wide
:class:`FrameClock` redraws what is dirty at most ``MAX_FPS`` times a second, so a fast stream costs the
window the same as a slow one.
"""
from __future__ import annotations

from pathlib import Path
from typing import Callable

import numpy as np
import pyqtgraph as pg
from pyqtgraph.exporters import ImageExporter
from PySide6.QtCore import QObject, Qt, QTimer, Signal
from PySide6.QtWidgets import QSizePolicy

from analysis.common.measurements import Control
from app.kbar_view import level_colours, level_symbol, ordered_levels
from app.session import atomic_output

MAX_FPS = 30
"""Upper bound of live redraws per second."""

# white background and antialiasing off: readable in print, cheap while streaming
pg.setConfigOptions(background="w", foreground="k", antialias=False)

SENSOR_SYMBOLS = ("o", "t", "s", "d", "star", "x")
CHANNEL_COLORS = ("#000000", "#1f77b4", "#d62728", "#2ca02c", "#ff7f0e", "#9467bd", "#8c564b")


def run_control(run) -> Control:
    """How a session's or a live campaign's run held its level, from its attributes (docs/session-format.md):
    force control at the run's force where they say nothing else."""
    a = run.attrs
    if a.get("control") == "response":
        return Control("response", a["control_dof"], a["control_quantity"], float(a["control_target"]))
    return Control(a.get("control") or "force", "", "force", float(run.force))


class LevelPalette:
    """A colour per level: the levels known to the window in :meth:`Control.order`, coloured as the report colours
    them (:func:`app.kbar_view.level_colours`), so neighbouring levels get neighbouring hues.

    The window keeps one palette so a level has the same colour on every tab. A view tells it every level of its
    data (:meth:`include`) before drawing; a level not known yet is added where it belongs in the order, which
    recolours the others -- a session's or a plan's levels are given all at once."""

    def __init__(self):
        self._levels: list[Control] = []
        self._colors: dict[tuple, str] = {}

    def include(self, controls) -> bool:
        """Know these levels too; whether any was new (the colours then changed)."""
        known = {c.key() for c in self._levels}
        new = [c for c in controls if c.key() not in known]
        if not new:
            return False
        self._levels = ordered_levels([*self._levels, *new])
        self._colors = {c.key(): "#%02x%02x%02x" % rgb
                        for c, rgb in zip(self._levels, level_colours(len(self._levels)))}
        return True

    def reset(self, controls=()) -> None:
        """Forget the levels (another session): only ``controls`` are known."""
        self._levels, self._colors = [], {}
        self.include(controls)

    @property
    def levels(self) -> list[Control]:
        return list(self._levels)

    def color(self, control: Control) -> str:
        self.include([control])
        return self._colors[control.key()]

    def symbol(self, control: Control) -> str:
        """The marker of a level's measured points: circles where the force was held, squares a response."""
        return level_symbol(control)

    def pen(self, control: Control, width: float = 1.5, dashed: bool = False):
        style = {"style": Qt.PenStyle.DashLine} if dashed else {}
        return pg.mkPen(self.color(control), width=width, **style)


def random_pen(index: int):
    """Pen of the random run's FRF at the ``index``-th sensor: greys (the colours belong to the sine levels),
    solid, dashed, dotted."""
    styles = (Qt.PenStyle.SolidLine, Qt.PenStyle.DashLine, Qt.PenStyle.DotLine)
    return pg.mkPen("#555555" if index % 2 == 0 else "#999999", width=1.2, style=styles[index % len(styles)])


def sensor_symbol(index: int) -> str:
    """Scatter symbol of the ``index``-th sensor (levels are told apart by colour, sensors by symbol)."""
    return SENSOR_SYMBOLS[index % len(SENSOR_SYMBOLS)]


class LogAxis(pg.AxisItem):
    """A log axis labelled at 1, 2 and 5 times the powers of ten (labels at every minor tick overlap), or at
    every tick when none of those is in view."""

    LABELLED = (1, 2, 5)

    def logTickValues(self, minVal, maxVal, size, stdTicks):  # noqa: N802 (pyqtgraph API)
        # pyqtgraph lists each power of ten among the major and again among the minor ticks: keep it once
        seen: set[float] = set()
        levels = []
        for spacing, values in super().logTickValues(minVal, maxVal, size, stdTicks):
            levels.append((spacing, [v for v in values if round(v, 9) not in seen]))
            seen.update(round(v, 9) for v in values)
        return levels

    def logTickStrings(self, values, scale, spacing):  # noqa: N802 (pyqtgraph API)
        numbers = [10.0 ** float(v) * scale for v in values]
        keep = [round(x / 10.0 ** np.floor(np.log10(x))) in self.LABELLED for x in numbers]
        if not any(keep):
            keep = [True] * len(numbers)
        return [f"{float(f'{x:.1g}'):g}" if k else "" for x, k in zip(numbers, keep)]


class SpacedAxis(pg.AxisItem):
    """A linear axis whose labels never run together on a narrow plot: the labelled ticks step by 1, 2 or 5 times a
    power of ten, the finest step that leaves ``MIN_GAP`` px between its widest labels (pyqtgraph picks the step by
    the plot's size alone, so a small multiple squeezes "78", "80", "82" into "788082"); finer ticks go unlabelled."""

    MIN_GAP = 8

    def __init__(self, orientation: str, **kwargs):
        super().__init__(orientation, **kwargs)
        self.setStyle(maxTextLevel=0)

    def label_width(self, values, spacing: float) -> float:
        """The widest of the labels of ``values`` at this ``spacing``, in px."""
        from PySide6.QtGui import QFontMetricsF

        metrics = QFontMetricsF(self.style.get("tickFont") or self.font())
        strings = self.tickStrings(list(values), self.autoSIPrefixScale * self.scale, spacing)
        return max((metrics.horizontalAdvance(text) for text in strings), default=0.0)

    def tickSpacing(self, minVal, maxVal, size):  # noqa: N802, N803 (pyqtgraph API)
        levels = super().tickSpacing(minVal, maxVal, size)
        if not levels or size <= 0 or not maxVal > minVal or self.orientation not in ("bottom", "top"):
            return levels
        per_px = (maxVal - minVal) / size
        major = levels[0][0]
        power = 10.0 ** np.floor(np.log10(major))
        for step in (power * m for m in (1, 2, 5, 10, 20, 50, 100, 200, 500, 1000)):
            if step < major * (1 - 1e-9):
                continue
            values = np.arange(np.ceil(minVal / step), np.floor(maxVal / step) + 1) * step
            if step / per_px >= self.label_width(values, step) + self.MIN_GAP or len(values) <= 1:
                # finer ticks only where they divide the step (2 Hz ticks between 5 Hz labels would not line up)
                return [(step, 0.0)] + [level for level in levels[1:] if level[0] < step and
                                        abs(step / level[0] - round(step / level[0])) < 1e-6]
        return levels[:1]


def configure_plot(plot: pg.PlotItem, title: str, x_label: str, x_units: str | None, y_label: str,
                   y_units: str | None, *, log_x: bool = False, log_y: bool = False,
                   legend: bool = False, grid: bool = True) -> pg.PlotItem:
    """Title, axis labels with units (SI prefixes on linear axes), grid and log modes of a plot.

    A plot redrawn at the full frame rate goes without a grid: its axes are repainted every frame, and the
    grid lines are most of their cost."""
    logs = {side: LogAxis(side) for side, log in (("bottom", log_x), ("left", log_y)) if log}
    if logs:
        plot.setAxisItems(logs)
    plot.setTitle(title, size="10pt")
    plot.setLabel("bottom", x_label, units=x_units)
    plot.setLabel("left", y_label, units=y_units)
    for side, log in (("bottom", log_x), ("left", log_y)):
        # SI prefixes make no sense on a log axis (its ticks are already powers of ten)
        plot.getAxis(side).enableAutoSIPrefix(not log)
    if grid:
        plot.showGrid(x=True, y=True, alpha=0.25)
    plot.setLogMode(x=log_x, y=log_y)
    if legend:
        plot.addLegend(offset=(-4, 4), labelTextSize="8pt", verSpacing=-6)
    return plot


def side_legend(layout: pg.GraphicsLayout, plot: pg.PlotItem, row: int, col: int, rowspan: int = 1,
                min_width: int = 120) -> pg.LegendItem:
    """The legend of a live plot in a cell of its own of ``layout``, beside the plots and never over the data, as
    the Model tab's (:func:`app.kbar_view.legend_column`): the curves added to ``plot`` with a name list themselves
    in it as they come, at the top of the cell, each marker level with its words. At least ``min_width`` wide, so
    the plots do not move at every new entry."""
    legend = pg.LegendItem(labelTextSize="8pt", verSpacing=-4, frame=False)
    legend.setMinimumWidth(min_width)
    # held at its own size (the cell would stretch it and spread the entries apart)
    legend.setSizePolicy(QSizePolicy.Policy.Fixed, QSizePolicy.Policy.Fixed)
    layout.addItem(legend, row=row, col=col, rowspan=rowspan)
    layout.layout.setAlignment(legend, Qt.AlignmentFlag.AlignTop | Qt.AlignmentFlag.AlignLeft)
    plot.legend = legend            # pyqtgraph adds a named curve to its plot's legend, wherever that stands
    return legend


def shrinkable_title(plot: pg.PlotItem) -> None:
    """Let a plot's title be cut short rather than widen the plot: pyqtgraph makes a title's text width the
    plot's minimum (again at every text change and resize), so side-by-side plots with long titles would push the
    window past a small screen. Once per plot: its title's minimum width stays 0 from then on."""
    label = plot.titleLabel
    if getattr(label, "shrinkable", False):
        return
    measure = label.updateMin

    def update_min() -> None:
        measure()
        label.setMinimumWidth(0)
        hints = getattr(label, "_sizeHint", None)
        if isinstance(hints, dict) and Qt.SizeHint.MinimumSize in hints:
            hints[Qt.SizeHint.MinimumSize] = (0, hints[Qt.SizeHint.MinimumSize][1])
        label.updateGeometry()

    label.updateMin = update_min
    label.shrinkable = True
    update_min()


def scatter(plot: pg.PlotItem, color: str, symbol: str = "o", size: float = 6, name: str | None = None):
    """An empty scatter curve (no line) to fill with ``setData``."""
    return plot.plot([], [], pen=None, symbol=symbol, symbolSize=size, symbolPen=None,
                     symbolBrush=pg.mkBrush(color), name=name)


def finite_log(values: np.ndarray) -> np.ndarray:
    """``values`` with non-positive entries dropped from a log axis (set to NaN, which pyqtgraph skips)."""
    out = np.asarray(values, float).copy()
    out[~(out > 0)] = np.nan
    return out


def export_png(item: pg.GraphicsItem, path, width: int = 1600, overwrite: bool = False) -> Path:
    """Write a plot (or a whole plot layout) as a PNG of ``width`` pixels with pyqtgraph's ImageExporter, all
    at once; an existing file is refused (InputError) unless ``overwrite``."""
    path = Path(path)
    exporter = ImageExporter(item)
    exporter.parameters()["width"] = int(width)
    with atomic_output(path, overwrite=overwrite, field=None, keep_suffix=True) as temp:
        exporter.export(str(temp))
    return path


def safe_file_name(text: str) -> str:
    """A file-name fragment from a plot title: letters, digits, ``-`` and ``_`` only."""
    cleaned = "".join(c if c.isalnum() or c in "-_" else "_" for c in text.strip().lower())
    return "_".join(part for part in cleaned.split("_") if part) or "plot"


class FrameClock(QObject):
    """One timer for every live plot of the window: ``tick`` at most ``fps`` times a second."""

    tick = Signal()

    def __init__(self, fps: int = MAX_FPS, parent: QObject | None = None):
        super().__init__(parent)
        self._timer = QTimer(self)
        # a coarse timer may run 5 % late; a precise one still fires about a millisecond after its interval
        # (measured: 33 ms gives 29 ticks/s), so the interval is one millisecond short of the period
        self._timer.setTimerType(Qt.TimerType.PreciseTimer)
        self._timer.setInterval(max(1, round(1000 / fps) - 1))
        self._timer.timeout.connect(self.tick)
        self._timer.start()

    def stop(self) -> None:
        self._timer.stop()


class Redraw(QObject):
    """Redraw something on the next clock tick if it was marked dirty since the last one, or if ``stale()``
    says its source has changed (a stream that changes all the time, polled once per frame)."""

    def __init__(self, clock: FrameClock, draw: Callable[[], None], parent: QObject | None = None,
                 stale: Callable[[], bool] | None = None):
        super().__init__(parent)
        self._draw = draw
        self._stale = stale
        self._dirty = False
        clock.tick.connect(self._on_tick)

    def request(self) -> None:
        self._dirty = True

    def now(self) -> None:
        """Redraw at once (data that arrive rarely, e.g. when a run ends)."""
        self._dirty = False
        self._draw()

    def _on_tick(self) -> None:
        if self._dirty or (self._stale is not None and self._stale()):
            self._dirty = False
            self._draw()

