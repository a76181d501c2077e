"""``contactid analyze``: identify, fit, predict, compare and rank missing effects for a session and a model."""
from __future__ import annotations

from dataclasses import dataclass, field

from typing import Callable

import numpy as np

from analysis.loop.auto import AutoResult, AutoStep, run_auto
from analysis.mechanics.admissibility import Admissibility, admissibility
from analysis.prediction.backbone import BackboneComparison, ModalError, compare_backbones, modal_error
from analysis.prediction.comparison import gain_phrase
from analysis.common.errors import InputError
from analysis.common.statistics import OUTLIER_SHARE_LIMIT
from analysis.common.wording import parameter_words
from analysis.laws.base import Origin
from analysis.signals.frf_noise import METHOD as NOISE_METHOD
from analysis.missing.misfit import Misfit, systematic_misfits
from analysis.common.measurements import Measurements
from analysis.mechanics.model import Model, load_model
from analysis.linear.reference import ReferenceReport, reference_from_random
from analysis.common.tables import load_toml
from analysis.loop.workbench import Workbench

from app.progress import Progress
from app.session import (SessionWriteError, append_model_history, measurements_from_session, open_session,
                         read_model_history)

EARLIER_SHOWN = 3          # earlier analyses listed in the report


def parse_add(text: str) -> tuple[str, str]:
    """``ELEMENT:LAW`` -> (element, law)."""
    element, sep, law = text.partition(":")
    if not sep or not element or not law:
        raise InputError(f"--add takes ELEMENT:LAW (e.g. contact:coulomb), got {text!r}")
    return element, law


@dataclass
class SessionNotes:
    """What an analysis says about the session besides the fit: runs that ended incomplete, the model
    histories earlier analyses stored in it, and whether this analysis's history was stored."""

    incomplete_runs: list[str] = field(default_factory=list)
    earlier: list[dict] = field(default_factory=list)          # app.session.writer.read_model_history
    stored_as: str | None = None
    not_stored: str = ""                                       # why the history was not stored

    def text(self) -> str:
        out = []
        if self.incomplete_runs:
            out.append(f"note: run(s) {', '.join(self.incomplete_runs)} ended incomplete (the measurement stopped "
                       f"mid-run); their lines up to the stop are used")
        if self.earlier:
            out.append(f"earlier analyses stored in this session ({len(self.earlier)}):")
            for h in self.earlier[-EARLIER_SHOWN:]:
                steps = " -> ".join(f"{s['action']} {s['error']:.3g}" for s in h["steps"])
                out.append(f"  {h['name']} ({h['created']}, model {h['model_source'] or '?'}): {steps}")
        if self.stored_as:
            out.append(f"model history stored in the session as /models/{self.stored_as}")
        elif self.not_stored:
            out.append(f"model history NOT stored in the session: {self.not_stored}")
        return "\n".join(out)

    def warning(self) -> str:
        """The one line for stderr where the history was not stored (else empty)."""
        return f"contactid: warning: model history not stored: {self.not_stored}" if self.not_stored else ""

    def to_json(self) -> dict:
        return {"incomplete_runs": self.incomplete_runs,
                "earlier_analyses": [{"name": h["name"], "created": h["created"], "model_source": h["model_source"],
                                      "steps": [{"action": s["action"], "error": s["error"]} for s in h["steps"]]}
                                     for h in self.earlier],
                "history_stored_as": self.stored_as, "history_not_stored": self.not_stored}


def read_measurements(session_path) -> Measurements:
    """The session's measurements, checked (read once per analysis: the noise of imported FRFs is estimated on
    the way)."""
    with open_session(session_path) as s:
        return measurements_from_session(s)


def run_workbench(session_path, model_path, adds: list[str] = (), rank: bool = True,
                  measurements: Measurements | None = None, progress: Progress | None = None):
    """The workbench taken through start, the requested additions and (optionally) the candidate ranking.

    Returns (workbench, candidates)."""
    wb = _started_workbench(session_path, model_path, adds, measurements, progress)
    if progress is not None and rank:
        progress.phase("ranking the missing effects")
    return wb, (wb.candidates() if rank else [])


def run_workbench_auto(session_path, model_path, adds: list[str] = (),
                       progress: Callable[[AutoStep], None] | None = None,
                       note: Callable[[str], None] | None = None,
                       measurements: Measurements | None = None) -> tuple[Workbench, AutoResult]:
    """The workbench taken through start and the requested additions, then the automatic loop
    (:func:`analysis.loop.auto.run_auto`, each step reported to ``progress`` as it is taken, discovery's search
    lines to ``note``)."""
    wb = _started_workbench(session_path, model_path, adds, measurements)
    return wb, run_auto(wb, progress=progress, note=note)


def check_adds(model: Model, adds) -> None:
    """Refuse, before any identification, an ``--add ELEMENT:LAW`` the workbench would refuse only after it: an
    element the model has not, a law no one knows, a law the element has already (in the model file or an
    earlier ``--add``: two terms of one law are one law whose parameters no fit tells apart, the rule of
    ``laws = [...]``), one line naming the model file, its field and the option."""
    from analysis.laws import get_law
    from analysis.mechanics.nonparametric import NAME as NONPARAMETRIC

    given: dict[tuple[str, str], str] = {}
    for add in adds:
        element, law = parse_add(add)
        names = [e.name for e in model.elements]
        if element not in names:
            raise InputError(f"no element named {element!r} (elements: {', '.join(names) or 'none'})", model.source,
                             f"--add {add}")
        index = names.index(element)
        el = model.elements[index]
        if law == NONPARAMETRIC:
            name = law
            if el.nonparametric is not None:
                raise InputError(f"element {element!r} has a non-parametric part already ([[element]][{index}]); "
                                 "--add adds what the model has not", model.source, f"--add {add}")
        else:
            name = get_law(law, model.source, f"--add {add}").name
            have = next((k for k, t in enumerate(el.laws) if t.law.name == name), None)
            if have is not None:
                raise InputError(f"element {element!r} has law {name!r} already ([[element]][{index}].laws[{have}]); "
                                 "--add adds a law the model has not: two terms of one law are one law whose "
                                 "parameters no fit tells apart", model.source, f"--add {add}")
        if (element, name) in given:
            raise InputError(f"law {name!r} is added twice to element {element!r} (also --add "
                             f"{given[element, name]})", model.source, f"--add {add}")
        given[element, name] = add


def _started_workbench(session_path, model_path, adds, measurements: Measurements | None = None,
                       progress: Progress | None = None) -> Workbench:
    model = load_model(load_toml(model_path), str(model_path))
    check_adds(model, adds)
    if measurements is None:
        measurements = read_measurements(session_path)
    if progress is not None:
        progress.phase("identifying the elements")
    wb = Workbench(model, measurements)
    wb.start()
    for add in adds:
        element, law = parse_add(add)
        try:
            wb.add(element, law)
        except InputError as err:               # the workbench knows nothing of the command line: say where
            raise err.located(field_prefix=f"--add {add}") from None
    return wb


@dataclass
class ReferenceAnalysis:
    """A session with a random run and no stepped sine: the modal fit and the model updated to it -- all a
    low-level test can tell (docs/workbench.md, section 1)."""

    model: Model
    reference: ReferenceReport

    def text(self) -> str:
        return "\n".join([self.reference.text(), "",
                          "no stepped-sine run: the elements are not identified (a random run is the reference only)"])

    def to_json(self) -> dict:
        return {"reference": self.reference.to_json(), "elements": [], "candidates": [], "history": [],
                "model": self.model.to_toml()}


def reference_only(session_path, model_path, adds: list[str] = (),
                   measurements: Measurements | None = None) -> ReferenceAnalysis | None:
    """The reference analysis of a session that has a random run and no stepped sine (None if it has a
    stepped-sine run: the workbench analyses it)."""
    if measurements is None:
        measurements = read_measurements(session_path)
    if measurements.sine or measurements.random is None:
        return None
    if adds:
        raise InputError(f"--add {adds[0]}: the session has no stepped-sine run to fit a law to", str(session_path))
    model = load_model(load_toml(model_path), str(model_path))
    missing = sorted(d for d in measurements.dofs() if d not in model.structure.dofs)
    if missing:
        raise InputError(f"measured DOF(s) {', '.join(missing)} are not in the model's structure", model.source)
    reference = reference_from_random(model, measurements.random)
    if reference.update is not None:
        model = model.with_structure(reference.update.table)
    return ReferenceAnalysis(model, reference)


def session_notes(session_path) -> SessionNotes:
    """Incomplete runs and earlier model histories of a session."""
    with open_session(session_path) as s:
        return SessionNotes([r.name for r in s.runs() if r.incomplete], read_model_history(s))


def store_history(session_path, wb: Workbench, model_path, notes: SessionNotes) -> None:
    """Append the workbench's model history to the session; a failure (read-only medium, full disk, a live
    writer) leaves the session untouched and is recorded in ``notes``."""
    try:
        stored = append_model_history(session_path, [h.to_json() for h in wb.history], str(model_path))
    except SessionWriteError as exc:
        notes.not_stored = str(exc)
        return
    notes.stored_as = stored.name
    if stored.recovered_runs:
        notes.incomplete_runs = sorted(set(notes.incomplete_runs) | set(stored.recovered_runs))


def _data_notes(wb: Workbench) -> list[str]:
    """What the analysis had to do without (imported FRFs carry no noise and no harmonics)."""
    out = []
    estimated = [r.name for r in wb.measurements.sine if r.noise_estimated]
    if estimated:
        out.append(f"noise: not measured for {', '.join(estimated)}; estimated {NOISE_METHOD}")
    blind = [r.name for r in wb.measurements.sine if r.distortion is None]
    if blind:
        out.append(f"distortion: no harmonics for {', '.join(blind)}, so no line is left out as far from "
                   "harmonic; the fits leave out the lines whose kbar does not follow the fitted laws (outliers, listed "
                   "per element)")
    return out + ([""] if out else [])


def element_misfits(wb: Workbench, element) -> list[Misfit]:
    """The systematic misfits the fitted laws leave in an element's kbar (analysis/missing/misfit.py); none for an
    element without fitted laws (nothing to misfit) or without samples."""
    report = wb.reports.get(element.name)
    s = report.samples if report is not None else None
    fitted = (element.laws or element.nonparametric is not None) and all(t.complete for t in element.laws)
    if s is None or not fitted or len(s.X) == 0:
        return []
    return systematic_misfits(element.name, s.X, s.kbar, element.describing_function(s.X, s.w), s.kbar_std,
                              s.units)


def model_admissibility(wb: Workbench) -> Admissibility | None:
    """The fitted model's admissibility (analysis/mechanics/admissibility.py) at every identified line, each element
    at its amplitude there; None before anything is identified. The elements' samples are line by line alike
    (a line is kept for all elements or for none); where they are not, each element is checked alone."""
    samples = [wb.reports[el.name].samples if el.name in wb.reports else None for el in wb.model.elements]
    if any(s is None for s in samples):
        return None
    structure = wb.model.structure
    vectors = [el.vector(structure) for el in wb.model.elements]
    functions = [el.describing_function for el in wb.model.elements]
    if len({len(s.X) for s in samples}) == 1 and all(np.array_equal(s.w, samples[0].w) for s in samples):
        return admissibility(structure, vectors, functions, np.stack([s.X for s in samples], axis=1), samples[0].w)
    alone = [admissibility(structure, [v], [f], s.X[:, None], s.w) for v, f, s in zip(vectors, functions, samples)]
    return Admissibility(*(np.concatenate([getattr(a, name) for a in alone])
                           for name in ("amplitude", "w", "dissipation", "stiffness")))


def admissibility_text(check: Admissibility | None) -> list[str]:
    """What the admissibility check found, in the words of the analysis report."""
    if check is None:
        return []
    n = len(check.w)
    if check.admissible:
        return [f"physically admissible at all {n} identified lines: the model dissipates energy at every motion "
                "(passive) and its static stiffness stays positive"]
    out = []
    for flagged, what in ((check.active, "gives energy back to the structure (NOT PASSIVE): the dissipation "
                                         "w C + sum Im kbar v v^T has a negative eigenvalue; no joint does that"),
                          (check.buckled, "has a negative static stiffness (K + sum Re kbar v v^T): the structure "
                                          "would not stand")):
        if flagged.any():
            f = check.w[flagged] / (2 * np.pi)
            out.append(f"at {int(flagged.sum())} of {n} identified lines ({f.min():.5g}-{f.max():.5g} Hz) the model "
                       f"{what}")
    return out


def admissibility_json(check: Admissibility | None) -> dict:
    """The ``admissibility`` entry of ``analyze --json`` (docs/contracts.md §6)."""
    if check is None:
        return {"admissibility": None}
    return {"admissibility": {"passive": check.passive, "statically_stiff": check.stiff, "lines": len(check.w),
                              "lines_not_passive": int(check.active.sum()),
                              "lines_negative_stiffness": int(check.buckled.sum())}}


def misfits_json(wb: Workbench) -> dict:
    """The ``misfits`` entry of ``analyze --json`` (docs/contracts.md §6)."""
    return {"misfits": [m.to_json() for el in wb.model.elements for m in element_misfits(wb, el)]}


def backbones(wb: Workbench) -> list[BackboneComparison]:
    """Natural frequency and damping against response amplitude: measured on the response-controlled levels and
    the phase-resonance runs, predicted from the workbench's (fitted) model (analysis/prediction/backbone.py; none without
    either)."""
    return compare_backbones(wb.model.structure, wb.model.elements, wb.measurements.sine, wb.measurements.phase)


def backbones_json(comparisons: list[BackboneComparison]) -> dict:
    """The ``backbones``, ``backbone_error`` and ``damping_error`` entries of ``analyze --json``
    (docs/contracts.md §6)."""
    return {"backbones": [c.to_json() for c in comparisons], **comparisons_error(comparisons).to_json()}


def comparisons_error(comparisons: list[BackboneComparison]) -> ModalError:
    """The RMS relative error of the predicted natural frequency and damping over every measured point."""
    return modal_error([(c.measured, c.predicted) for c in comparisons])


def backbone_text(comparisons: list[BackboneComparison]) -> list[str]:
    if not comparisons:
        return []
    out = ["", "natural frequency and damping against response amplitude (measured: a single-mode fit per "
               "response level, or the points of a phase-resonance run):"]
    for c in comparisons:
        out += c.text()
    error = comparisons_error(comparisons)
    out.append(f"  RMS relative error of the model: natural frequency {error.frequency:.3g}, damping ratio "
               + (f"{error.damping:.3g}" if np.isfinite(error.damping) else "- (no damping measured)"))
    return out


#: Why an element marked ``in_reference`` has its laws measured from their small-amplitude state (text and GUI)
IN_REFERENCE_WHY = ("the reference was made from a measured level and holds the element's small-amplitude "
                    "stiffness, so each law enters as its change from its small-amplitude state (docs/laws.md, "
                    "\"Measured from the reference\")")


def measured_from_why(origin: Origin | None) -> str:
    """Why an element marked ``in_reference`` has its laws measured as it has (text and GUI): from their
    small-amplitude state, or from the element's state at ``origin``, where the reference was made."""
    if origin is None:
        return IN_REFERENCE_WHY
    return (f"the reference was made from a measured level and holds the element as it was at that level's resonance "
            f"({origin.text()}), its stiffness and dissipation "
            "there included, so each law enters as its change from that state (docs/laws.md, \"Measured from the "
            "reference\")")


def report_text(wb: Workbench, candidates, top: int = 5,
                comparisons: list[BackboneComparison] | None = None) -> str:
    """The analysis as a test engineer reads it (``comparisons``: :func:`backbones`, computed here if not
    given)."""
    out = [f"note: {note.text()}" for note in wb.measurements.unfinished + wb.measurements.unresolved]
    if out:
        out.append("")
    if wb.reference is not None and wb.reference.text():
        out += [wb.reference.text(), ""]
    out += _data_notes(wb)
    out.append("elements:")
    for el in wb.model.elements:
        r = wb.reports[el.name]
        verdict = "no verdict (too few lines)" if r.verdict is None else \
            ("LINEAR" if r.verdict.linear else "NONLINEAR")
        out.append(f"  {el.name} ({', '.join(el.dofs)}): {verdict}; {r.lines_used} lines used, "
                   f"{r.lines_flagged} left out (ill-conditioned or distorted)")
        if r.verdict is not None:
            out.append(f"    evidence: {r.verdict.evidence}")
        if r.yardstick is not None:
            out.append(f"    {r.yardstick.text(r.samples.units[0] if r.samples else 'N/m')}")
        if el.in_reference:
            out.append(f"    measured from the reference: {measured_from_why(el.origin)}")
        for j, term in enumerate(el.laws):
            fitted = r.fit.terms[j] if r.fit is not None else None
            reading = r.reading(term)
            if reading is not None:
                rotational = r.samples.rotational
                shown = (reading.values_text(rotational) if fitted is None
                         else fitted.reading_words(reading, rotational))
                out.append(f"    law {term.law.name}, read as {reading.limit}: {shown} "
                           f"({reading.why}; {', '.join(reading.undetermined)} not determined apart)")
                continue
            params = [_param_text(k, v, fitted) for k, v in term.values.items()]
            out.append(f"    law {term.law.name}: {', '.join(params)}")
        if el.nonparametric is not None:
            out.append(f"    {el.nonparametric.describe(r.samples.units[1] if r.samples else 'm')}")
        out += [f"    systematic misfit: {m.text()}" for m in element_misfits(wb, el)]
        if r.fit is not None:
            out += [f"    {d}" for d in r.fit.degeneracies] + [f"    {c}" for c in r.fit.correlated]
            left_out = r.excluded_hz()
            if not r.fit.describes_the_data:
                out.append(f"    NOT A FIT OF THE DATA: {len(left_out)} of {r.lines_used} line(s) "
                           f"({100 * r.fit.outlier_share:.0f} %) left out of the fit, their kbar not following the "
                           f"fitted laws, more than the {100 * OUTLIER_SHARE_LIMIT:.0f} % a fit may leave out: so "
                           "many are not outliers but the data, which these laws do not describe; the values above "
                           "rest on the rest: " + frequency_ranges(left_out))
            elif left_out:
                out.append(f"    {len(left_out)} line(s) left out of the fit, their kbar not following the fitted "
                           "laws (outliers): " + frequency_ranges(left_out))
    out += [f"  {line}" for line in admissibility_text(model_admissibility(wb))]
    comp = wb.compare(folds=True)
    out.append("")
    single = wb.single_harmonic_comparison().error
    out.append(f"FRF error of the model: {comp.error:.4g}  (" +
               ", ".join(f"{e.label()}: {e.error:.3g}" for e in comp.error_by_level) + ")" +
               ("" if single == comp.error else
                f"; single-harmonic {single:.4g}, the measure the candidates below are judged by"))
    if wb.error_floor is not None:
        out.append(wb.error_floor.text(comp.error))
    worst = max(comp.residual_map, key=lambda n: comp.residual_map[n].max())
    i = int(comp.residual_map[worst].argmax())
    run = next(r for r in wb.measurements.sine if r.name == worst)
    out.append(f"largest misfit: run {worst} at {run.frequency_hz[i]:.4g} Hz (relative error "
               f"{comp.residual_map[worst][i]:.3g})")
    out += _jump_lines(comp, wb.measurements.sine)
    out += backbone_text(backbones(wb) if comparisons is None else comparisons)
    if len(wb.history) > 1:
        out.append("history: " + " -> ".join(f"{h.action} {h.error:.3g}" for h in wb.history))
    offers = wb.unexplained()
    if offers:
        out += ["", "not explained by the laws of the library:"]
        for o in offers:
            out += [f"  {o.finding.text()}", f"    {o.text()}"]
    if candidates:
        out += ["", f"what is missing (best first; single-harmonic FRF error, the model's {single:.4g}):"]
        empty = [el.name for el in wb.model.elements if not el.laws and el.nonparametric is None]
        if len(empty) > 1:
            out.append(f"  (one law at a time, the other elements as they are: {', '.join(empty)} have no laws yet, "
                       "so a right law at one can gain little while another is still empty; --auto first chooses "
                       "every element's laws from its own kbar -- model discovery, docs/discovery.md)")
        for c in candidates[:top]:
            mark = "significant" if c.significant else "not significant"
            out.append(f"  {c.name}  single-harmonic error {c.error:.4g} ({gain_phrase(c.gain)}, {mark})")
            out.append(f"    {c.explanation}")
            if c.model_form or c.held_back:
                out.append(f"    not significant: {c.model_form or c.held_back}")
            elif c.by_modes:
                out.append(f"    significant: {c.by_modes}")
    return "\n".join(out)


def frequency_ranges(hz: list[float]) -> str:
    """Frequencies as the ranges they fill: ``79-79.6 Hz (26 lines), 80.25 Hz`` -- a run of lines no further apart
    than 1.5 times the closest spacing is one range (the same line of several levels counts once per level)."""
    f = np.sort(np.round(np.asarray(hz, float), 6))       # one line of several levels: one frequency to a µHz
    unique = np.unique(f)
    if len(unique) == 0:
        return ""
    step = np.diff(unique).min() if len(unique) > 1 else 0.0
    breaks = np.flatnonzero(np.diff(unique) > 1.5 * step) if step > 0 else np.array([], int)
    parts = []
    for lo, hi in zip(np.r_[0, breaks + 1], np.r_[breaks, len(unique) - 1]):
        a, b = unique[lo], unique[hi]
        n = int(((f >= a) & (f <= b)).sum())
        parts.append(f"{a:.5g} Hz ({n} line{'s' if n > 1 else ''})" if a == b else
                     f"{a:.5g}-{b:.5g} Hz ({n} lines)")
    return ", ".join(parts)


def _param_text(name: str, value: float, fitted) -> str:
    """The parameter's words (:func:`analysis.common.wording.parameter_words`), its spread from the fit if any."""
    if fitted is None:
        return parameter_words(name, value)
    return parameter_words(name, value, fitted.stderr.get(name), name in fitted.undetermined)


def _jump_lines(comp, runs) -> list[str]:
    """The jumps, predicted (fold) against measured, the lines compared with another branch and those predicted
    multi-harmonically."""
    out = []
    if comp.jumps:
        out.append("jumps (predicted fold against measured):")
        out += [f"  {j.text()}" for j in comp.jumps]
    for name, freqs in comp.other_branch_hz(runs).items():
        out.append(f"  run {name}: {len(freqs)} line(s) measured on the other branch ("
                   + ", ".join(f"{f:.5g}" for f in freqs) + " Hz), compared with it")
    n_multi = int(sum(m.sum() for m in comp.multiharmonic.values()))
    if n_multi:
        out.append(f"{n_multi} line(s) predicted with harmonics (displacement THD above 1 % or near a fold)")
    return out
