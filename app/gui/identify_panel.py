"""Identify tab: Re and Im of the equivalent complex stiffness kbar against the element amplitude X for every
element, coloured by level (circles where the force was held, squares where a response was), growing while a
campaign runs; after fitting, the fitted laws as a black line per level under the dots (app/kbar_view.py, as
kbar.png draws them); one legend beside the plots, in level order; an element judged linear on an axis that
shows it flat; the linear/nonlinear verdict with its evidence; what the samples are relative to where the analysis
moved them, and by how much they moved."""
from __future__ import annotations

import html

import numpy as np
import pyqtgraph as pg
from PySide6.QtCore import Qt
from PySide6.QtWidgets import QLabel, QSplitter, QTextBrowser, QVBoxLayout, QWidget

from .lab import Lab
from app.kbar_view import (PANEL_LEVELS, legend_column, level_masks, level_path, level_style, linear_axis,
                            panel_title)
from .plots import FrameClock, LevelPalette, Redraw, configure_plot, scatter
from .results import IdentificationView

NO_IDENTIFICATION = "No identification yet: run a campaign or open a session, with a model (Model tab)."
NO_ELEMENTS = ("The model has no elements: nothing to identify. A linear structure's result is its measured FRFs "
               "(Session tab).")


MOVED = 1e-6          # change of a sample, of the element's largest |kbar|, past which the samples moved


def _same_lines(before: IdentificationView, after: IdentificationView) -> bool:
    """Whether two identifications hold the same elements at the same lines (the same X): a move of their kbar is
    then the analysis's doing, not new data."""
    if [e.name for e in before.elements] != [e.name for e in after.elements]:
        return False
    for a, b in zip(before.elements, after.elements):
        if (a.samples is None) != (b.samples is None):
            return False
        if a.samples is not None and (a.samples.X.shape != b.samples.X.shape or
                                      not np.array_equal(a.samples.X, b.samples.X)):
            return False
    return True


def _moved(before: IdentificationView | None, after: IdentificationView) -> str:
    """How far the samples moved between two identifications of the same lines, as a share of the element's largest
    |kbar| (a share of each sample would be huge where kbar crosses zero), and the sample of the element that moved
    most, where it moved most: its X and its kbar before and after ("" where nothing moved, or the lines
    differ)."""
    if before is None or not _same_lines(before, after):
        return ""
    worst = None
    for a, b in zip(before.elements, after.elements):
        if a.samples is None:
            continue
        scale = np.nanmax(np.abs(a.samples.kbar)) if len(a.samples.kbar) else 0.0
        change = np.abs(b.samples.kbar - a.samples.kbar) / max(scale, 1e-300)
        if len(change) and np.nanmax(change) > MOVED and (worst is None or np.nanmax(change) > worst[0]):
            worst = (float(np.nanmax(change)), a, b)
    if worst is None:
        return ""
    _, a, b = worst
    i = int(np.nanargmax(np.abs(b.samples.kbar - a.samples.kbar)))
    unit, x_unit = a.samples.units
    was, now = a.samples.kbar[i], b.samples.kbar[i]
    return (f"the samples moved with this analysis (its fit, not the data): {a.name} by up to {worst[0]:.1%} of "
            f"its largest |kbar|, most at X = {a.samples.X[i]:.3g} {x_unit}: Re kbar {was.real:.4g} -> "
            f"{now.real:.4g}, Im kbar {was.imag:.4g} -> {now.imag:.4g} {unit}")


def _levels_words(levels) -> str:
    """The levels by name while one plot holds them; more as ranges, one per way of holding them (0.05 ... 2 N,
    20 levels), so that the line above the plots stays a line or two."""
    if len(levels) <= PANEL_LEVELS:
        return ", ".join(c.label() for c in levels)
    groups: dict[tuple, list] = {}
    for c in levels:
        groups.setdefault(c.key()[:3], []).append(c)
    return "; ".join(f"{panel_title(g)} ({len(g)} levels)" for g in groups.values())


class IdentifyPanel(QWidget):
    """The Identify tab (module docstring)."""

    def __init__(self, lab: Lab, clock: FrameClock, palette: LevelPalette, parent: QWidget | None = None):
        super().__init__(parent)
        self.lab = lab
        self.palette = palette
        self.view: IdentificationView | None = None
        layout = QVBoxLayout(self)
        self.status = QLabel(NO_IDENTIFICATION)
        self.status.setWordWrap(True)
        layout.addWidget(self.status)
        splitter = QSplitter(Qt.Orientation.Horizontal)
        layout.addWidget(splitter, 1)
        self.graphics = pg.GraphicsLayoutWidget()
        splitter.addWidget(self.graphics)
        self.verdicts = QTextBrowser()
        self.verdicts.setOpenLinks(False)
        splitter.addWidget(self.verdicts)
        splitter.setSizes([1000, 420])
        self._rows: dict[str, tuple[pg.PlotItem, pg.PlotItem]] = {}
        self._curves: dict[tuple, pg.PlotDataItem] = {}
        self.legend: pg.LegendItem | None = None
        self._legend_entries: list = []
        self.redraw = Redraw(clock, self._draw, self)
        self._moved = ""                 # how the samples moved from the identification shown before
        lab.identificationUpdated.connect(self._update)
        lab.modelChanged.connect(self._model_changed)
        # another session: its own identification follows; nothing of the session before stays meanwhile
        lab.sessionChanged.connect(self._model_changed)

    def plots(self) -> dict[str, pg.PlotItem]:
        out = {}
        for name, (re_plot, im_plot) in self._rows.items():
            out[f"kbar_re_{name}"] = re_plot
            out[f"kbar_im_{name}"] = im_plot
        return out

    def _model_changed(self) -> None:
        self.view = None
        self._moved = ""
        self._clear()

    def _clear(self) -> None:
        self.graphics.clear()
        self._rows.clear()
        self._curves.clear()
        self.legend, self._legend_entries = None, []
        self.verdicts.clear()
        model = self.lab.model
        self.status.setText(NO_ELEMENTS if model is not None and not model.elements else NO_IDENTIFICATION)

    def _update(self, view: IdentificationView) -> None:
        self._moved = _moved(self.view, view)
        self.view = view
        self.redraw.request()

    def _ensure_rows(self, names: list[str]) -> None:
        if list(self._rows) == names:
            return
        self._clear()
        for i, name in enumerate(names):
            re_plot = configure_plot(self.graphics.addPlot(i, 0), f"{name}: Re kbar (stiffness)", "amplitude X",
                                     None, "Re kbar", "N/m", log_x=True)
            im_plot = configure_plot(self.graphics.addPlot(i, 1), f"{name}: Im kbar (damping)", "amplitude X",
                                     None, "Im kbar", "N/m", log_x=True)
            self._rows[name] = (re_plot, im_plot)

    def _draw(self) -> None:
        view = self.view
        if view is None:
            return
        self._ensure_rows([e.name for e in view.elements])
        if self.palette.include(view.levels):
            self._restyle()
        for el in view.elements:
            re_plot, im_plot = self._rows[el.name]
            samples = el.samples
            if samples is not None:
                x_unit, k_unit = samples.units[1], samples.units[0]
                for plot, part in ((re_plot, "Re"), (im_plot, "Im")):
                    plot.setLabel("bottom", "amplitude X", units=x_unit)
                    plot.setLabel("left", f"{part} kbar", units=k_unit)
            for plot, part, name in ((re_plot, np.real, "Re"), (im_plot, np.imag, "Im")):
                self._draw_part(el, plot, part, view)
                self._set_axis(el, plot, part, name)
        self._draw_legend(view)
        origin = "live, while the campaign runs" if view.live else "from the session"
        notes = [f"kbar {view.basis}"] if view.basis else []
        notes += [self._moved] if self._moved else []
        self.status.setText(f"kbar identified at {view.lines} stepped-sine lines ({origin}); "
                            f"levels {_levels_words(view.levels)}"
                            + "".join(f"\n{n}" for n in notes))
        self.verdicts.setHtml(self._verdict_html(view))

    def _restyle(self) -> None:
        """New levels recolour the others (:class:`LevelPalette`): the dots are made again in their colours."""
        plots = {id(p): p for pair in self._rows.values() for p in pair}
        for key in [k for k in self._curves if k[-1] != "model"]:
            plots[key[1]].removeItem(self._curves.pop(key))

    def _draw_part(self, el, plot: pg.PlotItem, part, view: IdentificationView) -> None:
        """The identified dots of each level above the fitted laws' line through the same lines."""
        samples = el.samples
        masks = level_masks(samples.level, view.runs) if samples is not None else \
            [(c, None) for c in view.levels]
        for control, mask in masks:
            key = (el.name, id(plot), control.key())
            fitted = el.model is not None and mask is not None and mask.any()
            path = level_path(samples.X[mask], samples.w[mask], samples.level[mask], el.model[mask]) \
                if fitted else None
            self._draw_model(plot, key + ("model",), path, part)
            curve = self._curves.get(key)
            if curve is None:
                curve = scatter(plot, self.palette.color(control), self.palette.symbol(control), size=5)
                curve.setZValue(10)
                self._curves[key] = curve
            if mask is None:
                curve.setData([], [])
                continue
            curve.setData(samples.X[mask], part(samples.kbar[mask]))

    def _draw_legend(self, view: IdentificationView) -> None:
        """One legend for every plot of the tab, in a column of its own beside them: the levels in order, and the
        fitted laws while they are drawn. Made again only when what it lists changes."""
        entries = [(level_style(c, self.palette.color(c), 6), f"{c.label()} identified") for c in view.levels]
        if any(el.model is not None and el.samples is not None for el in view.elements):
            entries.append(({"pen": pg.mkPen("k", width=1.5)}, "fitted laws"))
        described = [(str(style.get("symbolBrush")), name) for style, name in entries]
        if described == self._legend_entries:
            return
        if self.legend is not None:
            self.graphics.removeItem(self.legend)
        self._legend_entries = described
        self.legend = legend_column(self.graphics.ci, entries, row=0, col=2, rowspan=max(len(self._rows), 1))

    def legend_names(self) -> list[str]:
        return [] if self.legend is None else [label.text for _, label in self.legend.items]

    def _draw_model(self, plot: pg.PlotItem, key: tuple, path, part) -> None:
        """The fitted laws along one level's lines, under its dots."""
        line = self._curves.get(key)
        if path is None:
            if line is not None:
                plot.removeItem(line)            # and from the legend: nothing fitted is shown
                del self._curves[key]
            return
        if line is None:
            line = plot.plot([], [], pen=pg.mkPen("k", width=1.5), connect="finite")
            line.setZValue(0)
            self._curves[key] = line
        line.setData(path.X, part(path.kbar))

    @staticmethod
    def _set_axis(el, plot: pg.PlotItem, part, name: str) -> None:
        """A linear element on an axis that shows it flat, its spread in the title; any other one fitted to its
        data."""
        title = f"{el.name}: {name} kbar ({'stiffness' if name == 'Re' else 'damping'})"
        axis = linear_axis(part(el.samples.kbar)) if el.linear and el.samples is not None else None
        if axis is None:
            plot.enableAutoRange(axis="y")
        else:
            plot.setYRange(axis.low, axis.high, padding=0)
            title += f", linear: {axis.words()}"
        if plot.titleLabel.text != title:        # redrawn every frame while live: set only what changed
            plot.setTitle(title, size="10pt")

    @staticmethod
    def _verdict_html(view: IdentificationView) -> str:
        parts = []
        for el in view.elements:
            color = "#555" if el.linear is None else ("#2ca02c" if el.linear else "#d62728")
            name, where = html.escape(el.name, quote=False), html.escape(el.where, quote=False)
            parts.append(f"<h3 style='margin-bottom:2px'>{name} ({where}): "
                         f"<span style='color:{color}'>{el.verdict}</span></h3>"
                         f"<p style='margin-top:0'>{el.lines_used} lines used, {el.lines_flagged} left out "
                         f"(ill-conditioned or distorted)</p>")
            if el.evidence:
                parts.append(f"<p><b>Evidence:</b> {html.escape(el.evidence, quote=False)}</p>")
            if el.yardstick:
                parts.append(f"<p>{html.escape(el.yardstick[0].upper() + el.yardstick[1:], quote=False)}</p>")
        return "".join(parts)
