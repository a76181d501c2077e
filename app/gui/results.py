"""What the Identify and Model tabs show, taken out of a workbench in the worker thread.

The workbench belongs to the analysis worker; the GUI gets these views instead, whose arrays the workbench
never changes afterwards (identification and comparison make new arrays each time).
"""
from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from analysis.loop.auto import DISCOVERY, STOPPED_BY_USER, AutoResult
from analysis.prediction.backbone import (Backbone, BackboneComparison, measured_backbone, measured_power_balance,
                                          phase_resonance_backbone)
from analysis.prediction.comparison import LevelError
from analysis.missing.diagnosis import Candidate, ElementSamples
from analysis.common.measurements import Control, Measurements, SineRun
from analysis.common.wording import parameter_words
from analysis.laws.base import Origin, render_unit
from analysis.loop.workbench import Workbench
from analysis.mechanics.model import FittedOn
from analysis.prediction.held_out import SessionPrediction
from app.analyze import backbone_text, backbones, comparisons_error
from app.kbar_view import ordered_levels
from app.predict import KIND_WORDS


@dataclass(frozen=True)
class ParamView:
    name: str
    value: float
    stderr: float | None          # None: not fitted yet; inf: not determined by the data
    unit: str
    undetermined: bool = False    # the data do not determine it (docs/fitting.md): its value is no finding

    def text(self) -> str:
        return parameter_words(self.name, self.value, self.stderr, self.undetermined, self.unit)


@dataclass(frozen=True)
class LawView:
    law: str
    params: tuple[ParamView, ...]
    limit: str = ""        # the limit the law is read in over the amplitudes measured (docs/laws.md, "Limits")
    why: str = ""          # why it is read so, and what the limit leaves open


@dataclass(frozen=True)
class ElementView:
    """One element: where it sits, its kbar samples, the verdict and its laws."""

    name: str
    where: str
    samples: ElementSamples | None
    linear: bool | None               # None: too few lines for a verdict
    evidence: str
    lines_used: int
    lines_flagged: int
    laws: tuple[LawView, ...] = ()
    nonparametric: str = ""           # the non-parametric part, described; "" when the element has none
    model: np.ndarray | None = None   # the fitted laws' kbar at the samples; None before fitting
    in_reference: bool = False        # its laws are measured from their small-amplitude state (docs/laws.md)
    origin: Origin | None = None      # ... or from its state at the reference's level (analysis.laws.base.Origin)
    yardstick: str = ""               # which noise judged it: the line noise or the scatter between runs

    @property
    def verdict(self) -> str:
        if self.linear is None:
            return "no verdict yet (too few lines)"
        return "LINEAR" if self.linear else "NONLINEAR"


@dataclass(frozen=True)
class CandidateView:
    element: str
    law: str
    error: float
    gain: float
    significant: bool
    explanation: str


@dataclass(frozen=True)
class UnexplainedView:
    """An element whose kbar its laws leave unexplained, and what a non-parametric part gives there."""

    element: str
    finding: str          # the detector's sentence: how far and how the kbar departs
    noise_ratio: float
    error: float          # with the non-parametric part
    error_before: float
    gain: float


@dataclass(frozen=True)
class HistoryView:
    step: int
    action: str
    error: float


@dataclass
class AnalysisView:
    """The model tab's content after analyze / add / undo."""

    elements: list[ElementView]
    error: float
    error_by_level: list[LevelError]
    runs: list[SineRun]
    predicted: dict[str, np.ndarray]
    residual_map: dict[str, np.ndarray]
    candidates: list[CandidateView]
    history: list[HistoryView]
    model_toml: str
    reference_text: str = ""
    other_branch: dict[str, np.ndarray] = field(default_factory=dict)   # lines measured on another branch
    compared: dict[str, np.ndarray] = field(default_factory=dict)       # the prediction each line was compared with
    jumps: list[str] = field(default_factory=list)                       # predicted against measured, one per jump
    unexplained: list[UnexplainedView] = field(default_factory=list)     # elements outside the library
    auto: list[str] = field(default_factory=list)       # the steps of the last automatic loop and why it stopped
    single_harmonic_error: float = float("nan")         # the measure the candidates are judged by
    ranked: bool = True                                 # False: stopped before the candidates were ranked
    backbones: list[BackboneComparison] = field(default_factory=list)   # measured against this model's prediction
    kbar_basis: str = ""                                # what the kbar samples are relative to (kbar_basis())
    error_floor: str = ""                               # the FRF error the test itself allows, beside the model's

    @property
    def can_undo(self) -> bool:
        return len(self.history) > 1

    @property
    def tags(self) -> dict[str, str]:
        """Words added to a run's legend entry (none: every run was fitted)."""
        return {}


@dataclass
class PredictionView:
    """The model tab's content after Predict: a fitted model's prediction of the open session, nothing refitted
    (``text`` as ``contactid predict`` prints it; the FRFs drawn as after Analyze, each run tagged by its kind)."""

    text: str
    prediction: SessionPrediction
    runs: list[SineRun]

    @property
    def predicted(self) -> dict[str, np.ndarray]:
        return self.prediction.comparison.predicted

    @property
    def residual_map(self) -> dict[str, np.ndarray]:
        return self.prediction.comparison.residual_map

    @property
    def other_branch(self) -> dict[str, np.ndarray]:
        return self.prediction.comparison.other_branch

    @property
    def compared(self) -> dict[str, np.ndarray]:
        return self.prediction.comparison.compared

    @property
    def tags(self) -> dict[str, str]:
        kinds = {lv.control.key(): lv.kind for lv in self.prediction.levels}
        return {r.name: KIND_WORDS[kinds[r.control.key()]] for r in self.runs}


@dataclass
class IdentificationView:
    """The identify tab's content: kbar samples and verdicts, from ``lines`` stepped-sine lines of ``runs``."""

    elements: list[ElementView]
    lines: int
    live: bool = False
    runs: list[SineRun] = field(default_factory=list)
    basis: str = ""       # what the samples are relative to where a fit moved them (kbar_basis); "" plain

    @property
    def levels(self) -> list[Control]:
        """The runs' levels in :meth:`Control.order`."""
        return ordered_levels(r.control for r in self.runs)


@dataclass
class BackboneView:
    """The Backbone tab's content: natural frequency and damping ratio against response amplitude.

    ``measured`` holds every measured curve of the session -- a single-mode fit per response-controlled level, the
    points of each phase-resonance run -- and ``comparisons`` the model's prediction of each, the very comparisons
    ``contactid analyze`` and ``predict`` print (empty until a model is analysed or predicts); ``model`` names
    that model."""

    measured: list[Backbone]
    comparisons: list[BackboneComparison] = field(default_factory=list)
    model: str = ""

    @property
    def predicted(self) -> bool:
        return bool(self.comparisons)

    def text(self) -> str:
        """The table under the plots: the command line's own text once predicted (``backbone_text``), the measured
        points in its columns before."""
        if self.comparisons:
            return "\n".join(backbone_text(self.comparisons)).strip()
        out = []
        for bb in self.measured:
            what = "response level(s), a single-mode fit each" if bb.method.startswith("single-mode") else \
                f"point(s) of {bb.runs[0]}, {bb.method}"
            out += [f"{bb.quantity} at {bb.dof} ({len(bb.points)} {what}):",
                    f"  {'amplitude [' + bb.units + ']':>18} {'f meas [Hz]':>12} {'zeta meas':>10}"]
            for pt in sorted(bb.points, key=lambda p: p.amplitude):
                zeta = f"{pt.damping:10.5f}" if np.isfinite(pt.damping) else f"{'-':>10}"
                out.append(f"  {pt.amplitude:18.4g} {pt.frequency:12.5f} {zeta}"
                           + ("" if pt.converged else "  (lock not converged)"))
        return "\n".join(out)

    def error_words(self) -> str:
        """The model's RMS relative errors over every measured point (as the command line states them)."""
        if not self.comparisons:
            return ""
        error = comparisons_error(self.comparisons)
        damping = f"{error.damping:.3g}" if np.isfinite(error.damping) else "- (no damping measured)"
        return f"natural frequency {error.frequency:.3g}, damping ratio {damping}"


def measured_backbones(measurements: Measurements) -> list[Backbone]:
    """Every measured curve of a session without a model, as the Acquire tab draws them live: the response levels'
    single-mode fits (:func:`measured_backbone`), and each phase-resonance run's locked points with the damping by
    the power balance on the session's own low-level FRF (NaN where the session holds none)."""
    out = measured_backbone(measurements.sine)
    for run in measurements.phase:
        curve = phase_resonance_backbone(run)
        zeta = measured_power_balance(measurements, run)
        if zeta is not None:
            curve.points = [replace(p, damping=float(z)) for p, z in zip(curve.points, zeta)]
        out.append(curve)
    return out


def kbar_basis(wb: Workbench) -> str:
    """What the identified kbar is relative to where the analysis moved it away from the plain closed form on the
    model as loaded: the structure updated from the random run, and on data without harmonics (imported FRFs) the
    fitted model's own fundamental bias taken out once every element has fitted laws (docs/fitting.md, "The
    fundamental's bias"). Said beside the dots, because without it a sample that moves between two analyses reads as
    a changed measurement."""
    out = []
    if wb.reference is not None and wb.reference.update is not None:
        out.append("relative to the structure updated from the random run")
    fitted = all(el.laws and all(t.complete for t in el.laws) for el in wb.model.elements)
    if wb.harmonics_blind and fitted and wb.model.elements:
        out.append("on data without harmonics, less the fitted laws' own fundamental bias, so the samples move "
                   "when the laws change (docs/fitting.md, \"The fundamental's bias\")")
    return "; ".join(out)


def element_views(wb: Workbench, with_laws: bool) -> list[ElementView]:
    """Identification results (and, after fitting, the laws with their values) of every element."""
    views = []
    for el in wb.model.elements:
        report = wb.reports[el.name]
        rotational = el.rotational(wb.model.structure)
        laws = []
        if with_laws:
            for j, term in enumerate(el.laws):
                laws.append(_law_view(report, j, term, rotational))
        where = el.dofs[0] if el.grounded else f"{el.dofs[0]}-{el.dofs[1]}"
        verdict = report.verdict
        part = el.nonparametric.describe("rad" if rotational else "m") if with_laws and el.nonparametric else ""
        samples = report.samples
        fitted = with_laws and samples is not None and (el.laws or el.nonparametric is not None) \
            and all(t.complete for t in el.laws)
        views.append(ElementView(el.name, where, samples, None if verdict is None else verdict.linear,
                                 "" if verdict is None else verdict.evidence, report.lines_used,
                                 report.lines_flagged, tuple(laws), part,
                                 el.describing_function(samples.X, samples.w) if fitted else None,
                                 el.in_reference, el.origin,
                                 "" if report.yardstick is None or samples is None
                                 else report.yardstick.text(samples.units[0])))
    return views


def _law_view(report, j: int, term, rotational: bool) -> LawView:
    """A fitted law as the user reads it: its parameters with their errors, or, where its values sit in one of its
    limits, the combination the data determine there (with the errors of the limit's own fit where it was fitted
    in it), as the text of ``analyze`` gives it."""
    fitted = report.fit.terms[j] if report.fit is not None else None
    reading = report.reading(term)
    if reading is None:
        units = {p.name: p.render_unit(rotational) for p in term.law.params}
        values, found = term.values, fitted
    else:
        units = {k: render_unit(u, rotational) for k, u in reading.units.items()}
        values, found = reading.values, None if fitted is None else fitted.findings
    stderr = found.stderr if found is not None else {}
    loose = found.undetermined if found is not None else ()
    params = tuple(ParamView(k, float(v), stderr.get(k), units.get(k, ""), k in loose) for k, v in values.items())
    if reading is None:
        return LawView(term.law.name, params)
    return LawView(term.law.name, params, reading.limit,
                   f"{reading.why}; {', '.join(reading.undetermined)} not determined apart")


def _identification(elements: list[ElementView], runs: list[SineRun], live: bool,
                    basis: str = "") -> IdentificationView:
    return IdentificationView(elements, sum(len(r.frequency_hz) for r in runs), live, list(runs), basis)


def identification_view(wb: Workbench, live: bool) -> IdentificationView:
    """After :meth:`Workbench.identify`."""
    return _identification(element_views(wb, with_laws=False), wb.measurements.sine, live, kbar_basis(wb))


def identification_of(view: AnalysisView) -> IdentificationView:
    """The identification part of an analysis (from the session, not live)."""
    return _identification(view.elements, view.runs, live=False, basis=view.kbar_basis)


def _discovered(auto: AutoResult) -> list[str]:
    """One line per element whose laws discovery chose, with the sets the data cannot tell from them; a choice the
    loop was stopped before adding says so (the model does not hold it)."""
    added = {s.element for s in auto.steps if s.action == "discover"}
    replaced = {s.element: "+".join(s.laws) for s in auto.steps if s.action == "replace"}
    out = []
    for e in [] if auto.discovery is None else auto.discovery.elements:
        alike = f"; indistinguishable on these data: {', '.join('+'.join(s.laws) for s in e.equivalents)}" \
            if e.equivalents else ""
        later = f"; read as {replaced[e.element]} by the loop (judged by prediction)" if e.element in replaced else ""
        kept = e.element in added or not e.laws
        out.append(f"discovered {e.element}: {e.chosen.name}{alike}{later}" if kept else
                   f"found for {e.element}: {e.chosen.name} -- not added (stopped before it)")
    return out


def _judged_against(auto: AutoResult) -> list[str]:
    """What the measured modes were judged against, where the session measures them."""
    return [] if auto.modal_yardstick is None else [auto.modal_yardstick.words()]


def _stopped(auto: AutoResult) -> str:
    """Why the loop ended; stopped by the user, what the model keeps and what was not tried."""
    if auto.stopped != STOPPED_BY_USER:
        return f"stopped: {auto.stopped}"
    added = {s.element for s in auto.steps if s.action == "discover"}
    pending = [e.element for e in ([] if auto.discovery is None else auto.discovery.elements)
               if e.laws and e.element not in added]
    kept = (f"the model on this tab keeps the {len(auto.steps)} step(s) taken" if auto.steps else
            "no step was taken: the model is as it was")
    if auto.undone:
        kept += f"; {auto.undone}, under way, was undone"
    if auto.undone == DISCOVERY:
        untried = "the laws discovery would have found, the linear corrections and the ranking of the missing effects"
    elif pending:
        untried = (f"adding the laws found for {', '.join(pending)}, the linear corrections and the ranking of the "
                   "missing effects")
    else:
        untried = "the next ranking of the missing effects and what it would add"
    return f"stopped by the user: {kept}; not tried: {untried}"


def analysis_view(wb: Workbench, candidates: list[Candidate], auto: AutoResult | None = None,
                  fitted_on: FittedOn | None = None) -> AnalysisView:
    """After :meth:`Workbench.start` / ``add`` / ``undo`` and the candidate ranking, or after the automatic loop
    (``auto``; its ranking is ``candidates``); ``fitted_on``: what the saved model says it was fitted to."""
    comp = wb.compare(folds=True)
    return AnalysisView(
        element_views(wb, with_laws=True), comp.error, list(comp.error_by_level), list(wb.measurements.sine),
        dict(comp.predicted), dict(comp.residual_map),
        [CandidateView(c.element, c.law, c.error, c.gain, c.significant, c.explanation) for c in candidates],
        [HistoryView(h.step, h.action, h.error) for h in wb.history],
        replace(wb.model, fitted_on=fitted_on).to_toml(),
        wb.reference.text() if wb.reference is not None else "", dict(comp.other_branch), dict(comp.compared),
        [j.text() for j in comp.jumps],
        [UnexplainedView(o.element, o.finding.text(), o.finding.noise_ratio, o.error, o.error_before, o.gain)
         for o in wb.unexplained()],
        [] if auto is None else _discovered(auto) + _judged_against(auto) + [s.text() for s in auto.steps]
        + [_stopped(auto)],
        wb.single_harmonic_comparison().error,
        # a stopped loop leaves no ranking; an empty table would read as "every law was tried"
        auto is None or auto.stopped != STOPPED_BY_USER,
        backbones(wb), kbar_basis(wb), "" if wb.error_floor is None else wb.error_floor.text(comp.error))
